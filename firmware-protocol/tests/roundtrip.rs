//! Property tests: every message survives encode → decode, any byte stream leaves the decoder
//! in one piece, and a frame after garbage is still recovered.
use firmware_protocol::*;
use proptest::prelude::*;

fn pick<T: Copy + core::fmt::Debug + 'static>(all: &'static [T]) -> impl Strategy<Value = T> {
    (0..all.len()).prop_map(move |i| all[i])
}

fn arb_message() -> impl Strategy<Value = Message> {
    let i = any::<i32>;
    let u = any::<u32>;
    prop_oneof![
        any::<u16>().prop_map(|version| Message::Hello { version }),
        Just(Message::Identify),
        any::<u8>().prop_map(|axes| Message::Home { axes }),
        (i(), i(), u()).prop_map(|(x_nm, y_nm, speed_um_s)| Message::MoveAbs {
            x_nm,
            y_nm,
            speed_um_s
        }),
        (i(), i(), u()).prop_map(|(dx_nm, dy_nm, speed_um_s)| Message::MoveRel {
            dx_nm,
            dy_nm,
            speed_um_s
        }),
        (i(), i(), u()).prop_map(|(vx_um_s, vy_um_s, max_ms)| Message::Jog {
            vx_um_s,
            vy_um_s,
            max_ms
        }),
        Just(Message::Stop),
        Just(Message::EStop),
        Just(Message::Status),
        any::<u8>().prop_map(|id| Message::GetSetting { id }),
        (any::<u8>(), i()).prop_map(|(id, value)| Message::SetSetting { id, value }),
        (any::<u8>(), u(), u()).prop_map(|(mode, delay_us, pulse_us)| Message::Trigger {
            mode,
            delay_us,
            pulse_us
        }),
        Just(Message::ClearFault),
        Just(Message::Ack),
        pick(NakCode::ALL).prop_map(|code| Message::Nak { code }),
        any::<u16>().prop_map(|version| Message::HelloReply { version }),
        (any::<[u8; 16]>(), u(), u()).prop_map(|(model, serial, firmware)| Message::Identity {
            model,
            serial,
            firmware
        }),
        (
            pick(State::ALL),
            any::<u8>(),
            pick(FaultCode::ALL),
            i(),
            i()
        )
            .prop_map(|(state, flags, fault, x_nm, y_nm)| {
                Message::StatusReply(StatusReport {
                    state,
                    flags,
                    fault,
                    x_nm,
                    y_nm,
                })
            }),
        (any::<u8>(), i()).prop_map(|(id, value)| Message::SettingValue { id, value }),
        (i(), i()).prop_map(|(x_nm, y_nm)| Message::MotionDone { x_nm, y_nm }),
        (any::<u8>(), i(), i()).prop_map(|(switches, x_nm, y_nm)| Message::LimitHit {
            switches,
            x_nm,
            y_nm
        }),
        (pick(FaultCode::ALL), i(), i()).prop_map(|(code, x_nm, y_nm)| Message::Fault {
            code,
            x_nm,
            y_nm
        }),
        any::<u8>().prop_map(|cause| Message::Reset { cause }),
        u().prop_map(|count| Message::TriggerFired { count }),
    ]
}

fn arb_frame() -> impl Strategy<Value = Frame> {
    (any::<u8>(), arb_message()).prop_map(|(seq, msg)| Frame { seq, msg })
}

fn decode_all(bytes: &[u8]) -> (Vec<Frame>, usize) {
    let mut d = Decoder::new();
    let mut frames = Vec::new();
    let mut errors = 0;
    for &b in bytes {
        match d.push(b) {
            Some(Ok(f)) => frames.push(f),
            Some(Err(_)) => errors += 1,
            None => {}
        }
    }
    (frames, errors)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4096))]

    #[test]
    fn roundtrip(frame in arb_frame()) {
        let mut buf = [0u8; MAX_WIRE];
        let n = encode(&frame, &mut buf).unwrap();
        prop_assert!(n <= MAX_WIRE);
        prop_assert_eq!(buf[n - 1], 0);
        prop_assert!(!buf[..n - 1].contains(&0), "delimiter inside a frame");
        let (frames, errors) = decode_all(&buf[..n]);
        prop_assert_eq!(errors, 0);
        prop_assert_eq!(frames, vec![frame]);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let (frames, _) = decode_all(&bytes);
        // Everything decoded must re-encode to a valid frame (no invented kinds).
        for f in frames {
            let mut buf = [0u8; MAX_WIRE];
            encode(&f, &mut buf).unwrap();
        }
    }

    #[test]
    fn resync_after_garbage(garbage in proptest::collection::vec(any::<u8>(), 0..200), frame in arb_frame()) {
        let mut bytes = garbage;
        bytes.push(0); // any garbage ends at the next delimiter
        let mut buf = [0u8; MAX_WIRE];
        let n = encode(&frame, &mut buf).unwrap();
        bytes.extend_from_slice(&buf[..n]);
        let (frames, _) = decode_all(&bytes);
        prop_assert_eq!(frames.last(), Some(&frame));
    }
}

