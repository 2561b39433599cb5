//! The camera layer: a small [`Camera`] trait (Micro-Manager-like: open, formats, exposure,
//! gain, a stream of numbered, time-stamped frames, dropped frames counted), with the simulated
//! camera here and the V4L2 backend behind the `v4l2` feature.

pub mod convert;
mod sim;
pub mod socket;
#[cfg(feature = "v4l2")]
pub mod v4l2;

pub use sim::SimCamera;

use std::time::Duration;

/// One greyscale frame.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The driver's sequence number; a gap means frames were dropped.
    pub seq: u64,
    /// Time since the stream started (the device's clock where it has one).
    pub timestamp: Duration,
    pub width: usize,
    pub height: usize,
    /// Significant bits per pixel (8, 10, 12 or 16), stored in a u16 each.
    pub bit_depth: u32,
    pub data: Vec<u16>,
}

/// A pixel format the device offers, and whether the rig can measure with it.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FormatInfo {
    pub fourcc: String,
    pub width: usize,
    pub height: usize,
    pub bit_depth: u32,
    /// `None` if usable for measurement; otherwise why not (lossy compression, colour only…).
    pub refused: Option<String>,
}

#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct CameraInfo {
    pub name: String,
    pub driver: String,
    pub width: usize,
    pub height: usize,
    pub bit_depth: u32,
    pub exposure_ms: Option<f64>,
    /// `None` = automatic gain.
    pub gain: Option<f64>,
    /// Frames per second, where the device says (a scan's time estimate uses it).
    pub frame_rate_hz: Option<f64>,
}

#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    #[error("cannot open camera {device}: {why}")]
    Open { device: String, why: String },
    #[error("camera {device} offers no format the rig can measure with: {why}")]
    NoUsableFormat { device: String, why: String },
    #[error("no frame within {0:?}")]
    Timeout(Duration),
    #[error("camera error: {0}")]
    Io(String),
    #[error("{0} is not supported by this camera")]
    Unsupported(&'static str),
}

pub type Result<T, E = CameraError> = std::result::Result<T, E>;

/// What the rest of the rig uses to take pictures.
pub trait Camera {
    fn info(&self) -> CameraInfo;
    fn formats(&mut self) -> Result<Vec<FormatInfo>>;
    fn set_exposure_ms(&mut self, ms: f64) -> Result<()>;
    /// `None` = automatic gain.
    fn set_gain(&mut self, gain: Option<f64>) -> Result<()>;
    /// The next frame of the stream (the stream starts on first use). Streams are buffered:
    /// a frame may have been captured well before it is handed out (while the stage was still
    /// moving); its `timestamp` says when.
    fn next_frame(&mut self, timeout: Duration) -> Result<Frame>;
    /// The current time on the clock of the frames' timestamps (V4L2: the host's monotonic
    /// clock), so that frames captured before a moment can be told apart.
    fn now(&mut self) -> Result<Duration>;
    /// Frames missing from the sequence so far.
    fn dropped(&self) -> u64;
}

pub use crate::seconds::clock as secs;

/// Counts gaps in a stream's sequence numbers.
#[derive(Debug, Default, Clone)]
pub struct SeqTracker {
    last: Option<u64>,
    pub dropped: u64,
}

impl SeqTracker {
    /// Records `seq`; returns how many frames were missing just before it.
    pub fn see(&mut self, seq: u64) -> u64 {
        let gap = match self.last {
            Some(l) if seq > l + 1 => seq - l - 1,
            _ => 0,
        };
        self.dropped += gap;
        self.last = Some(seq);
        gap
    }
}

#[cfg(test)]
mod tests {
    use super::SeqTracker;

    #[test]
    fn gaps_are_counted() {
        let mut t = SeqTracker::default();
        assert_eq!([5, 6, 9, 10, 12].map(|s| t.see(s)), [0, 0, 2, 0, 1]);
        assert_eq!(t.dropped, 3);
    }
}
