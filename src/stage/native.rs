//! Client for the rig's own firmware protocol (firmware-protocol/PROTOCOL.md).
//!
//! Replies are matched to requests by sequence number; events are queued. Only idempotent
//! queries are retried. A motion request whose reply is lost is never repeated blindly: the
//! status is read back, and only if it proves the request was not executed is it sent once
//! more.

use super::limits_check::{check, Range};
use super::{
    Controller, ControllerInfo, FaultKind, LinkOptions, Port, Result, SoftLimits, StageError,
    StageState, StageStatus, StopAction,
};
use crate::coords::CarriageUm;
use firmware_protocol::{
    encode, flags, major, Decoder, FaultCode, Frame, Message, NakCode, SettingId, State,
    StatusReport, MAX_WIRE, PROTOCOL_VERSION,
};
use std::collections::VecDeque;
use std::path::Path;
use std::time::{Duration, Instant};

/// How long to wait for a reply (the spec promises 50 ms; the rest is slack for the OS).
const REPLY_TIMEOUT: Duration = Duration::from_millis(300);
const QUERY_TRIES: usize = 4;
/// Sends of one motion request, each after the status proved the previous did not run.
const MOTION_TRIES: usize = 3;
/// Status polling interval while waiting for motion.
const POLL: Duration = Duration::from_millis(20);

pub struct NativeController {
    port: Port,
    dec: Decoder,
    seq: u8,
    events: VecDeque<Message>,
    info: ControllerInfo,
    /// Frames that failed to decode (line noise), for diagnostics.
    pub bad_frames: u64,
}

fn um(nm: i32) -> f64 {
    nm as f64 / 1000.0
}

fn nm(um: f64) -> i32 {
    (um * 1000.0).round() as i32
}

fn switches_name(bits: u8) -> String {
    let mut s = String::new();
    for (b, n) in [
        (flags::LIMIT_X_MIN, "X-"),
        (flags::LIMIT_X_MAX, "X+"),
        (flags::LIMIT_Y_MIN, "Y-"),
        (flags::LIMIT_Y_MAX, "Y+"),
    ] {
        if bits & b != 0 {
            s.push_str(n);
        }
    }
    s
}

fn nak_reason(code: NakCode) -> &'static str {
    match code {
        NakCode::UnknownCommand => "unknown command (firmware too old?)",
        NakCode::BadArgument => "an argument is out of range",
        NakCode::Busy => "the stage is moving",
        NakCode::NotHomed => "not homed",
        NakCode::OutOfLimits => "target outside the controller's soft limits",
        NakCode::Faulted => "the controller is in a fault state",
        NakCode::Version => "no protocol handshake (the controller has reset)",
        NakCode::ReadOnly => "read-only setting",
        NakCode::UnknownSetting => "unknown setting",
    }
}

