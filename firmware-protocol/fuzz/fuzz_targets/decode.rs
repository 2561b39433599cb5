//! Arbitrary bytes into the frame decoder: it must never panic, and every frame it yields must
//! re-encode into bytes that decode to the same frame.
#![no_main]
use firmware_protocol::{encode, Decoder, MAX_WIRE};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut d = Decoder::new();
    for &b in data {
        if let Some(Ok(frame)) = d.push(b) {
            let mut buf = [0u8; MAX_WIRE];
            let n = encode(&frame, &mut buf).expect("a decoded frame fits the wire buffer");
            let mut d2 = Decoder::new();
            let again: Vec<_> = buf[..n].iter().filter_map(|&b| d2.push(b)).collect();
            assert_eq!(again, vec![Ok(frame)]);
        }
    }
});
