//! The rig's own controller firmware (PROTOCOL.md), running on the simulated stage.

use crate::stage::{MotionKind, Stage, StageEvent, StopCause};
use firmware_protocol::{
    encode, flags, major, Decoder, FaultCode, Frame, Message, NakCode, SettingId, State,
    StatusReport, MAX_WIRE, PROTOCOL_VERSION,
};

/// Linear encoder resolution, µm.
const ENCODER_UM: f64 = 0.05;

pub struct NativeFirmware {
    dec: Decoder,
    hello_ok: bool,
    /// Soft limits, logical µm: [axis][min, max].
    soft: [[f64; 2]; 2],
    max_speed: f64,
    backlash_comp_nm: [i32; 2],
    fault: FaultCode,
    event_seq: u8,
    trigger_at: Option<f64>,
    trigger_armed_delay: Option<f64>,
    trigger_count: u32,
    serial: u32,
    pub bad_frames: u64,
    /// What a misconfigured controller reports for these settings, whatever it does itself
    /// (for hostile tests: a zero speed, a travel of nothing, inverted limits).
    pub reported: Vec<(SettingId, i32)>,
}

fn nm(um: f64) -> i32 {
    (um * 1000.0)
        .round()
        .clamp(i32::MIN as f64, i32::MAX as f64) as i32
}

impl NativeFirmware {
    pub fn new(stage: &Stage, serial: u32) -> Self {
        NativeFirmware {
            dec: Decoder::new(),
            hello_ok: false,
            soft: [[0.0, stage.cfg.travel_um[0]], [0.0, stage.cfg.travel_um[1]]],
            max_speed: stage.cfg.max_speed_um_s,
            backlash_comp_nm: [0, 0],
            fault: FaultCode::None,
            event_seq: 0,
            trigger_at: None,
            trigger_armed_delay: None,
            trigger_count: 0,
            serial,
            bad_frames: 0,
            reported: Vec::new(),
        }
    }

    /// The encoder reading in the controller's frame, µm.
    fn encoder(stage: &Stage, k: usize) -> f64 {
        (stage.encoder(k) / ENCODER_UM).round() * ENCODER_UM
    }

    fn pos_nm(stage: &Stage) -> (i32, i32) {
        (nm(Self::encoder(stage, 0)), nm(Self::encoder(stage, 1)))
    }

    fn send(&mut self, seq: u8, msg: Message, out: &mut Vec<u8>) {
        let mut buf = [0u8; MAX_WIRE];
        let n = encode(&Frame { seq, msg }, &mut buf).expect("every message fits MAX_WIRE");
        out.extend_from_slice(&buf[..n]);
    }

    fn event(&mut self, msg: Message, out: &mut Vec<u8>) {
        let seq = self.event_seq;
        self.event_seq = self.event_seq.wrapping_add(1);
        self.send(seq, msg, out);
    }

    fn state(&self, stage: &Stage) -> State {
        if self.fault != FaultCode::None {
            return State::Fault;
        }
        match stage.motion_kind() {
            Some(MotionKind::HomeSeek | MotionKind::HomePulloff) => State::Homing,
            Some(MotionKind::Jog) => State::Jogging,
            Some(_) => State::Moving,
            None if !stage.homed => State::Unhomed,
            None => State::Idle,
        }
    }

    pub fn status(&self, stage: &Stage) -> StatusReport {
        let (x_nm, y_nm) = Self::pos_nm(stage);
        let mut f = stage.switches();
        if stage.homed {
            f |= flags::HOMED;
        }
        if self.trigger_armed_delay.is_some() {
            f |= flags::TRIGGER_ARMED;
        }
        StatusReport {
            state: self.state(stage),
            flags: f,
            fault: self.fault,
            x_nm,
            y_nm,
        }
    }

    pub fn state_name(&self, stage: &Stage) -> String {
        format!("{:?}", self.state(stage))
    }

    fn in_soft(&self, p: [f64; 2]) -> bool {
        (0..2).all(|k| p[k] >= self.soft[k][0] && p[k] <= self.soft[k][1])
    }

    fn motion_check(&self, stage: &Stage) -> Option<NakCode> {
        if self.fault != FaultCode::None {
            Some(NakCode::Faulted)
        } else if stage.is_busy() {
            Some(NakCode::Busy)
        } else if !stage.homed {
            Some(NakCode::NotHomed)
        } else {
            None
        }
    }

    fn start_move(&mut self, stage: &mut Stage, target: [f64; 2], speed_um_s: u32) -> Message {
        if !self.in_soft(target) {
            return Message::Nak {
                code: NakCode::OutOfLimits,
            };
        }
        let speed = if speed_um_s == 0 {
            self.max_speed
        } else {
            (speed_um_s as f64).min(self.max_speed)
        };
        // Firmware backlash compensation: overshoot by the setting when moving in -.
        let mut t = target;
        for k in 0..2 {
            if target[k] < stage.logical(k) {
                t[k] -= self.backlash_comp_nm[k] as f64 / 1000.0;
            }
        }
        stage.start_move(t, speed);
        Message::Ack
    }