impl NativeController {
    pub fn open(path: &Path, link: &LinkOptions) -> Result<Self> {
        let port = Port::open(path, 115_200, link)?;
        let mut c = NativeController {
            port,
            dec: Decoder::new(),
            seq: 0,
            events: VecDeque::new(),
            info: ControllerInfo {
                resolution_um: 0.05,
                ..ControllerInfo::unknown("native")
            },
            bad_frames: 0,
        };
        c.handshake()?;
        if let Message::Identity {
            model,
            serial,
            firmware,
        } = c.query(Message::Identify)?
        {
            let model = String::from_utf8_lossy(&model)
                .trim_end_matches('\0')
                .to_string();
            c.info.identity = format!(
                "{model} serial {serial} firmware {}.{}.{}",
                firmware >> 16,
                (firmware >> 8) & 0xff,
                firmware & 0xff
            );
        }
        // Settings are input, not truth: each is range-checked before a limit, a speed or a
        // wait is computed from it, and the soft limits never reach beyond the travel.
        let mut s = |id, range: &Range| -> Result<f64> {
            let v = c.setting(id)? as f64;
            check(
                "native",
                &format!("{id:?}"),
                v,
                range,
                &format!("set {id:?} in its configuration"),
            )
        };
        // Travel and limits in nm (1 mm to the i32 range), speed in µm/s, acceleration in µm/s².
        let travel_nm = Range::closed(1e6, i32::MAX as f64);
        let um = |nm: f64| nm / 1000.0;
        let travel = CarriageUm::new(
            um(s(SettingId::TravelX, &travel_nm)?),
            um(s(SettingId::TravelY, &travel_nm)?),
        );
        let pos = Range::closed(i32::MIN as f64, i32::MAX as f64);
        let limits = SoftLimits {
            min: CarriageUm::new(
                um(s(SettingId::SoftMinX, &pos)?),
                um(s(SettingId::SoftMinY, &pos)?),
            ),
            max: CarriageUm::new(
                um(s(SettingId::SoftMaxX, &pos)?),
                um(s(SettingId::SoftMaxY, &pos)?),
            ),
        }
        .intersect(&SoftLimits {
            min: CarriageUm::new(0.0, 0.0),
            max: travel,
        });
        if !(limits.min.x < limits.max.x && limits.min.y < limits.max.y) {
            return Err(StageError::BadSetting {
                dialect: "native",
                setting: "SoftMin/SoftMax".into(),
                value: format!("{}..{}", limits.min, limits.max),
                allowed: format!("a non-empty box inside the travel 0..{travel}"),
                fix: "set SoftMin/SoftMax inside the travel in its configuration".into(),
            });
        }
        let max_speed = s(SettingId::MaxSpeed, &Range::closed(10.0, 2_000_000.0))?;
        let accel = s(SettingId::Accel, &Range::closed(100.0, 100_000_000.0))?;
        c.info.travel = travel;
        c.info.limits = limits;
        c.info.max_speed_um_s = max_speed;
        c.info.accel_um_s2 = accel;
        c.info.home_speed_um_s = max_speed / 2.0;
        Ok(c)
    }

    /// `msg` again once the controller has answered Nak(Version): it has reset and forgotten
    /// the handshake. The reset is queued as an event, hands are shaken again, `msg` is sent.
    fn after_reset(&mut self, msg: Message) -> Result<Message> {
        self.events.push_back(Message::Reset { cause: 0xff });
        self.handshake()?;
        self.query(msg)
    }

    /// Version handshake, with a purge first so that stale bytes cannot answer it.
    fn handshake(&mut self) -> Result<()> {
        self.port.purge()?;
        self.dec.reset();
        let answer = self
            .query(Message::Hello {
                version: PROTOCOL_VERSION,
            })
            .map_err(|e| match e {
                // Silence at the handshake is most often the wrong port or the wrong dialect.
                StageError::Timeout { after, .. } => StageError::Timeout {
                    what: "the rig protocol's Hello (is the controller powered, on this port, \
                           and running the rig's firmware? a GRBL board needs --dialect grbl)"
                        .into(),
                    after,
                },
                e => e,
            })?;
        match answer {
            Message::HelloReply { version } if major(version) == major(PROTOCOL_VERSION) => Ok(()),
            Message::HelloReply { version } => Err(StageError::Version {
                host: format!("{}.{}", PROTOCOL_VERSION >> 8, PROTOCOL_VERSION & 0xff),
                controller: format!("{}.{}", version >> 8, version & 0xff),
            }),
            Message::Nak {
                code: NakCode::Version,
            } => Err(StageError::Version {
                host: format!("{}.{}", PROTOCOL_VERSION >> 8, PROTOCOL_VERSION & 0xff),
                controller: "another major version".into(),
            }),
            other => Err(StageError::Protocol(format!(
                "unexpected answer to Hello: {other:?}"
            ))),
        }
    }

    fn setting(&mut self, id: SettingId) -> Result<i32> {
        match self.query(Message::GetSetting { id: id as u8 })? {
            Message::SettingValue { id: got, value } if got == id as u8 => Ok(value),
            Message::Nak { code } => Err(StageError::Rejected {
                command: format!("reading setting {id:?}"),
                reason: nak_reason(code).into(),
            }),
            other => Err(StageError::Protocol(format!(
                "unexpected answer to GetSetting: {other:?}"
            ))),
        }
    }

