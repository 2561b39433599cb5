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
/// error on the left photo's texture ([`sigma`]). The two run side by side (so that neither's
/// serial steps leave a core idle), within the memory limit together.
pub fn match_pair(
    left: &ImageF32,
    right: &ImageF32,
    p: &PairParams,
    max_memory_mb: u64,
    progress: &dyn crate::matching::progress::Progress,
) -> Result<DisparityMap, PairError> {
    matcher::check(left, right, p)?;
    let q = sigma::self_params(p);
    let need = matcher::bytes_needed(left.width, left.height, right.width, p)
        + matcher::bytes_needed(left.width, left.height, left.width, &q);
    matcher::within_memory(need, max_memory_mb, p)?;
    let t0 = std::time::Instant::now();
    let (m, (var, seconds_sigma)) = rayon::join(
        || match_pair_alone(left, right, p, max_memory_mb, progress),
        || {
            let var = sigma::estimator_variance(left, p, max_memory_mb);
            (var, t0.elapsed().as_secs_f64())
        },
    );
    let (mut m, var) = (m?, var?);
    for (s, &v) in m.sigma.iter_mut().zip(&var) {
        if s.is_finite() && v.is_finite() {
            *s = (*s * *s + v).sqrt();
        }
    }
    m.stats.seconds_sigma = seconds_sigma;
    m.stats.seconds_total = t0.elapsed().as_secs_f64();
    Ok(m)
}
