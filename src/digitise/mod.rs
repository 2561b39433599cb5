//! Digitisation (seed 002, "Test data"): average N frames, remove the CCD's stripe noise
//! without blurring, stretch the contrast. The seed's own filters (3×3 then 7×3 low-pass) are
//! kept as a baseline to compare against, since they blurred the edges the matcher needs.

mod average;
pub mod capture;
pub mod flat;
mod lowpass;
pub mod output;
mod stretch;
mod stripes;

pub use crate::image::ImageF32;
pub use average::{average_frames, average_frames_into, Averaged, Averager};
pub use capture::{capture, CaptureError, Captured};
pub use flat::FlatField;
pub use lowpass::seed_lowpass;
pub use stretch::{look8, stretch, Stretch};
pub use stripes::{estimate_stripes, estimate_stripes_where, remove_stripes, StripeEstimate};

/// Why digitisation could not go on.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DigitiseError {
    #[error("frame {seq} is {got_w}×{got_h}, the others {want_w}×{want_h}")]
    SizeMismatch {
        seq: u64,
        got_w: usize,
        got_h: usize,
        want_w: usize,
        want_h: usize,
    },
    #[error("no frames to average")]
    NoFrames,
}