    fn next_seq(&mut self) -> u8 {
        self.seq = if self.seq == 255 { 1 } else { self.seq + 1 };
        self.seq
    }

    /// Sends one request and waits for the reply with its sequence number. Events that arrive
    /// meanwhile are queued; stale replies are dropped.
    fn exchange(&mut self, msg: Message) -> Result<Option<Message>> {
        let seq = self.next_seq();
        let mut buf = [0u8; MAX_WIRE];
        let n = encode(&Frame { seq, msg }, &mut buf)
            .map_err(|e| StageError::Protocol(format!("{e:?}")))?;
        self.port.write_all(&buf[..n])?;
        let deadline = Instant::now() + REPLY_TIMEOUT;
        let mut bytes = Vec::new();
        while Instant::now() < deadline {
            bytes.clear();
            self.port.read_until(deadline, &mut bytes)?;
            for &b in &bytes {
                match self.dec.push(b) {
                    Some(Ok(f)) if f.msg.is_event() => self.events.push_back(f.msg),
                    Some(Ok(f)) if f.seq == seq && !f.msg.is_request() => return Ok(Some(f.msg)),
                    Some(Ok(_)) => {} // a late or duplicated reply to an earlier request
                    Some(Err(_)) => self.bad_frames += 1,
                    None => {}
                }
            }
        }
        Ok(None)
    }

    /// An idempotent query: retried, with a purge between tries.
    fn query(&mut self, msg: Message) -> Result<Message> {
        for _ in 0..QUERY_TRIES {
            if let Some(r) = self.exchange(msg)? {
                return Ok(r);
            }
            self.port.purge()?;
            self.dec.reset();
        }
        Err(StageError::Timeout {
            what: format!("{msg:?}"),
            after: REPLY_TIMEOUT * QUERY_TRIES as u32,
        })
    }

    fn raw_status(&mut self) -> Result<StatusReport> {
        match self.query(Message::Status)? {
            Message::StatusReply(s) => Ok(s),
            Message::Nak {
                code: NakCode::Version,
            } => {
                // Report what it is now (unhomed); a move in progress sees that as a reset.
                match self.after_reset(Message::Status)? {
                    Message::StatusReply(s) => Ok(s),
                    other => Err(StageError::Protocol(format!(
                        "unexpected answer to Status: {other:?}"
                    ))),
                }
            }
            other => Err(StageError::Protocol(format!(
                "unexpected answer to Status: {other:?}"
            ))),
        }
    }

    fn to_status(s: &StatusReport) -> StageStatus {
        let fault = match s.fault {
            FaultCode::None => None,
            FaultCode::EStop => Some(FaultKind::EmergencyStop),
            FaultCode::Limit => Some(FaultKind::LimitSwitch {
                switches: switches_name(s.flags),
            }),
            FaultCode::FollowingError => Some(FaultKind::Stall),
            FaultCode::Reset => Some(FaultKind::Reset),
        };
        StageStatus {
            state: match s.state {
                State::Idle => StageState::Idle,
                State::Moving => StageState::Moving,
                State::Homing => StageState::Homing,
                State::Jogging => StageState::Jogging,
                State::Fault => StageState::Fault,
                State::Unhomed => StageState::Unhomed,
            },
            position: CarriageUm::new(um(s.x_nm), um(s.y_nm)),
            homed: s.flags & flags::HOMED != 0,
            limit_switches: switches_name(s.flags),
            fault,
            controller_state: format!("{:?}", s.state),
        }
    }

