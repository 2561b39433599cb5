//! The simulated native controller follows PROTOCOL.md, checked frame by frame over its
//! pseudo-terminal without the rig's client in between.

use crate::common;

use firmware_protocol::*;
use rig_sim::{Dialect, EmbeddedSim, FaultSpec, SimConfig};
use std::io::{Read, Write};
use std::time::{Duration, Instant};

struct Line {
    f: std::fs::File,
    dec: Decoder,
    seq: u8,
    events: Vec<Message>,
    _sim: EmbeddedSim,
}

impl Line {
    fn open(start_homed: bool, faults: &str) -> Line {
        let sim = EmbeddedSim::start(SimConfig {
            dialect: Dialect::Native,
            time_scale: 0.0,
            start_homed,
            faults: FaultSpec::parse(faults).unwrap(),
            ..Default::default()
        })
        .unwrap();
        let f = common::open_nonblocking(&sim.port);
        Line {
            f,
            dec: Decoder::new(),
            seq: 0,
            events: vec![],
            _sim: sim,
        }
    }

    fn send_raw(&mut self, seq: u8, msg: Message) {
        let mut buf = [0u8; MAX_WIRE];
        let n = encode(&Frame { seq, msg }, &mut buf).unwrap();
        self.f.write_all(&buf[..n]).unwrap();
    }

    /// Frames received within `wait`.
    fn recv(&mut self, wait: Duration) -> Vec<Frame> {
        let deadline = Instant::now() + wait;
        let mut out = vec![];
        let mut buf = [0u8; 256];
        while Instant::now() < deadline {
            match self.f.read(&mut buf) {
                Ok(n) if n > 0 => {
                    for &b in &buf[..n] {
                        if let Some(Ok(fr)) = self.dec.push(b) {
                            out.push(fr);
                        }
                    }
                }
                _ => std::thread::sleep(Duration::from_millis(1)),
            }
        }
        out
    }

    /// One request, its reply (matched by seq); events are kept.
    fn req(&mut self, msg: Message) -> Message {
        self.seq = self.seq.wrapping_add(1).max(1);
        let seq = self.seq;
        self.send_raw(seq, msg);
        let deadline = Instant::now() + Duration::from_secs(1);
        let mut reply = None;
        while reply.is_none() && Instant::now() < deadline {
            // Keep every event, also those that follow the reply in the same read.
            for fr in self.recv(Duration::from_millis(20)) {
                if fr.msg.is_event() {
                    self.events.push(fr.msg);
                } else if fr.seq == seq {
                    reply = Some(fr.msg);
                }
            }
        }
        reply.unwrap_or_else(|| panic!("no reply to {msg:?}"))
    }

    fn status(&mut self) -> StatusReport {
        match self.req(Message::Status) {
            Message::StatusReply(s) => s,
            m => panic!("{m:?}"),
        }
    }
}

fn handshake_identity_and_version_refusal() {
    let mut l = Line::open(false, "");
    // Before the handshake every request is refused.
    assert_eq!(
        l.req(Message::Status),
        Message::Nak {
            code: NakCode::Version
        }
    );
    // Another major version is refused too.
    assert_eq!(
        l.req(Message::Hello { version: 0x0200 }),
        Message::Nak {
            code: NakCode::Version
        }
    );
    assert_eq!(
        l.req(Message::Hello { version: 0x0105 }),
        Message::HelloReply {
            version: PROTOCOL_VERSION
        }
    );
    match l.req(Message::Identify) {
        Message::Identity { model, .. } => assert!(model.starts_with(b"rig-sim native")),
        m => panic!("{m:?}"),
    }
    let s = l.status();
    assert_eq!((s.state, s.flags & flags::HOMED), (State::Unhomed, 0));
}

