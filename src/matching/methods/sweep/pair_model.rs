//! Seed 000's method from two photos to an elevation model: the height sweep over the
//! reference photo along the image→image PMFs, removal of wrong heights, ground coordinates
//! by the image→ground PMFs, gridding, and — given a reference model — the comparison.

use crate::coords::GroundM;
use crate::matching::error::DtmError;
use crate::matching::grid::ElevationGrid;
use crate::matching::mapping::pmf_set::PmfSet;
use crate::matching::methods::sweep::height_sweep::{HeightMap, SweepParams};
use crate::matching::methods::sweep::regions::{remove_wrong_heights, RegionParams, RegionStats};
use crate::matching::point::MatchedPoint;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PmfDtmParams {
    pub sweep: SweepParams,
    pub regions: RegionParams,
    /// Cell of the elevation model, m.
    pub cell_m: f64,
}

/// What a run may take; estimated before it starts (see [`estimate`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Budget {
    pub max_memory_mb: u64,
    /// Candidate heights the sweep may try.
    pub max_candidates: f64,
}

/// The sweep's worst-case candidates and the run's memory, from the photos' sizes and the
/// parameters alone; refused above `budget` before anything is matched.
pub fn estimate(
    left: (usize, usize),
    right: (usize, usize),
    p: &PmfDtmParams,
    budget: &Budget,
) -> Result<(f64, f64), DtmError> {
    let s = p.sweep.stride.max(1) as u64;
    let pixels = (left.0 as u64).div_ceil(s) * (left.1 as u64).div_ceil(s);
    let heights = ((p.sweep.h_max - p.sweep.h_min) / p.sweep.h_step).floor() + 1.0;
    let heights = if heights.is_finite() && heights >= 1.0 {
        heights
    } else {
        f64::INFINITY
    };
    let candidates = pixels as f64 * heights;
    if candidates.is_nan() || candidates > budget.max_candidates {
        return Err(DtmError::TooMuchWork {
            candidates,
            pixels,
            heights: heights.min(u64::MAX as f64) as u64,
            limit: budget.max_candidates,
        });
    }
    // Photos as f32, the height map (height, correlation, σ), a matched point (32) with its
    // ground position, and its LAS record (20) when the points are written.
    let bytes =
        4.0 * (left.0 * left.1 + right.0 * right.1) as f64 + pixels as f64 * (12.0 + 40.0 + 20.0);
    let mib = bytes / (1u64 << 20) as f64;
    if mib.is_nan() || mib > budget.max_memory_mb as f64 {
        return Err(DtmError::TooMuchMemory {
            mib,
            limit_mib: budget.max_memory_mb,
        });
    }
    Ok((candidates, mib))
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
    /// Share of the points kept whose height lies within a step of the lowest (highest)
    /// height tried, %: a pile there means the terrain may reach beyond the range.
    #[serde(default)]
    pub at_lowest_percent: f64,
    #[serde(default)]
    pub at_highest_percent: f64,
}

/// The highest height the sweep tries: the last whole step from `h_min`.
fn highest_tried(s: &crate::matching::methods::sweep::height_sweep::SweepParams) -> f64 {
    s.h_min + ((s.h_max - s.h_min) / s.h_step).floor() * s.h_step
}

/// The share of matches piled at a bound above which a run warns, %.
pub const PILE_WARNING_PERCENT: f64 = 2.0;

/// Below this share of the reference photo's points matched, a run warns, %: seed 000 matched
/// most of its photo; far fewer means heights or mappings that miss the terrain.
pub const LOW_COVERAGE_PERCENT: f64 = 50.0;

impl PmfDtmReport {
    /// Every warning of the pair's run: heights piled at a bound, few points matched.
    pub fn warnings(&self) -> Vec<String> {
        let mut v: Vec<String> = self.pile_warning().into_iter().collect();
        if self.matched_percent < LOW_COVERAGE_PERCENT {
            v.push(format!(
                "only {:.1} % of the reference photo's points matched (a run that finds the terrain matches most of them): the heights tried or the mappings may miss the terrain",
                self.matched_percent
            ));
        }
        v
    }

    /// A warning when the matches pile at a bound of the heights tried; `None` when not.
    pub fn pile_warning(&self) -> Option<String> {
        let s = &self.params.sweep;
        let (lo, hi) = (self.at_lowest_percent, self.at_highest_percent);
        if lo.max(hi) <= PILE_WARNING_PERCENT {
            return None;
        }
        let (share, which, h) = if lo >= hi {
            (lo, "lowest", s.h_min)
        } else {
            (hi, "highest", highest_tried(s))
        };
        Some(format!(
            "{share:.1} % of the heights lie within a step of the {which} height tried ({h:.1} m): the terrain may reach beyond {:.1} … {:.1} m, or the mappings cannot tell heights apart; widen the heights (format 2: [dem] heights; format 1: [matching] h_min, h_max) or check the control points",
            s.h_min, s.h_max
        ))
    }
}

pub struct PmfDtm {
    pub heights: HeightMap,
    pub points: Vec<MatchedPoint>,
    pub grid: ElevationGrid,
    pub report: PmfDtmReport,
}

/// The method after the sweep (whose heights may have come from several machines, see
/// `rig dtm --tile`): wrong heights removed, ground coordinates, the grid, the comparison.
/// `secs` is the time the sweep took. The model's comparison with a reference is the merged
/// grid's, not a pair's.
pub fn pmf_dtm_from_heights(
    mut heights: HeightMap,
    pmfs: &PmfSet,
    p: &PmfDtmParams,
    budget: &Budget,
    secs: f64,
) -> Result<PmfDtm, DtmError> {
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
            // A mapping that is not a number here (a degenerate fit) gives no point.
            if g.iter().all(|v| v.is_finite()) {
                points.push(MatchedPoint {
                    ground: GroundM::new(g[0], g[1], h as f64),
                    corr: heights.corr[k],
                    sigma_m: heights.sigma[k],
                });
            }
        }
    }
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for MatchedPoint { ground: g, .. } in &points {
        lo = [lo[0].min(g.x), lo[1].min(g.y)];
        hi = [hi[0].max(g.x), hi[1].max(g.y)];
    }
    let mut grid = if points.is_empty() {
        ElevationGrid::covering([0.0, 0.0, 0.0, 0.0], p.cell_m, budget.max_memory_mb)?
    } else {
        ElevationGrid::covering([lo[0], lo[1], hi[0], hi[1]], p.cell_m, budget.max_memory_mb)?
    };
    let pts: Vec<GroundM> = points.iter().map(|p| p.ground).collect();
    grid.fill(&pts);
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
        at_lowest_percent: RegionStats::percent(
            points
                .iter()
                .filter(|q| q.ground.z <= p.sweep.h_min + p.sweep.h_step)
                .count(),
            points.len(),
        ),
        at_highest_percent: RegionStats::percent(
            points
                .iter()
                .filter(|q| q.ground.z >= highest_tried(&p.sweep) - p.sweep.h_step)
                .count(),
            points.len(),
        ),
    };
    Ok(PmfDtm {
        heights,
        points,
        grid,
        report,
    })
}
