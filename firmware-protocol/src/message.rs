//! The messages of PROTOCOL.md, with their kinds and body layouts.

/// One decoded frame: the message and its sequence number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame {
    /// Request number (copied into the reply) or event counter.
    pub seq: u8,
    pub msg: Message,
}

/// Axis bits for [`Message::Home`].
pub const AXIS_X: u8 = 1;
pub const AXIS_Y: u8 = 2;

/// Every message of the protocol. Requests, replies and events share one enum so that one
/// decoder serves both ends of the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Message {
    // Requests.
    Hello {
        version: u16,
    },
    Identify,
    Home {
        axes: u8,
    },
    MoveAbs {
        x_nm: i32,
        y_nm: i32,
        speed_um_s: u32,
    },
    MoveRel {
        dx_nm: i32,
        dy_nm: i32,
        speed_um_s: u32,
    },
    Jog {
        vx_um_s: i32,
        vy_um_s: i32,
        max_ms: u32,
    },
    Stop,
    EStop,
    Status,
    GetSetting {
        id: u8,
    },
    SetSetting {
        id: u8,
        value: i32,
    },
    Trigger {
        mode: u8,
        delay_us: u32,
        pulse_us: u32,
    },
    ClearFault,
    // Replies.
    Ack,
    Nak {
        code: NakCode,
    },
    HelloReply {
        version: u16,
    },
    Identity {
        model: [u8; 16],
        serial: u32,
        firmware: u32,
    },
    StatusReply(StatusReport),
    SettingValue {
        id: u8,
        value: i32,
    },
    // Events.
    MotionDone {
        x_nm: i32,
        y_nm: i32,
    },
    LimitHit {
        switches: u8,
        x_nm: i32,
        y_nm: i32,
    },
    Fault {
        code: FaultCode,
        x_nm: i32,
        y_nm: i32,
    },
    Reset {
        cause: u8,
    },
    TriggerFired {
        count: u32,
    },
}

/// The body of a [`Message::StatusReply`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StatusReport {
    pub state: State,
    pub flags: u8,
    pub fault: FaultCode,
    pub x_nm: i32,
    pub y_nm: i32,
}

/// Status flag bits.
pub mod flags {
    pub const HOMED: u8 = 1 << 0;
    pub const LIMIT_X_MIN: u8 = 1 << 1;
    pub const LIMIT_X_MAX: u8 = 1 << 2;
    pub const LIMIT_Y_MIN: u8 = 1 << 3;
    pub const LIMIT_Y_MAX: u8 = 1 << 4;
    pub const TRIGGER_ARMED: u8 = 1 << 5;
    pub const ANY_LIMIT: u8 = LIMIT_X_MIN | LIMIT_X_MAX | LIMIT_Y_MIN | LIMIT_Y_MAX;
}

