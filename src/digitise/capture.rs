//! One measured picture: N frames from a camera, averaged, the stripe noise removed. What a
//! calibration or a scan takes at each stage position.

use super::{average_frames, estimate_stripes, remove_stripes, Averaged, ImageF32, StripeEstimate};
use crate::camera::{Camera, CameraError};
use std::time::Duration;

#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    #[error(transparent)]
    Camera(#[from] CameraError),
    #[error("frame {seq} is {got_w}×{got_h}, the camera said {want_w}×{want_h}")]
    Size {
        seq: u64,
        got_w: usize,
        got_h: usize,
        want_w: usize,
        want_h: usize,
    },
    #[error(transparent)]
    Digitise(#[from] super::DigitiseError),
}

#[derive(Debug, Clone)]
pub struct Captured {
    /// The filtered mean (DN of the source bit depth).
    pub image: ImageF32,
    pub averaged: Averaged,
    pub stripes: Option<StripeEstimate>,
    /// Frames the camera dropped while these were taken.
    pub dropped: u64,
}

/// Takes `frames` frames (each within `timeout`), averages them and, with `filter`, removes the
/// field shift and the column pattern. `progress(i)` is called after each frame.
pub fn capture(
    cam: &mut dyn Camera,
    frames: u32,
    filter: bool,
    timeout: Duration,
    mut progress: impl FnMut(u32),
) -> Result<Captured, CaptureError> {
    let info = cam.info();
    let dropped0 = cam.dropped();
    let mut kept: Vec<Vec<u16>> = Vec::with_capacity(frames as usize);
    for i in 0..frames {
        let f = cam.next_frame(timeout)?;
        if (f.width, f.height) != (info.width, info.height) {
            return Err(CaptureError::Size {
                seq: f.seq,
                got_w: f.width,
                got_h: f.height,
                want_w: info.width,
                want_h: info.height,
            });
        }
        kept.push(f.data);
        progress(i + 1);
    }
    let refs: Vec<&[u16]> = kept.iter().map(|f| f.as_slice()).collect();
    let averaged = average_frames(info.width, info.height, &refs)?;
    let mut image = averaged.mean.clone();
    let stripes = filter.then(|| {
        let e = estimate_stripes(&image);
        remove_stripes(&mut image, &e);
        e
    });
    Ok(Captured {
        image,
        averaged,
        stripes,
        dropped: cam.dropped() - dropped0,
    })
}
