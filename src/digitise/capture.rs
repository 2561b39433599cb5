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
    #[error("{frames} frames of {width}×{height} would hold {mib} MiB in memory; the limit is {limit_mib} MiB (1 to {MAX_FRAMES} frames, fewer for large sensors)")]
    TooMany {
        frames: u32,
        width: usize,
        height: usize,
        mib: u64,
        limit_mib: u64,
    },
    #[error("the camera handed out {stale} frames in a row taken before the stage had settled: its timestamps are not on the clock it reports (a driver without monotonic timestamps?)")]
    NeverFresh { stale: u64 },
}

/// Most frames one average may take.
pub const MAX_FRAMES: u32 = 4096;
/// Most memory the frames of one average may hold.
pub const MAX_FRAME_BYTES: u64 = 4 << 30;
/// Stale frames dropped before giving up: a V4L2 stream holds a handful of buffers, so more
/// than this means the timestamps cannot be compared with the camera's clock.
const MAX_STALE: u64 = 64;

#[derive(Debug, Clone)]
pub struct Captured {
    /// The filtered mean (DN of the source bit depth).
    pub image: ImageF32,
    pub averaged: Averaged,
    pub stripes: Option<StripeEstimate>,
    /// Frames the camera dropped while these were taken.
    pub dropped: u64,
    /// Frames set aside because they were captured before `fresh_after` (queued in the
    /// driver's buffers while the stage moved or settled).
    pub stale: u64,
}

/// Takes `frames` frames (each within `timeout`), averages them and, with `filter`, removes the
/// field shift and the column pattern. `progress(i)` is called after each frame.
///
/// With `fresh_after` (the camera's [`Camera::now`] once the stage has settled), every frame
/// captured before it is set aside: a streaming camera hands out frames from its buffers that
/// were filled while the stage still moved, and no such frame may enter an average.
pub fn capture(
    cam: &mut dyn Camera,
    frames: u32,
    filter: bool,
    timeout: Duration,
    fresh_after: Option<Duration>,
    mut progress: impl FnMut(u32),
) -> Result<Captured, CaptureError> {
    let info = cam.info();
    let bytes = (frames as u64).saturating_mul(info.width as u64 * info.height as u64 * 2);
    if !(1..=MAX_FRAMES).contains(&frames) || bytes > MAX_FRAME_BYTES {
        return Err(CaptureError::TooMany {
            frames,
            width: info.width,
            height: info.height,
            mib: bytes >> 20,
            limit_mib: MAX_FRAME_BYTES >> 20,
        });
    }
    let dropped0 = cam.dropped();
    let mut kept: Vec<Vec<u16>> = Vec::with_capacity(frames as usize);
    let mut stale = 0;
    let mut i = 0;
    while i < frames {
        let f = cam.next_frame(timeout)?;
        if fresh_after.is_some_and(|t| f.timestamp < t) {
            stale += 1;
            if stale > MAX_STALE {
                return Err(CaptureError::NeverFresh { stale });
            }
            continue;
        }
        i += 1;
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
        progress(i);
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
        stale,
    })
}
