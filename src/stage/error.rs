use crate::coords::CarriageUm;
use std::path::PathBuf;
use std::time::Duration;

fn at(p: &Option<CarriageUm>) -> String {
    p.map(|p| format!(" at {p}")).unwrap_or_default()
}

/// Why the controller stopped or refuses to move.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    EmergencyStop,
    /// A limit switch closed (`switches` names them, e.g. "X+").
    LimitSwitch {
        switches: String,
    },
    /// The axis did not follow the motor (stalled or blocked).
    Stall,
    /// The controller reset (power, watchdog, brown-out); its position is lost.
    Reset,
    /// A GRBL alarm, with GRBL's code and meaning.
    Alarm {
        code: u32,
        meaning: String,
    },
    /// The controller reported a position far outside its own travel: a garbled report, a
    /// wrong setting or a lost reference; nothing it says about position can be trusted.
    ImplausiblePosition {
        x_mm: f64,
        y_mm: f64,
        travel_x_mm: f64,
        travel_y_mm: f64,
    },
}

impl std::fmt::Display for FaultKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FaultKind::EmergencyStop => write!(f, "emergency stop"),
            FaultKind::LimitSwitch { switches } if switches.is_empty() => {
                write!(f, "a limit switch tripped (open again now)")
            }
            FaultKind::LimitSwitch { switches } => write!(f, "limit switch {switches} closed"),
            FaultKind::Stall => write!(f, "axis stalled (following error)"),
            FaultKind::Reset => write!(f, "controller reset"),
            FaultKind::Alarm { code, meaning } => write!(f, "ALARM:{code} ({meaning})"),
            FaultKind::ImplausiblePosition {
                x_mm,
                y_mm,
                travel_x_mm,
                travel_y_mm,
            } => write!(
                f,
                "the controller reports X {x_mm:.3} Y {y_mm:.3} mm, far outside its travel \
                 0..{travel_x_mm} x 0..{travel_y_mm} mm (a garbled report, a wrong travel or \
                 homing setting, or a lost reference)"
            ),
        }
    }
}

/// Errors of the stage drivers. Every motion error has already stopped the stages (as far as
/// the link allows) when it is returned.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    #[error("cannot open stage port {path}: {source}")]
    Open {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "stage port {path} is in use by another program; close it (or stop the other rig) first"
    )]
    PortBusy { path: PathBuf },
    #[error("the link to the stage controller is gone ({0}); check the cable and power, then home again")]
    Disconnected(String),
    #[error("no answer from the stage controller to {what} within {after:?}")]
    Timeout { what: String, after: Duration },
    #[error("the stage controller does not speak this protocol: {0}")]
    Protocol(String),
    #[error("protocol version mismatch: host speaks {host}, controller {controller}")]
    Version { host: String, controller: String },
    #[error("the controller refused {command}: {reason}")]
    Rejected { command: String, reason: String },
    #[error("{axis} target {value_mm:.4} mm is outside the soft limits {min_mm:.4}..{max_mm:.4} mm; nothing was sent")]
    OutOfLimits {
        axis: char,
        value_mm: f64,
        min_mm: f64,
        max_mm: f64,
    },
    #[error("the stage is not homed; run `rig stage home` first")]
    NotHomed,
    #[error(
        "stage fault: {kind}; stages stopped{}. Clear the cause, then home again",
        at(position)
    )]
    Fault {
        kind: FaultKind,
        position: Option<CarriageUm>,
    },
    #[error("position check failed: asked for {target}, controller reports {actual} (tolerance {tolerance_um} µm); stages stopped")]
    PositionMismatch {
        target: CarriageUm,
        actual: CarriageUm,
        tolerance_um: f64,
    },
    #[error("cancelled by the operator; stages stopped")]
    Cancelled,
    /// The controller takes no command in the state an earlier program left it in (GRBL in a
    /// feed hold reads no line until resumed or reset; one still moving refuses `$$`).
    #[error(
        "the controller is {state}, as an earlier program left it, and takes no command now. \
         `rig stage stop` brings it to a standstill and soft-resets it (keeping the position when \
         it stands still); then connect again"
    )]
    NotReady { state: String },
    #[error("motion did not finish within {after:?} (its expected duration with margin); stages stopped")]
    MotionTimeout { after: Duration },
    #[error("{dialect} setting {setting} = {value} is outside the allowed range {allowed}; nothing was moved. Fix it on the controller ({fix}), then connect again")]
    BadSetting {
        dialect: &'static str,
        setting: String,
        value: String,
        allowed: String,
        fix: String,
    },
    /// The stop that should have followed `cause` was not confirmed: the stages may still be
    /// moving. Never reported as stopped.
    #[error("{} — and the stop was NOT confirmed: {why}. The stages may still be moving: use the emergency stop switch", unstopped(cause))]
    StopFailed { cause: Box<StageError>, why: String },
}

/// What `e` says, without its claim that the stages were stopped.
fn unstopped(e: &StageError) -> String {
    e.to_string()
        .replace("; stages stopped", "")
        .replace(", stages stopped", "")
        .replace(" stages stopped", "")
}

impl StageError {
    /// Exit code for the `rig` command (docs/cli.md, "Exit codes").
    pub fn exit_code(&self) -> i32 {
        use crate::exit;
        match self {
            StageError::OutOfLimits { .. } => exit::OUTSIDE_LIMITS,
            StageError::Timeout { .. } | StageError::MotionTimeout { .. } => exit::TIMEOUT,
            StageError::Fault { .. } | StageError::NotHomed | StageError::NotReady { .. } => {
                exit::FAULT
            }
            StageError::PositionMismatch { .. } => exit::POSITION,
            StageError::Open { .. } | StageError::PortBusy { .. } | StageError::Disconnected(_) => {
                exit::PORT
            }
            StageError::Rejected { .. }
            | StageError::Protocol(_)
            | StageError::Version { .. }
            | StageError::BadSetting { .. } => exit::REFUSED,
            StageError::Cancelled => exit::INTERRUPTED,
            // The worst outcome: the motion may go on. Its own code, so scripts cannot take it
            // for the error that caused the stop.
            StageError::StopFailed { .. } => exit::STOP_NOT_CONFIRMED,
        }
    }

    /// A short, stable name for `--json` output and logs.
    pub fn kind(&self) -> &'static str {
        match self {
            StageError::Open { .. } => "open",
            StageError::PortBusy { .. } => "port_busy",
            StageError::Disconnected(_) => "disconnected",
            StageError::Timeout { .. } => "timeout",
            StageError::Protocol(_) => "protocol",
            StageError::Version { .. } => "version",
            StageError::Rejected { .. } => "rejected",
            StageError::OutOfLimits { .. } => "out_of_limits",
            StageError::NotHomed => "not_homed",
            StageError::Fault { .. } => "fault",
            StageError::PositionMismatch { .. } => "position_mismatch",
            StageError::MotionTimeout { .. } => "motion_timeout",
            StageError::Cancelled => "cancelled",
            StageError::NotReady { .. } => "not_ready",
            StageError::BadSetting { .. } => "bad_setting",
            StageError::StopFailed { .. } => "stop_failed",
        }
    }
}

pub type Result<T, E = StageError> = std::result::Result<T, E>;
