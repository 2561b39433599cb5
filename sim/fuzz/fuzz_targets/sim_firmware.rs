//! Arbitrary bytes from a hostile host into both simulated firmwares: no panic, and the stage
//! never leaves its travel by more than the switches allow.
#![no_main]
use libfuzzer_sys::fuzz_target;
use rig_sim::faults::FaultSpec;
use rig_sim::grbl::GrblFirmware;
use rig_sim::native::NativeFirmware;
use rig_sim::rng::Rng;
use rig_sim::stage::{Stage, StageConfig, StageEvent};

trait Firmware {
    fn bytes(&mut self, b: &[u8], s: &mut Stage, out: &mut Vec<u8>);
    fn event(&mut self, e: StageEvent, s: &mut Stage, out: &mut Vec<u8>);
}

impl Firmware for NativeFirmware {
    fn bytes(&mut self, b: &[u8], s: &mut Stage, out: &mut Vec<u8>) {
        self.on_bytes(b, s, out)
    }
    fn event(&mut self, e: StageEvent, s: &mut Stage, out: &mut Vec<u8>) {
        self.on_event(e, s, out)
    }
}

impl Firmware for GrblFirmware {
    fn bytes(&mut self, b: &[u8], s: &mut Stage, out: &mut Vec<u8>) {
        self.on_bytes(b, s, out)
    }
    fn event(&mut self, e: StageEvent, s: &mut Stage, out: &mut Vec<u8>) {
        self.on_event(e, s, out)
    }
}

fn drive(fw: &mut dyn Firmware, stage: &mut Stage, data: &[u8]) {
    let (mut out, mut events) = (Vec::new(), Vec::new());
    for chunk in data.chunks(7) {
        fw.bytes(chunk, stage, &mut out);
        let t = stage.next_event_time().unwrap_or(stage.t);
        stage.advance(t, &mut events);
        for e in events.drain(..) {
            fw.event(e, stage, &mut out);
        }
    }
}

fuzz_target!(|data: &[u8]| {
    // The native firmware, then GRBL homing toward + and toward − ($23=3).
    for case in 0..3 {
        let cfg = match case {
            0 => StageConfig::native(&mut Rng::new(1)),
            1 => StageConfig::grbl(&mut Rng::new(1), [1.0, 1.0]),
            _ => StageConfig::grbl(&mut Rng::new(1), [-1.0, -1.0]),
        };
        let mut stage = Stage::new(cfg, FaultSpec::default(), 1, true);
        if case == 0 {
            drive(&mut NativeFirmware::new(&stage, 1), &mut stage, data);
        } else {
            let mask = if case == 2 { vec![(23, 3.0)] } else { vec![] };
            let mut fw = GrblFirmware::new(&stage, &mask, &mut Vec::new());
            drive(&mut fw, &mut stage, data);
        }
        for k in 0..2 {
            let c = stage.carriage(k);
            let [lo, hi] = stage.cfg.switch_um[k];
            assert!(c > lo - 100.0 && c < hi + 100.0, "axis {k} at {c}");
        }
    }
});