macro_rules! byte_enum {
    ($(#[$m:meta])* $name:ident { $($(#[$vm:meta])* $var:ident = $val:expr),+ $(,)? }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[repr(u8)]
        pub enum $name { $($(#[$vm])* $var = $val),+ }
        impl $name {
            pub fn from_u8(v: u8) -> Option<Self> {
                match v { $($val => Some(Self::$var),)+ _ => None }
            }
            /// Every value, in code order.
            pub const ALL: &'static [Self] = &[$(Self::$var),+];
        }
    };
}

byte_enum!(
    /// Controller state in [`StatusReport`].
    State { Idle = 0, Moving = 1, Homing = 2, Jogging = 3, Fault = 4, Unhomed = 5 }
);
byte_enum!(
    /// Why a request was refused.
    NakCode {
        UnknownCommand = 1, BadArgument = 2, Busy = 3, NotHomed = 4, OutOfLimits = 5,
        Faulted = 6, Version = 7, ReadOnly = 8, UnknownSetting = 9,
    }
);
byte_enum!(
    /// Why the controller is in [`State::Fault`]; `None` when it is not.
    FaultCode { None = 0, EStop = 1, Limit = 2, FollowingError = 3, Reset = 4 }
);
byte_enum!(
    /// Setting ids (PROTOCOL.md, "Settings").
    SettingId {
        SoftMinX = 1, SoftMaxX = 2, SoftMinY = 3, SoftMaxY = 4, MaxSpeed = 5, Accel = 6,
        BacklashX = 7, BacklashY = 8, StepNm = 9, TravelX = 10, TravelY = 11,
        FollowingTolerance = 12,
    }
);

impl SettingId {
    pub fn read_only(self) -> bool {
        matches!(self, Self::StepNm | Self::TravelX | Self::TravelY)
    }
}

impl Message {
    /// The kind byte of this message.
    pub fn kind(&self) -> u8 {
        match self {
            Message::Hello { .. } => 0x01,
            Message::Identify => 0x02,
            Message::Home { .. } => 0x03,
            Message::MoveAbs { .. } => 0x04,
            Message::MoveRel { .. } => 0x05,
            Message::Jog { .. } => 0x06,
            Message::Stop => 0x07,
            Message::EStop => 0x08,
            Message::Status => 0x09,
            Message::GetSetting { .. } => 0x0A,
            Message::SetSetting { .. } => 0x0B,
            Message::Trigger { .. } => 0x0C,
            Message::ClearFault => 0x0D,
            Message::Ack => 0x80,
            Message::Nak { .. } => 0x81,
            Message::HelloReply { .. } => 0x82,
            Message::Identity { .. } => 0x83,
            Message::StatusReply(_) => 0x84,
            Message::SettingValue { .. } => 0x85,
            Message::MotionDone { .. } => 0xC0,
            Message::LimitHit { .. } => 0xC1,
            Message::Fault { .. } => 0xC2,
            Message::Reset { .. } => 0xC3,
            Message::TriggerFired { .. } => 0xC4,
        }
    }

    /// Requests go host → controller.
    pub fn is_request(&self) -> bool {
        self.kind() < 0x80
    }

    /// Events are unsolicited; their `seq` is the controller's event counter.
    pub fn is_event(&self) -> bool {
        self.kind() >= 0xC0
    }

    /// Writes the body into `w`.
    pub(crate) fn write_body(&self, w: &mut Writer<'_>) -> Option<()> {
        match *self {
            Message::Hello { version } | Message::HelloReply { version } => w.u16(version),
            Message::Identify
            | Message::Stop
            | Message::EStop
            | Message::Status
            | Message::ClearFault
            | Message::Ack => Some(()),
            Message::Home { axes } => w.u8(axes),
            Message::MoveAbs {
                x_nm,
                y_nm,
                speed_um_s,
            } => {
                w.i32(x_nm)?;
                w.i32(y_nm)?;
                w.u32(speed_um_s)
            }
            Message::MoveRel {
                dx_nm,
                dy_nm,
                speed_um_s,
            } => {
                w.i32(dx_nm)?;
                w.i32(dy_nm)?;
                w.u32(speed_um_s)
            }
            Message::Jog {
                vx_um_s,
                vy_um_s,
                max_ms,
            } => {
                w.i32(vx_um_s)?;
                w.i32(vy_um_s)?;
                w.u32(max_ms)
            }
            Message::GetSetting { id } => w.u8(id),
            Message::SetSetting { id, value } | Message::SettingValue { id, value } => {
                w.u8(id)?;
                w.i32(value)
            }
            Message::Trigger {
                mode,
                delay_us,
                pulse_us,
            } => {
                w.u8(mode)?;
                w.u32(delay_us)?;
                w.u32(pulse_us)
            }
            Message::Nak { code } => w.u8(code as u8),
            Message::Identity {
                model,
                serial,
                firmware,
            } => {
                w.bytes(&model)?;
                w.u32(serial)?;
                w.u32(firmware)
            }
            Message::StatusReply(s) => {
                w.u8(s.state as u8)?;
                w.u8(s.flags)?;
                w.u8(s.fault as u8)?;
                w.i32(s.x_nm)?;
                w.i32(s.y_nm)
            }
            Message::MotionDone { x_nm, y_nm } => {
                w.i32(x_nm)?;
                w.i32(y_nm)
            }
            Message::LimitHit {
                switches,
                x_nm,
                y_nm,
            } => {
                w.u8(switches)?;
                w.i32(x_nm)?;
                w.i32(y_nm)
            }
            Message::Fault { code, x_nm, y_nm } => {
                w.u8(code as u8)?;
                w.i32(x_nm)?;
                w.i32(y_nm)
            }
            Message::Reset { cause } => w.u8(cause),
            Message::TriggerFired { count } => w.u32(count),
        }
    }

    /// Parses a body of the given kind. `None` for an unknown kind, a wrong length or a
    /// field value outside its enumeration.
    pub(crate) fn read_body(kind: u8, body: &[u8]) -> Option<Message> {
        let mut r = Reader { buf: body, pos: 0 };
        let m = match kind {
            0x01 => Message::Hello { version: r.u16()? },
            0x02 => Message::Identify,
            0x03 => Message::Home { axes: r.u8()? },
            0x04 => Message::MoveAbs {
                x_nm: r.i32()?,
                y_nm: r.i32()?,
                speed_um_s: r.u32()?,
            },
            0x05 => Message::MoveRel {
                dx_nm: r.i32()?,
                dy_nm: r.i32()?,
                speed_um_s: r.u32()?,
            },
            0x06 => Message::Jog {
                vx_um_s: r.i32()?,
                vy_um_s: r.i32()?,
                max_ms: r.u32()?,
            },
            0x07 => Message::Stop,
            0x08 => Message::EStop,
            0x09 => Message::Status,
            0x0A => Message::GetSetting { id: r.u8()? },
            0x0B => Message::SetSetting {
                id: r.u8()?,
                value: r.i32()?,
            },
            0x0C => Message::Trigger {
                mode: r.u8()?,
                delay_us: r.u32()?,
                pulse_us: r.u32()?,
            },
            0x0D => Message::ClearFault,
            0x80 => Message::Ack,
            0x81 => Message::Nak {
                code: NakCode::from_u8(r.u8()?)?,
            },
            0x82 => Message::HelloReply { version: r.u16()? },
            0x83 => {
                let mut model = [0u8; 16];
                model.copy_from_slice(r.take(16)?);
                Message::Identity {
                    model,
                    serial: r.u32()?,
                    firmware: r.u32()?,
                }
            }
            0x84 => Message::StatusReply(StatusReport {
                state: State::from_u8(r.u8()?)?,
                flags: r.u8()?,
                fault: FaultCode::from_u8(r.u8()?)?,
                x_nm: r.i32()?,
                y_nm: r.i32()?,
            }),
            0x85 => Message::SettingValue {
                id: r.u8()?,
                value: r.i32()?,
            },
            0xC0 => Message::MotionDone {
                x_nm: r.i32()?,
                y_nm: r.i32()?,
            },
            0xC1 => Message::LimitHit {
                switches: r.u8()?,
                x_nm: r.i32()?,
                y_nm: r.i32()?,
            },
            0xC2 => Message::Fault {
                code: FaultCode::from_u8(r.u8()?)?,
                x_nm: r.i32()?,
                y_nm: r.i32()?,
            },
            0xC3 => Message::Reset { cause: r.u8()? },
            0xC4 => Message::TriggerFired { count: r.u32()? },
            _ => return None,
        };
        if r.pos != body.len() {
            return None;
        }
        Some(m)
    }
}

pub(crate) struct Writer<'a> {
    pub buf: &'a mut [u8],
    pub pos: usize,
}

impl Writer<'_> {
    pub fn bytes(&mut self, b: &[u8]) -> Option<()> {
        let end = self.pos.checked_add(b.len())?;
        self.buf.get_mut(self.pos..end)?.copy_from_slice(b);
        self.pos = end;
        Some(())
    }
    pub fn u8(&mut self, v: u8) -> Option<()> {
        self.bytes(&[v])
    }
    pub fn u16(&mut self, v: u16) -> Option<()> {
        self.bytes(&v.to_le_bytes())
    }
    pub fn u32(&mut self, v: u32) -> Option<()> {
        self.bytes(&v.to_le_bytes())
    }
    pub fn i32(&mut self, v: i32) -> Option<()> {
        self.bytes(&v.to_le_bytes())
    }
}

struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let s = self.buf.get(self.pos..self.pos.checked_add(n)?)?;
        self.pos += n;
        Some(s)
    }
    fn u8(&mut self) -> Option<u8> {
        Some(self.take(1)?[0])
    }
    fn u16(&mut self) -> Option<u16> {
        Some(u16::from_le_bytes(self.take(2)?.try_into().ok()?))
    }
    fn u32(&mut self) -> Option<u32> {
        Some(u32::from_le_bytes(self.take(4)?.try_into().ok()?))
    }
    fn i32(&mut self) -> Option<i32> {
        Some(i32::from_le_bytes(self.take(4)?.try_into().ok()?))
    }
}