fn motion_rules_events_and_settings() {
    let mut l = Line::open(false, "");
    l.req(Message::Hello {
        version: PROTOCOL_VERSION,
    });
    let mv = |x_nm, y_nm| Message::MoveAbs {
        x_nm,
        y_nm,
        speed_um_s: 0,
    };
    assert_eq!(
        l.req(mv(1_000_000, 1_000_000)),
        Message::Nak {
            code: NakCode::NotHomed
        }
    );
    assert_eq!(l.req(Message::Home { axes: 3 }), Message::Ack);
    let _ = l.recv(Duration::from_millis(50));
    let s = l.status();
    assert_eq!(s.state, State::Idle);
    assert!(s.flags & flags::HOMED != 0);
    assert!(
        s.x_nm.abs() < 1000 && s.y_nm.abs() < 1000,
        "homed at the origin: {s:?}"
    );

    // Soft limits: outside is refused, the limit itself is fine.
    let xmax = match l.req(Message::GetSetting {
        id: SettingId::SoftMaxX as u8,
    }) {
        Message::SettingValue { value, .. } => value,
        m => panic!("{m:?}"),
    };
    assert_eq!(
        l.req(mv(xmax + 1, 0)),
        Message::Nak {
            code: NakCode::OutOfLimits
        }
    );
    l.events.clear();
    assert_eq!(l.req(mv(50_000_000, 20_000_000)), Message::Ack);
    // The MotionDone event carries the encoder position.
    let deadline = Instant::now() + Duration::from_secs(1);
    while !l
        .events
        .iter()
        .any(|e| matches!(e, Message::MotionDone { .. }))
        && Instant::now() < deadline
    {
        for f in l.recv(Duration::from_millis(20)) {
            l.events.push(f.msg);
        }
    }
    let done = l.events.iter().find_map(|e| match e {
        Message::MotionDone { x_nm, y_nm } => Some((*x_nm, *y_nm)),
        _ => None,
    });
    let (x, y) = done.expect("MotionDone event");
    assert!(
        (x - 50_000_000).abs() < 5_000 && (y - 20_000_000).abs() < 5_000,
        "{x} {y}"
    );

    // Settings: read-only ones are refused, soft limits outside the travel are refused.
    assert_eq!(
        l.req(Message::SetSetting {
            id: SettingId::TravelX as u8,
            value: 1
        }),
        Message::Nak {
            code: NakCode::ReadOnly
        }
    );
    assert_eq!(
        l.req(Message::SetSetting {
            id: SettingId::SoftMinX as u8,
            value: -1
        }),
        Message::Nak {
            code: NakCode::BadArgument
        }
    );
    assert_eq!(
        l.req(Message::SetSetting { id: 200, value: 1 }),
        Message::Nak {
            code: NakCode::UnknownSetting
        }
    );
    assert_eq!(
        l.req(Message::SetSetting {
            id: SettingId::SoftMaxX as u8,
            value: 100_000_000
        }),
        Message::Ack
    );
    assert_eq!(
        l.req(mv(100_000_001, 0)),
        Message::Nak {
            code: NakCode::OutOfLimits
        }
    );

    // The trigger output: once now, and armed for the next motion's end.
    l.events.clear();
    assert_eq!(
        l.req(Message::Trigger {
            mode: 0,
            delay_us: 0,
            pulse_us: 100
        }),
        Message::Ack
    );
    assert_eq!(
        l.req(Message::Trigger {
            mode: 1,
            delay_us: 1000,
            pulse_us: 100
        }),
        Message::Ack
    );
    assert!(l.status().flags & flags::TRIGGER_ARMED != 0);
    assert_eq!(l.req(mv(10_000_000, 10_000_000)), Message::Ack);
    let deadline = Instant::now() + Duration::from_secs(1);
    while l
        .events
        .iter()
        .filter(|e| matches!(e, Message::TriggerFired { .. }))
        .count()
        < 2
        && Instant::now() < deadline
    {
        for f in l.recv(Duration::from_millis(20)) {
            l.events.push(f.msg);
        }
    }
    let fired: Vec<u32> = l
        .events
        .iter()
        .filter_map(|e| {
            if let Message::TriggerFired { count } = e {
                Some(*count)
            } else {
                None
            }
        })
        .collect();
    assert_eq!(fired, vec![1, 2]);

    // Emergency stop: fault until cleared, then unhomed.
    assert_eq!(l.req(Message::EStop), Message::Ack);
    let s = l.status();
    assert_eq!((s.state, s.fault), (State::Fault, FaultCode::EStop));
    assert_eq!(
        l.req(mv(0, 0)),
        Message::Nak {
            code: NakCode::Faulted
        }
    );
    assert_eq!(l.req(Message::ClearFault), Message::Ack);
    assert_eq!(l.status().state, State::Unhomed);
}

