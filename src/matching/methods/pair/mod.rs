//! A rectified pair (rows correspond) matched to a disparity map with honest error bars:
//! the matcher (`matcher`: plane sweep, winner or semi-global aggregation, the left-right
//! check, parabola or least-squares sub-pixel), the estimator's own error on the photo's
//! texture (`sigma`), and the files `rig match pair` writes (`output`).

pub mod block_match;
pub mod matcher;
pub mod output;
pub mod sgm;
mod sigma;

pub use matcher::{
    bytes_needed, match_pair_alone, DisparityMap, Filter, PairError, PairParams, PairStats,
    Subpixel, MAX_ABS_DISPARITY, MAX_DISPARITIES,
};

use crate::image::ImageF32;

/// Matches a rectified pair. Each disparity's σ holds the noise's share (from the
/// correlation's curvature, or least squares' normal matrix) and the sub-pixel estimator's own
/// error on the left photo's texture ([`sigma`]).
pub fn match_pair(
    left: &ImageF32,
    right: &ImageF32,
    p: &PairParams,
    max_memory_mb: u64,
    progress: &dyn crate::matching::progress::Progress,
) -> Result<DisparityMap, PairError> {
    let mut m = match_pair_alone(left, right, p, max_memory_mb, progress)?;
    let t0 = std::time::Instant::now();
    progress.begin("σ (the estimator on its own photo)", 1);
    let var = sigma::estimator_variance(left, p, max_memory_mb)?;
    progress.end();
    for (s, &v) in m.sigma.iter_mut().zip(&var) {
        if s.is_finite() && v.is_finite() {
            *s = (*s * *s + v).sqrt();
        }
    }
    m.stats.seconds_sigma = t0.elapsed().as_secs_f64();
    m.stats.seconds_total += m.stats.seconds_sigma;
    Ok(m)
}