#[test]
fn every_kind_byte_is_distinct() {
    // Wire kinds must be unique, or a reply could be read as a request.
    use std::collections::HashSet;
    let samples = [
        Message::Hello { version: 0 },
        Message::Identify,
        Message::Home { axes: 0 },
        Message::MoveAbs {
            x_nm: 0,
            y_nm: 0,
            speed_um_s: 0,
        },
        Message::MoveRel {
            dx_nm: 0,
            dy_nm: 0,
            speed_um_s: 0,
        },
        Message::Jog {
            vx_um_s: 0,
            vy_um_s: 0,
            max_ms: 0,
        },
        Message::Stop,
        Message::EStop,
        Message::Status,
        Message::GetSetting { id: 0 },
        Message::SetSetting { id: 0, value: 0 },
        Message::Trigger {
            mode: 0,
            delay_us: 0,
            pulse_us: 0,
        },
        Message::ClearFault,
        Message::Ack,
        Message::Nak {
            code: NakCode::Busy,
        },
        Message::HelloReply { version: 0 },
        Message::Identity {
            model: [0; 16],
            serial: 0,
            firmware: 0,
        },
        Message::StatusReply(StatusReport {
            state: State::Idle,
            flags: 0,
            fault: FaultCode::None,
            x_nm: 0,
            y_nm: 0,
        }),
        Message::SettingValue { id: 0, value: 0 },
        Message::MotionDone { x_nm: 0, y_nm: 0 },
        Message::LimitHit {
            switches: 0,
            x_nm: 0,
            y_nm: 0,
        },
        Message::Fault {
            code: FaultCode::Limit,
            x_nm: 0,
            y_nm: 0,
        },
        Message::Reset { cause: 0 },
        Message::TriggerFired { count: 0 },
    ];
    let kinds: HashSet<u8> = samples.iter().map(|m| m.kind()).collect();
    assert_eq!(kinds.len(), samples.len());
    assert!(samples.iter().filter(|m| m.is_request()).count() == 13);
}

#[test]
fn every_single_bit_flip_is_rejected() {
    // Exhaustive over a set of real frames: no single flipped bit on the line yields a frame
    // other than the original (COBS may split it, the CRC must catch the rest).
    let frames = [
        Frame {
            seq: 7,
            msg: Message::MoveAbs {
                x_nm: 123_456_789,
                y_nm: -5,
                speed_um_s: 20_000,
            },
        },
        Frame {
            seq: 255,
            msg: Message::StatusReply(StatusReport {
                state: State::Moving,
                flags: 0x21,
                fault: FaultCode::None,
                x_nm: 1,
                y_nm: 0,
            }),
        },
        Frame {
            seq: 0,
            msg: Message::Identity {
                model: *b"rig-sim native\0\0",
                serial: 42,
                firmware: 0x010203,
            },
        },
        Frame {
            seq: 1,
            msg: Message::Ack,
        },
    ];
    let mut wrong = 0;
    for frame in frames {
        let mut buf = [0u8; MAX_WIRE];
        let n = encode(&frame, &mut buf).unwrap();
        for bit in 0..8 * (n - 1) {
            let mut b = buf;
            b[bit / 8] ^= 1 << (bit % 8);
            let (got, _) = decode_all(&b[..n]);
            wrong += got.iter().filter(|f| **f != frame).count();
        }
    }
    assert_eq!(wrong, 0);
}
