//! What the hardware thread and the work it runs share: the devices, how a running item is
//! interrupted, how a run ends, the live frame, the settings the work is checked against, and
//! what an item runs with (`Rig`).

use super::events::{Bus, Kind};
use super::queue::ItemId;
use crate::camera::Camera;
use crate::coords::CarriageUm;
use crate::stage::{Stage, StageError};
use serde::Serialize;
use serde_json::json;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// The devices the service holds, and what closes them (the simulator writes its truth).
pub struct Devices {
    pub stage: Box<dyn Stage>,
    pub camera: Box<dyn Camera>,
    /// The simulator's own certificates (TOML), for calibration items that name none.
    pub certificates: SimCertificates,
    /// The simulator's film: laid on the carriage (true) or lifted off, as an operator's hands
    /// do between a calibration on the plate and a scan. None on real hardware, whose film the
    /// service never sees.
    pub sim_film: Option<Arc<AtomicBool>>,
    pub close: Box<dyn FnOnce() -> Result<(), String>>,
}

/// What the service says of a stage that is not homed: the stage's own text names a command
/// line (`rig stage home`); here the remedy is an item.
pub const NOT_HOMED: &str =
    "the stage is not homed (after a start, a halt or a reset): queue a home item first";

/// The simulator's plate and camera certificates; empty on real hardware.
#[derive(Debug, Clone, Default)]
pub struct SimCertificates {
    pub plate: Option<String>,
    pub camera: Option<String>,
}

/// Opens the devices on the hardware thread, given the flag that cancels a stage wait and the
/// listener to every position the controller reports (position events during a motion).
pub type Opener = Box<
    dyn FnOnce(Arc<AtomicBool>, crate::stage::port::PositionSink) -> Result<Devices, String> + Send,
>;

/// What the operator asked of the running item.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Interrupt {
    /// Pause at the next tile (deferred).
    Pause,
    /// End the item at the next tile, done.
    Stop,
    /// Pause now: feed hold; the tile being taken is taken again on resume.
    PauseNow,
    /// Stop the stages now; the item goes back to the front for a new attempt.
    Abort,
    /// Reset the controller now.
    Halt,
}

/// How the running item is interrupted from outside the hardware thread.
pub struct Control {
    /// Seen by the scan at each tile boundary.
    pub pause: AtomicBool,
    /// Cancels the stage's current wait (the driver stops the stages).
    cancel: Arc<AtomicBool>,
    wanted: Mutex<Option<Interrupt>>,
}

impl Control {
    pub(super) fn new(cancel: Arc<AtomicBool>) -> Control {
        Control {
            pause: AtomicBool::new(false),
            cancel,
            wanted: Mutex::new(None),
        }
    }

    /// Asks the running item to be interrupted; the stronger of two requests wins (a halt
    /// after a pause is a halt).
    pub fn interrupt(&self, i: Interrupt) {
        let mut w = self.wanted.lock().unwrap_or_else(|e| e.into_inner());
        *w = Some(w.map_or(i, |old| old.max(i)));
        self.pause.store(true, Ordering::SeqCst);
        if i >= Interrupt::PauseNow {
            self.cancel.store(true, Ordering::SeqCst);
        }
    }

    /// What was asked, clearing every flag for the next item.
    pub(super) fn take(&self) -> Option<Interrupt> {
        self.pause.store(false, Ordering::SeqCst);
        self.cancel.store(false, Ordering::SeqCst);
        self.wanted.lock().unwrap_or_else(|e| e.into_inner()).take()
    }
}

#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    #[error(transparent)]
    Stage(#[from] StageError),
    #[error(transparent)]
    Camera(#[from] crate::camera::CameraError),
    #[error(transparent)]
    Capture(#[from] crate::digitise::CaptureError),
    #[error("the hardware is busy with item {0}: pause it or wait")]
    Busy(ItemId),
    #[error("the hardware thread has ended")]
    Gone,
    #[error("there is no simulated film here: on a real rig the operator lays and lifts the film by hand")]
    NotSimulated,
    #[error("{0}")]
    Other(String),
}

/// How a run of an item ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Ended {
    Done,
    Failed,
    /// Paused (deferred or at once); running it again continues it.
    Paused,
    Stopped,
    Aborted,
    Halted,
}

#[derive(Debug, Clone)]
pub struct Ran {
    pub ended: Ended,
    pub message: Option<String>,
    pub result: Option<serde_json::Value>,
}

/// A frame for the live view: PNG bytes, its number and when it was taken.
#[derive(Debug, Clone)]
pub struct Look {
    pub png: Arc<Vec<u8>>,
    pub number: u64,
    /// The image's own size (width, height), camera px: the PNG may be smaller.
    pub size: [usize; 2],
    pub taken: std::time::Instant,
}

/// Where the work's files go and what it is checked against.
#[derive(Debug, Clone)]
pub struct Settings {
    /// Calibration sessions (`rig calibrate --store`).
    pub store: PathBuf,
    /// The operator's soft limits (intersected with the controller's).
    pub limits: Option<crate::stage::SoftLimits>,
    pub max_memory_mib: u64,
    /// Frames averaged for a live frame.
    pub look_frames: u32,
    /// The hardware is the simulator (its certificates stand in for ones not given).
    pub sim: bool,
    /// Where certificates named by items are (`--certificates`); none: only the simulator's.
    pub certificates: Option<PathBuf>,
}

pub fn position_json(p: CarriageUm) -> serde_json::Value {
    json!({"x_mm": p.x_mm(), "y_mm": p.y_mm()})
}

/// The operator's 8-bit look at an image, as PNG bytes (at most 800 px across).
pub fn png_of(img: &crate::digitise::ImageF32) -> image::ImageResult<Vec<u8>> {
    let (w, h, grey) = crate::digitise::look8(img.width, img.height, 800, |i| img.data[i]);
    let mut out = std::io::Cursor::new(Vec::new());
    image::write_buffer_with_format(
        &mut out,
        &grey,
        w as u32,
        h as u32,
        image::ExtendedColorType::L8,
        image::ImageFormat::Png,
    )?;
    Ok(out.into_inner())
}

/// What an item runs with on the hardware thread.
pub struct Rig<'a> {
    pub dev: &'a mut Devices,
    pub bus: &'a Bus,
    pub control: &'a Control,
    pub settings: &'a Settings,
    pub last_look: &'a Mutex<Option<Look>>,
}

/// `img` as the live view's newest frame, and a preview event naming it (with `what`).
pub fn show(
    bus: &Bus,
    last: &Mutex<Option<Look>>,
    img: &crate::digitise::ImageF32,
    what: serde_json::Value,
) {
    let Ok(png) = super::devices::png_of(img) else {
        return;
    };
    let number = {
        let mut l = last.lock().unwrap_or_else(|e| e.into_inner());
        let n = l.as_ref().map_or(1, |l| l.number + 1);
        *l = Some(Look {
            png: Arc::new(png),
            number: n,
            size: [img.width, img.height],
            taken: std::time::Instant::now(),
        });
        n
    };
    let mut data = json!({"url": format!("/api/v1/live.png?n={number}")});
    if let (Some(d), Some(w)) = (data.as_object_mut(), what.as_object()) {
        d.extend(w.clone());
    }
    bus.publish(Kind::Preview, data);
}
