//! The stage driver layer: a small [`Stage`] trait for the rest of the rig, and serial clients
//! for the rig's own firmware protocol ([`native`]) and for GRBL 1.1 ([`grbl`]).
//!
//! Each dialect implements the low-level [`Controller`] trait (send a move, wait for the end of
//! motion, read the status); the safety policy lives once, in [`Driver`]: soft limits checked
//! on the host before anything is sent, the one-direction approach that takes out backlash, a
//! timeout on every wait computed from distance, speed and acceleration, the position verified
//! after each move, and the stages stopped on any fault.

mod driver;
mod error;
pub mod grbl;
mod limits_check;
mod motion;
pub mod native;
pub mod port;

pub use driver::{Driver, DriverOptions};
pub use error::{FaultKind, Result, StageError};
pub use motion::{move_duration, secs, Approach, SoftLimits, TimeoutPolicy};
pub use port::{LinkOptions, Port, BUSY_GRACE};

use crate::coords::CarriageUm;
use serde::Serialize;
use std::path::Path;
use std::time::Duration;

/// What the controller is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StageState {
    Idle,
    Moving,
    Homing,
    Jogging,
    /// Decelerating or paused by a feed hold (GRBL).
    Holding,
    /// Idle without a position reference: home before moving.
    Unhomed,
    /// Stopped by a fault or alarm: clear it and home.
    Fault,
}

impl StageState {
    pub fn is_moving(self) -> bool {
        matches!(
            self,
            StageState::Moving | StageState::Homing | StageState::Jogging | StageState::Holding
        )
    }
}

/// One status reading.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StageStatus {
    pub state: StageState,
    pub position: CarriageUm,
    pub homed: bool,
    /// Closed limit switches, e.g. "X-" or "XY"; empty when none.
    pub limit_switches: String,
    pub fault: Option<FaultKind>,
    /// The controller's own words for its state (`Idle`, `Hold:0`, `Alarm`, …).
    pub controller_state: String,
}

/// What the host learnt about the controller when it connected (sessions record it; fields
/// that older sessions lack read as zero or empty).
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct ControllerInfo {
    pub dialect: String,
    pub identity: String,
    #[serde(default)]
    pub travel: CarriageUm,
    /// The controller's own soft limits, in carriage coordinates.
    pub limits: SoftLimits,
    pub max_speed_um_s: f64,
    pub accel_um_s2: f64,
    #[serde(default)]
    pub home_speed_um_s: f64,
    /// Smallest position increment the controller reports (step or encoder count).
    #[serde(default)]
    pub resolution_um: f64,
    /// Things the operator should know (e.g. the controller's own soft limits are off, or it
    /// was in Alarm when the rig connected).
    #[serde(default)]
    pub notes: Vec<String>,
    /// The longest a homing cycle may take, from the controller's own rates and travel.
    #[serde(default)]
    pub homing_bound_s: f64,
    /// What the controller's set-up should change for the rig (`rig stage check-setup`).
    #[serde(default)]
    pub advice: Vec<SetupAdvice>,
    /// The controller settings the rig uses, as read (name, value and meaning).
    #[serde(default)]
    pub settings: Vec<(String, String)>,
}

/// One change the controller's set-up needs, or would benefit from.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct SetupAdvice {
    pub setting: String,
    pub now: String,
    pub todo: String,
}

/// What a stop did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StopAction {
    /// Nothing was moving (or the controller had already stopped itself in an alarm). GRBL:
    /// still, its hold and any pending commands dropped by a soft reset; position kept.
    Nothing,
    /// A decelerating stop (native Stop; GRBL feed hold to `Hold:0`, then a soft reset that
    /// drops what is left of the motion, the position compared before and after); the position
    /// is kept.
    Decelerated,
    /// The controller did not confirm a decelerating stop in time and was reset, or its reset
    /// lost the position: the motors stopped at once; home again.
    Reset,
    /// A homing cycle was ended by a reset: not homed.
    HomingAborted,
    /// The controller stood still but took no command, as an earlier program left it (GRBL in
    /// a feed hold, or busy with commands it was sent): a soft reset dropped what was pending;
    /// the position is kept.
    Released,
}

impl StopAction {
    pub fn describe(self) -> &'static str {
        match self {
            StopAction::Nothing => "nothing was moving; the controller takes commands",
            StopAction::Decelerated => {
                "decelerated to a stop; position kept; the controller takes commands"
            }
            StopAction::Reset => {
                "the controller did not confirm a controlled stop in time (or its reset lost the \
                 position) and was reset: stopped at once, position lost (home again)"
            }
            StopAction::HomingAborted => "homing cycle ended by a reset: home again",
            StopAction::Released => {
                "the controller stood still but took no command (a feed hold, or commands an \
                 earlier program left); a soft reset dropped them; position kept; the controller \
                 takes commands"
            }
        }
    }
}

/// Where a stop left the carriage, and how it was stopped.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct Stopped {
    pub action: StopAction,
    /// The position after the stop, when the controller still knows it.
    pub position: Option<CarriageUm>,
    /// The fault or alarm the controller is in after it stopped (clear the cause, then home),
    /// if any.
    #[serde(default)]
    pub fault: Option<String>,
}

impl ControllerInfo {
    /// The longest a homing cycle may take: the controller's own bound when it has one, else
    /// a seek over 1.2 × the travel and back at the homing speed.
    pub fn homing_duration(&self) -> Duration {
        if self.homing_bound_s > 0.0 {
            return secs(self.homing_bound_s);
        }
        let far = self.travel.x.max(self.travel.y) * 1.2 + 5000.0;
        move_duration(far, self.home_speed_um_s, self.accel_um_s2) * 2
    }

