//! Seed 000's method from two photos to an elevation model: the height sweep over the
//! reference photo along the image→image PMFs, removal of wrong heights, ground coordinates
//! by the image→ground PMFs, gridding, and — given a reference model — the comparison.

use super::grid::{Comparison, ElevationGrid};
use super::pmf_set::PmfSet;
use super::regions::{remove_wrong_heights, RegionParams, RegionStats};
use super::sweep::{sweep, HeightMap, SweepParams};
use crate::coords::GroundM;
use crate::digitise::ImageF32;
use serde::{Deserialize, Serialize};
use std::time::Instant;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PmfDtmParams {
    pub sweep: SweepParams,
    pub regions: RegionParams,
    /// Cell of the elevation model, m.
    pub cell_m: f64,
}

/// Seed 000 Tables 3–5 in one document.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PmfDtmReport {
    pub params: PmfDtmParams,
    pub points_total: usize,
    pub points_matched: usize,
    pub matched_percent: f64,
    pub candidates: u64,
    pub matching_seconds: f64,
    pub pixels_per_second: f64,
    pub regions: RegionStats,
    pub removed_percent: f64,
    pub remaining_percent: f64,
    pub grid_nodes: usize,
    pub grid_filled: usize,
    pub comparison: Option<Comparison>,
    /// Flying height above the terrain, m, when known: the RMSE in per mille of it.
    pub flying_height_m: Option<f64>,
    pub rmse_permille_of_flying_height: Option<f64>,
}

pub struct PmfDtm {
    pub heights: HeightMap,
    pub points: Vec<(GroundM, f32)>,
    pub grid: ElevationGrid,
    pub report: PmfDtmReport,
}

/// Runs the method; `reference` (a height at ground x, y) gives the comparison.
pub fn pmf_dtm(
    left: &ImageF32,
    right: &ImageF32,
    pmfs: &PmfSet,
    p: &PmfDtmParams,
    reference: Option<&dyn Fn(f64, f64) -> f64>,
    flying_height_m: Option<f64>,
) -> PmfDtm {
    let t = Instant::now();
    let mut heights = sweep(left, right, &pmfs.left_to_right, &p.sweep);
    let secs = t.elapsed().as_secs_f64();
    let total = heights.cols * heights.rows;
    let matched = heights.matched();
    let stats = remove_wrong_heights(&mut heights, &p.regions);
    let mut points = Vec::with_capacity(stats.points_left);
    for j in 0..heights.rows {
        for i in 0..heights.cols {
            let k = j * heights.cols + i;
            let h = heights.h[k];
            if !h.is_finite() {
                continue;
            }
            let px = heights.pixel(i, j);
            let g = pmfs.left_to_ground.eval([px[0], px[1], h as f64]);
            points.push((GroundM::new(g[0], g[1], h as f64), heights.corr[k]));
        }
    }
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for (g, _) in &points {
        lo = [lo[0].min(g.x), lo[1].min(g.y)];
        hi = [hi[0].max(g.x), hi[1].max(g.y)];
    }
    let mut grid = if points.is_empty() {
        ElevationGrid::covering([0.0, 0.0, 0.0, 0.0], p.cell_m)
    } else {
        ElevationGrid::covering([lo[0], lo[1], hi[0], hi[1]], p.cell_m)
    };
    let pts: Vec<GroundM> = points.iter().map(|(g, _)| *g).collect();
    grid.fill(&pts);
    let comparison = reference.map(|f| grid.compare(f));
    let rmse_permille = match (&comparison, flying_height_m) {
        (Some(c), Some(h)) => Some(1000.0 * c.rmse_m / h),
        _ => None,
    };
    let report = PmfDtmReport {
        params: p.clone(),
        points_total: total,
        points_matched: matched,
        matched_percent: RegionStats::percent(matched, total),
        candidates: heights.candidates,
        matching_seconds: secs,
        pixels_per_second: total as f64 / secs.max(1e-9),
        removed_percent: RegionStats::percent(stats.points_removed, total),
        remaining_percent: RegionStats::percent(stats.points_left, total),
        regions: stats,
        grid_nodes: grid.cols * grid.rows,
        grid_filled: grid.filled(),
        comparison,
        flying_height_m,
        rmse_permille_of_flying_height: rmse_permille,
    };
    PmfDtm {
        heights,
        points,
        grid,
        report,
    }
}