    fn setting(&self, stage: &Stage, id: SettingId) -> i32 {
        if let Some(&(_, v)) = self.reported.iter().rev().find(|(k, _)| *k == id) {
            return v;
        }
        match id {
            SettingId::SoftMinX => nm(self.soft[0][0]),
            SettingId::SoftMaxX => nm(self.soft[0][1]),
            SettingId::SoftMinY => nm(self.soft[1][0]),
            SettingId::SoftMaxY => nm(self.soft[1][1]),
            SettingId::MaxSpeed => self.max_speed as i32,
            SettingId::Accel => stage.cfg.accel_um_s2 as i32,
            SettingId::BacklashX => self.backlash_comp_nm[0],
            SettingId::BacklashY => self.backlash_comp_nm[1],
            SettingId::StepNm => nm(stage.cfg.step_um),
            SettingId::TravelX => nm(stage.cfg.travel_um[0]),
            SettingId::TravelY => nm(stage.cfg.travel_um[1]),
            SettingId::FollowingTolerance => nm(stage.cfg.following_tol_um),
        }
    }

    fn set_setting(&mut self, stage: &mut Stage, id: SettingId, v: i32) -> Message {
        if id.read_only() {
            return Message::Nak {
                code: NakCode::ReadOnly,
            };
        }
        let um = v as f64 / 1000.0;
        let bad = Message::Nak {
            code: NakCode::BadArgument,
        };
        let in_travel = |k: usize| um >= 0.0 && um <= stage.cfg.travel_um[k];
        match id {
            SettingId::SoftMinX
            | SettingId::SoftMaxX
            | SettingId::SoftMinY
            | SettingId::SoftMaxY => {
                let k = if matches!(id, SettingId::SoftMinX | SettingId::SoftMaxX) {
                    0
                } else {
                    1
                };
                let i = if matches!(id, SettingId::SoftMinX | SettingId::SoftMinY) {
                    0
                } else {
                    1
                };
                if !in_travel(k) {
                    return bad;
                }
                self.soft[k][i] = um;
            }
            SettingId::MaxSpeed => {
                if v <= 0 || v as f64 > stage.cfg.max_speed_um_s * 2.0 {
                    return bad;
                }
                self.max_speed = v as f64;
            }
            SettingId::Accel => {
                if v <= 0 {
                    return bad;
                }
                stage.cfg.accel_um_s2 = v as f64;
            }
            SettingId::BacklashX | SettingId::BacklashY => {
                if !(0..=100_000).contains(&v) {
                    return bad;
                }
                self.backlash_comp_nm[if id == SettingId::BacklashX { 0 } else { 1 }] = v;
            }
            SettingId::FollowingTolerance => {
                if v <= 0 {
                    return bad;
                }
                stage.cfg.following_tol_um = um;
            }
            SettingId::StepNm | SettingId::TravelX | SettingId::TravelY => {
                unreachable!("read-only")
            }
        }
        Message::Ack
    }