fn replies_echo_sequence_numbers_and_garbage_is_survived() {
    let mut l = Line::open(true, "");
    // Garbage, then a frame: the controller resynchronises at the delimiter.
    l.f.write_all(&[0x13, 0x37, 0xFF, 0x42, 0x00]).unwrap();
    l.send_raw(
        77,
        Message::Hello {
            version: PROTOCOL_VERSION,
        },
    );
    let frames = l.recv(Duration::from_millis(100));
    assert_eq!(frames.len(), 1);
    assert_eq!(frames[0].seq, 77);
    // A request with a bad CRC is dropped silently (no reply at all).
    let mut buf = [0u8; MAX_WIRE];
    let n = encode(
        &Frame {
            seq: 78,
            msg: Message::Status,
        },
        &mut buf,
    )
    .unwrap();
    buf[2] ^= 0x01;
    l.f.write_all(&buf[..n]).unwrap();
    assert!(l.recv(Duration::from_millis(100)).is_empty());
}

fn reset_mid_move_is_reported_and_forgets_everything() {
    let mut l = Line::open(true, "reset=1");
    l.req(Message::Hello {
        version: PROTOCOL_VERSION,
    });
    assert_eq!(
        l.req(Message::MoveAbs {
            x_nm: 100_000_000,
            y_nm: 100_000_000,
            speed_um_s: 0
        }),
        Message::Ack
    );
    let frames = l.recv(Duration::from_millis(100));
    l.events.extend(frames.iter().map(|f| f.msg));
    assert!(
        l.events.iter().any(|m| matches!(m, Message::Reset { .. })),
        "Reset event expected: {:?}",
        l.events
    );
    // The handshake is gone, and so is the reference.
    assert_eq!(
        l.req(Message::Status),
        Message::Nak {
            code: NakCode::Version
        }
    );
    l.req(Message::Hello {
        version: PROTOCOL_VERSION,
    });
    assert_eq!(l.status().state, State::Unhomed);
}

/// A port released a moment after the rig asks for it (a process ending, a child between
/// fork and exec holding a copy) is opened; one held on is reported busy, after the grace.
fn a_port_released_within_the_grace_opens_and_a_held_one_is_busy() {
    use rig::stage::{LinkOptions, Port, StageError, BUSY_GRACE};
    let sim = EmbeddedSim::start(SimConfig {
        dialect: Dialect::Native,
        time_scale: 0.0,
        ..Default::default()
    })
    .unwrap();
    let held = Port::open(&sim.port, 115_200, &LinkOptions::default()).unwrap();
    let t0 = Instant::now();
    match Port::open(&sim.port, 115_200, &LinkOptions::default()) {
        Err(StageError::PortBusy { .. }) => {}
        Err(e) => panic!("not a busy port: {e}"),
        Ok(_) => panic!("a held port opened twice"),
    }
    assert!(t0.elapsed() >= BUSY_GRACE, "{:?}", t0.elapsed());
    let release = std::thread::spawn(move || {
        std::thread::sleep(BUSY_GRACE / 3);
        drop(held);
    });
    Port::open(&sim.port, 115_200, &LinkOptions::default()).expect("released within the grace");
    release.join().unwrap();
}

crate::waiting_tests!(
    handshake_identity_and_version_refusal,
    motion_rules_events_and_settings,
    replies_echo_sequence_numbers_and_garbage_is_survived,
    reset_mid_move_is_reported_and_forgets_everything,
    a_port_released_within_the_grace_opens_and_a_held_one_is_busy,
);