    /// Before the controller has been asked: nothing known but the dialect.
    pub fn unknown(dialect: &'static str) -> Self {
        ControllerInfo {
            dialect: dialect.into(),
            identity: String::new(),
            travel: CarriageUm::default(),
            limits: SoftLimits {
                min: CarriageUm::default(),
                max: CarriageUm::default(),
            },
            max_speed_um_s: 1.0,
            accel_um_s2: 1.0,
            home_speed_um_s: 1.0,
            resolution_um: 1.0,
            notes: vec![],
            homing_bound_s: 0.0,
            advice: vec![],
            settings: vec![],
        }
    }
}

/// The low-level operations of one controller dialect. Implementations never decide policy:
/// they send, wait and report; [`Driver`] decides.
pub trait Controller {
    fn info(&self) -> &ControllerInfo;
    fn status(&mut self) -> Result<StageStatus>;
    /// Sends a straight move to `target` and returns once the controller accepted it.
    fn start_move(&mut self, target: CarriageUm, speed_um_s: f64) -> Result<()>;
    fn start_home(&mut self) -> Result<()>;
    /// Sends a jog by `delta` (already clipped to the soft limits) at `speed_um_s`.
    fn start_jog(&mut self, delta: CarriageUm, speed_um_s: f64) -> Result<()>;
    /// Waits for the motion to end, up to `timeout`; a fault during the wait is an error.
    fn wait_done(&mut self, timeout: Duration) -> Result<StageStatus>;
    /// Stops whatever moves, escalating until the controller confirms it; says what it did.
    /// An error means the stop was not confirmed.
    fn stop(&mut self) -> Result<StopAction>;
    /// The longest a homing cycle may take (the wait's bound before its margin).
    fn homing_duration(&self) -> Duration {
        self.info().homing_duration()
    }
    /// Immediate stop.
    fn emergency_stop(&mut self) -> Result<()>;
    /// Leaves the fault or alarm state (the stage is then unhomed).
    fn clear_fault(&mut self) -> Result<()>;
}

/// What the rest of the rig uses to move the carriage.
pub trait Stage {
    fn info(&self) -> &ControllerInfo;
    /// The soft limits in force on the host.
    fn limits(&self) -> SoftLimits;
    fn status(&mut self) -> Result<StageStatus>;
    fn position(&mut self) -> Result<CarriageUm> {
        Ok(self.status()?.position)
    }
    /// Homes both axes; returns the position after homing.
    fn home(&mut self) -> Result<CarriageUm>;
    /// Moves to `target`, approached from the configured direction, and returns the verified
    /// position.
    fn move_to(&mut self, target: CarriageUm) -> Result<CarriageUm>;
    fn move_by(&mut self, delta: CarriageUm) -> Result<CarriageUm> {
        let here = self.position()?;
        self.move_to(here + delta)
    }
    /// Jogs by `delta` at `speed_um_s`, clipped to the soft limits (a jog is for looking
    /// around, not for measuring: no approach, no position check).
    fn jog(&mut self, delta: CarriageUm, speed_um_s: f64) -> Result<CarriageUm>;
    /// Stops the stages (decelerating where the controller confirms it, at once where it does
    /// not); says what was done and where the carriage rests. An error: not confirmed.
    fn stop(&mut self) -> Result<Stopped>;
    fn emergency_stop(&mut self) -> Result<()>;
    /// Waits for the current motion to end, with a timeout from the expected duration.
    fn wait_motion(&mut self, expected: Duration) -> Result<StageStatus>;
}

/// The controller dialects the rig speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Dialect {
    /// The rig's own firmware protocol (firmware-protocol/PROTOCOL.md).
    Native,
    /// GRBL 1.1.
    Grbl,
}

/// Opens the controller at `path` (with `link`: wire log, Ctrl-C) and wraps it in the safety
/// [`Driver`]. A controller that takes no command in the state it was left in is refused
/// ([`StageError::NotReady`]), never changed.
pub fn open(
    path: &Path,
    dialect: Dialect,
    opts: DriverOptions,
    link: &LinkOptions,
) -> Result<Box<dyn Stage>> {
    open_as(path, dialect, opts, link, false)
}

/// As [`open`], for stopping (`rig stage stop`, `estop`): a controller left moving, holding or
/// busy by an earlier program is brought to a standstill and made to take commands as it
/// connects (GRBL: feed hold, then a soft reset once still), and the next [`Stage::stop`] says
/// what that did.
pub fn open_to_stop(
    path: &Path,
    dialect: Dialect,
    opts: DriverOptions,
    link: &LinkOptions,
) -> Result<Box<dyn Stage>> {
    open_as(path, dialect, opts, link, true)
}

fn open_as(
    path: &Path,
    dialect: Dialect,
    opts: DriverOptions,
    link: &LinkOptions,
    to_stop: bool,
) -> Result<Box<dyn Stage>> {
    Ok(match dialect {
        Dialect::Native => Box::new(Driver::new(
            native::NativeController::open(path, link)?,
            opts,
        )),
        Dialect::Grbl if to_stop => Box::new(Driver::new(
            grbl::GrblController::open_to_stop(path, link)?,
            opts,
        )),
        Dialect::Grbl => Box::new(Driver::new(grbl::GrblController::open(path, link)?, opts)),
    })
}