    /// A fault reported by an event.
    fn event_fault(&mut self) -> Option<StageError> {
        while let Some(e) = self.events.pop_front() {
            let kind = match e {
                Message::LimitHit { switches, .. } => FaultKind::LimitSwitch {
                    switches: switches_name(switches),
                },
                Message::Fault {
                    code: FaultCode::EStop,
                    ..
                } => FaultKind::EmergencyStop,
                Message::Fault {
                    code: FaultCode::FollowingError,
                    ..
                } => FaultKind::Stall,
                Message::Fault { .. } | Message::Reset { .. } => FaultKind::Reset,
                _ => continue,
            };
            let position = match e {
                Message::LimitHit { x_nm, y_nm, .. } | Message::Fault { x_nm, y_nm, .. } => {
                    Some(CarriageUm::new(um(x_nm), um(y_nm)))
                }
                _ => None,
            };
            self.events.clear();
            return Some(StageError::Fault { kind, position });
        }
        None
    }

    /// Sends a motion request. If its reply is lost, reads the status back: if the stage is
    /// moving, has moved or changed state, the request ran; if it is just as it was, the request
    /// never arrived and is sent again, at most [`MOTION_TRIES`] times in all.
    fn motion_request(&mut self, msg: Message) -> Result<()> {
        let before = Self::to_status(&self.raw_status()?);
        for attempt in 0..MOTION_TRIES {
            let reply = self.exchange(msg)?;
            match reply {
                Some(Message::Ack) => return Ok(()),
                Some(Message::Nak {
                    code: NakCode::NotHomed,
                }) => return Err(StageError::NotHomed),
                Some(Message::Nak {
                    code: NakCode::Version,
                }) => {
                    return Err(StageError::Fault {
                        kind: FaultKind::Reset,
                        position: None,
                    })
                }
                Some(Message::Nak {
                    code: NakCode::Faulted,
                }) => {
                    let st = Self::to_status(&self.raw_status()?);
                    return Err(StageError::Fault {
                        kind: st.fault.unwrap_or(FaultKind::Reset),
                        position: Some(st.position),
                    });
                }
                Some(Message::Nak { code }) => {
                    return Err(StageError::Rejected {
                        command: format!("{msg:?}"),
                        reason: nak_reason(code).into(),
                    })
                }
                Some(other) => {
                    return Err(StageError::Protocol(format!(
                        "unexpected answer to {msg:?}: {other:?}"
                    )))
                }
                None => {
                    self.port.purge()?;
                    self.dec.reset();
                    let st = Self::to_status(&self.raw_status()?);
                    if let Some(e) = self.event_fault() {
                        return Err(e);
                    }
                    if st.state == StageState::Fault {
                        return Err(StageError::Fault {
                            kind: st.fault.unwrap_or(FaultKind::Reset),
                            position: Some(st.position),
                        });
                    }
                    // Nothing but our request moves the stage: if it is moving, or has moved, or
                    // changed state, the request ran; the wait and the position check that follow
                    // judge how it ended.
                    let unchanged =
                        st.state == before.state && (st.position - before.position).norm() < 0.5;
                    if st.state.is_moving() || !unchanged {
                        return Ok(());
                    }
                    if attempt + 1 == MOTION_TRIES {
                        return Err(StageError::Timeout {
                            what: format!("{msg:?}"),
                            after: REPLY_TIMEOUT,
                        });
                    }
                }
            }
        }
        unreachable!("the last attempt returns")
    }
}

impl Controller for NativeController {
    fn info(&self) -> &ControllerInfo {
        &self.info
    }

    fn status(&mut self) -> Result<StageStatus> {
        let s = self.raw_status()?;
        let st = Self::to_status(&s);
        self.port.observe(st.position);
        Ok(st)
    }

    fn start_move(&mut self, target: CarriageUm, speed_um_s: f64) -> Result<()> {
        self.events.clear();
        let msg = Message::MoveAbs {
            x_nm: nm(target.x),
            y_nm: nm(target.y),
            speed_um_s: speed_um_s.round().max(1.0) as u32,
        };
        self.motion_request(msg)
    }

    fn start_home(&mut self) -> Result<()> {
        self.events.clear();
        self.motion_request(Message::Home { axes: 3 })
    }