    fn handle(&mut self, req: Message, stage: &mut Stage) -> Message {
        if let Message::Hello { version } = req {
            self.hello_ok = major(version) == major(PROTOCOL_VERSION);
            return if self.hello_ok {
                Message::HelloReply {
                    version: PROTOCOL_VERSION,
                }
            } else {
                Message::Nak {
                    code: NakCode::Version,
                }
            };
        }
        if !self.hello_ok {
            return Message::Nak {
                code: NakCode::Version,
            };
        }
        let nak = |code| Message::Nak { code };
        match req {
            Message::Identify => {
                let mut model = [0u8; 16];
                model[..14].copy_from_slice(b"rig-sim native");
                Message::Identity {
                    model,
                    serial: self.serial,
                    firmware: 0x01_00_00,
                }
            }
            Message::Home { axes } => {
                if axes & 3 == 0 {
                    return nak(NakCode::BadArgument);
                }
                if self.fault != FaultCode::None {
                    return nak(NakCode::Faulted);
                }
                if stage.is_busy() {
                    return nak(NakCode::Busy);
                }
                stage.start_home(crate::stage::HomingCycle::NATIVE);
                Message::Ack
            }
            Message::MoveAbs {
                x_nm,
                y_nm,
                speed_um_s,
            } => match self.motion_check(stage) {
                Some(c) => nak(c),
                None => self.start_move(
                    stage,
                    [x_nm as f64 / 1000.0, y_nm as f64 / 1000.0],
                    speed_um_s,
                ),
            },
            Message::MoveRel {
                dx_nm,
                dy_nm,
                speed_um_s,
            } => match self.motion_check(stage) {
                Some(c) => nak(c),
                None => {
                    let t = [
                        stage.logical(0) + dx_nm as f64 / 1000.0,
                        stage.logical(1) + dy_nm as f64 / 1000.0,
                    ];
                    self.start_move(stage, t, speed_um_s)
                }
            },
            Message::Jog {
                vx_um_s,
                vy_um_s,
                max_ms,
            } => {
                if max_ms == 0 || max_ms > 60_000 {
                    return nak(NakCode::BadArgument);
                }
                match self.motion_check(stage) {
                    Some(c) => nak(c),
                    None => {
                        let v = [vx_um_s as f64, vy_um_s as f64];
                        let s = (v[0] * v[0] + v[1] * v[1]).sqrt();
                        let k = if s > self.max_speed {
                            self.max_speed / s
                        } else {
                            1.0
                        };
                        stage.start_jog([v[0] * k, v[1] * k], self.soft, max_ms as f64 / 1000.0);
                        Message::Ack
                    }
                }
            }
            Message::Stop => {
                stage.stop();
                Message::Ack
            }
            Message::EStop => {
                stage.halt();
                stage.lose_reference();
                self.fault = FaultCode::EStop;
                Message::Ack
            }
            Message::Status => Message::StatusReply(self.status(stage)),
            Message::GetSetting { id } => match SettingId::from_u8(id) {
                Some(s) => Message::SettingValue {
                    id,
                    value: self.setting(stage, s),
                },
                None => nak(NakCode::UnknownSetting),
            },
            Message::SetSetting { id, value } => match SettingId::from_u8(id) {
                Some(s) => {
                    if stage.is_busy() {
                        return nak(NakCode::Busy);
                    }
                    self.set_setting(stage, s, value)
                }
                None => nak(NakCode::UnknownSetting),
            },
            Message::Trigger {
                mode,
                delay_us,
                pulse_us,
            } => {
                if pulse_us == 0 {
                    return nak(NakCode::BadArgument);
                }
                let d = delay_us as f64 / 1e6;
                match mode {
                    0 => self.trigger_at = Some(stage.t + d),
                    1 => self.trigger_armed_delay = Some(d),
                    _ => return nak(NakCode::BadArgument),
                }
                Message::Ack
            }
            Message::ClearFault => {
                if self.fault != FaultCode::None {
                    self.fault = FaultCode::None;
                    stage.lose_reference();
                }
                Message::Ack
            }
            _ => nak(NakCode::UnknownCommand),
        }
    }

    /// Bytes from the host.
    pub fn on_bytes(&mut self, bytes: &[u8], stage: &mut Stage, out: &mut Vec<u8>) {
        for &b in bytes {
            match self.dec.push(b) {
                Some(Ok(Frame { seq, msg })) if msg.is_request() => {
                    let reply = self.handle(msg, stage);
                    self.send(seq, reply, out);
                }
                // Replies and events from the host are nonsense; ignore like garbage.
                Some(Ok(_)) | Some(Err(_)) => self.bad_frames += 1,
                None => {}
            }
        }
    }

    pub fn next_event_time(&self) -> Option<f64> {
        self.trigger_at
    }

    pub fn on_time(&mut self, stage: &Stage, out: &mut Vec<u8>) {
        if let Some(t) = self.trigger_at {
            if stage.t >= t {
                self.trigger_at = None;
                self.trigger_count += 1;
                let count = self.trigger_count;
                self.event(Message::TriggerFired { count }, out);
            }
        }
    }

    pub fn on_event(&mut self, ev: StageEvent, stage: &mut Stage, out: &mut Vec<u8>) {
        let (x_nm, y_nm) = Self::pos_nm(stage);
        match ev {
            StageEvent::MotionDone(MotionKind::Dwell) => {}
            StageEvent::MotionDone(_) | StageEvent::Homed => {
                if let Some(d) = self.trigger_armed_delay.take() {
                    self.trigger_at = Some(stage.t + d);
                }
                self.event(Message::MotionDone { x_nm, y_nm }, out);
            }
            StageEvent::Faulted(StopCause::Limit { switches }) => {
                self.fault = FaultCode::Limit;
                stage.lose_reference();
                self.event(
                    Message::LimitHit {
                        switches,
                        x_nm,
                        y_nm,
                    },
                    out,
                );
            }
            StageEvent::Faulted(c) => {
                self.fault = if matches!(c, StopCause::EStop) {
                    FaultCode::EStop
                } else {
                    FaultCode::FollowingError
                };
                stage.lose_reference();
                self.event(
                    Message::Fault {
                        code: self.fault,
                        x_nm,
                        y_nm,
                    },
                    out,
                );
            }
            StageEvent::Reset => {
                // A reset forgets everything: the handshake, the settings, the reference.
                let serial = self.serial;
                stage.power_on_reference();
                let reported = std::mem::take(&mut self.reported);
                *self = NativeFirmware::new(stage, serial);
                self.reported = reported;
                self.event(Message::Reset { cause: 2 }, out);
            }
            StageEvent::Disconnect => {}
        }
    }
}
