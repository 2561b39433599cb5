//! The simulated camera, in-process: frames from the simulator's world, looking where its
//! stage really is.

use super::{Camera, CameraInfo, FormatInfo, Frame, Result, SeqTracker};
use rig_sim::frames::FrameSource;
use std::time::Duration;

pub struct SimCamera {
    src: FrameSource,
    seq: SeqTracker,
    gain: Option<f64>,
}

impl SimCamera {
    /// A camera on `world` that loses frames with probability `drop_p`.
    pub fn new(world: std::sync::Arc<rig_sim::World>, drop_p: f64) -> Self {
        SimCamera {
            src: FrameSource::new(world, drop_p),
            seq: SeqTracker::default(),
            gain: None,
        }
    }

    /// The simulator's record of the frames it lost (its truth).
    pub fn truth_dropped(&self) -> &[u64] {
        &self.src.dropped
    }
}

impl Camera for SimCamera {
    fn info(&self) -> CameraInfo {
        let c = self.src.config();
        CameraInfo {
            name: "rig-sim camera".into(),
            driver: "sim".into(),
            width: c.width,
            height: c.height,
            bit_depth: c.bit_depth,
            exposure_ms: Some(c.exposure_ms),
            gain: self.gain,
            frame_rate_hz: Some(c.frame_rate_hz),
        }
    }

    fn formats(&mut self) -> Result<Vec<FormatInfo>> {
        let c = self.src.config();
        Ok(vec![FormatInfo {
            fourcc: "GREY".into(),
            width: c.width,
            height: c.height,
            bit_depth: c.bit_depth,
            refused: None,
        }])
    }

    fn set_exposure_ms(&mut self, ms: f64) -> Result<()> {
        self.src.set_exposure(ms);
        Ok(())
    }

    fn set_gain(&mut self, gain: Option<f64>) -> Result<()> {
        self.gain = gain;
        self.src.set_gain(gain);
        Ok(())
    }

    fn next_frame(&mut self, _timeout: Duration) -> Result<Frame> {
        let f = self.src.next_frame();
        self.seq.see(f.seq);
        Ok(Frame {
            seq: f.seq,
            // The simulator's clock, checked as any device's is.
            timestamp: super::secs(f.t_s).ok_or_else(|| {
                super::CameraError::Io(format!(
                    "the simulator's frame time {} s is no clock reading",
                    f.t_s
                ))
            })?,
            width: f.width,
            height: f.height,
            bit_depth: f.bit_depth,
            data: f.data,
        })
    }

    fn now(&mut self) -> Result<Duration> {
        let t = self.src.now_s();
        super::secs(t).ok_or_else(|| {
            super::CameraError::Io(format!("the simulator's clock {t} s is no clock reading"))
        })
    }

    fn dropped(&self) -> u64 {
        self.seq.dropped
    }
}