    fn start_jog(&mut self, delta: CarriageUm, speed_um_s: f64) -> Result<()> {
        self.events.clear();
        let len = delta.norm();
        // Whole milliseconds, rounded up: the jog ends by decelerating, never short of the
        // clipped target by a truncated deadline.
        let t_ms = (len / speed_um_s * 1000.0).ceil().max(1.0);
        let v = [delta.x / len * speed_um_s, delta.y / len * speed_um_s];
        let msg = Message::Jog {
            vx_um_s: v[0].round() as i32,
            vy_um_s: v[1].round() as i32,
            max_ms: t_ms as u32,
        };
        self.motion_request(msg)
    }

    fn wait_done(&mut self, timeout: Duration) -> Result<StageStatus> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(e) = self.event_fault() {
                return Err(e);
            }
            let st = self.status()?;
            match st.state {
                StageState::Fault => {
                    return Err(StageError::Fault {
                        kind: st.fault.unwrap_or(FaultKind::Reset),
                        position: Some(st.position),
                    })
                }
                s if s.is_moving() => {}
                _ => {
                    if let Some(e) = self.event_fault() {
                        return Err(e);
                    }
                    return Ok(st);
                }
            }
            if Instant::now() >= deadline {
                // Stopping is the driver's decision (it stops on every error).
                return Err(StageError::MotionTimeout { after: timeout });
            }
            // Listen for events between polls.
            let until = Instant::now() + POLL;
            let mut bytes = Vec::new();
            self.port.read_until(until, &mut bytes)?;
            for &b in &bytes {
                match self.dec.push(b) {
                    Some(Ok(f)) if f.msg.is_event() => self.events.push_back(f.msg),
                    Some(Ok(_)) => {}
                    Some(Err(_)) => self.bad_frames += 1,
                    None => {}
                }
            }
        }
    }

    /// A decelerating Stop; if it is not acknowledged, the emergency stop (the motors stop at
    /// once, the position is lost); if that is not acknowledged either, an error: the stop was
    /// not confirmed.
    fn stop(&mut self) -> Result<StopAction> {
        let first = match self.query(Message::Stop) {
            Ok(Message::Ack) => return Ok(StopAction::Decelerated),
            Ok(Message::Nak {
                code: NakCode::Version,
            }) => {
                // Its motors stopped and its position was lost: have it confirm the stop rather
                // than take the reset's word for it.
                match self.after_reset(Message::Stop) {
                    Ok(Message::Ack) => return Ok(StopAction::Reset),
                    Ok(other) => format!(
                        "the controller had reset; after a new handshake, unexpected answer to Stop: {other:?}"
                    ),
                    Err(StageError::Disconnected(e)) => return Err(StageError::Disconnected(e)),
                    Err(e) => format!("the controller had reset; {e}"),
                }
            }
            Ok(other) => format!("unexpected answer to Stop: {other:?}"),
            Err(StageError::Disconnected(e)) => return Err(StageError::Disconnected(e)),
            Err(e) => e.to_string(),
        };
        match self.query(Message::EStop) {
            Ok(Message::Ack) => Ok(StopAction::Reset),
            Ok(other) => Err(StageError::Protocol(format!(
                "{first}; then unexpected answer to EStop: {other:?}"
            ))),
            Err(e) => Err(StageError::Protocol(format!(
                "{first}; then the emergency stop was not acknowledged: {e}"
            ))),
        }
    }

    fn emergency_stop(&mut self) -> Result<()> {
        match self.query(Message::EStop)? {
            Message::Ack => Ok(()),
            other => Err(StageError::Protocol(format!(
                "unexpected answer to EStop: {other:?}"
            ))),
        }
    }

    fn clear_fault(&mut self) -> Result<()> {
        // After a controller reset the handshake is gone too.
        if matches!(
            self.query(Message::ClearFault)?,
            Message::Nak {
                code: NakCode::Version
            }
        ) {
            self.handshake()?;
            self.query(Message::ClearFault)?;
        }
        self.events.clear();
        Ok(())
    }
}
