//! Everything the sweep decides before it sweeps, from the project and the photos' geometry
//! alone (the same on every machine of a tiled run): each overlapping pair's mapping
//! functions from the two sensors (seed 004 §4), its height step and parameters, its work
//! checked against the budget.

use crate::geometry::{PhotoSensor, Sensor};
use crate::matching::block::orient::{orient, Oriented};
use crate::matching::block::photo::PhotoGeometry;
use crate::matching::error::MatchingError;
use crate::matching::mapping::pmf_set::{SampleGrid, TermSet};
use crate::matching::methods::sweep::height_sweep::{step_for_parallax, SweepLayout, SweepParams};
use crate::matching::methods::sweep::pair_model::{estimate, Budget, PmfDtmParams};
use crate::matching::methods::sweep::regions::RegionParams;
use crate::matching::project::Project;
use crate::matching::PmfSet;

/// One pair to sweep: photos `left` and `right` (indices into the project's photos).
#[derive(Debug, Clone)]
pub struct PlannedPair {
    pub left: usize,
    pub right: usize,
    pub pmfs: PmfSet,
    pub params: PmfDtmParams,
    pub layout: SweepLayout,
}

/// Everything decided before the sweep, from the project and the photos' geometry alone: the
/// same on every machine of a tiled run.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The photos oriented, the heights, the extent and the overlapping pairs.
    pub oriented: Oriented,
    pub pairs: Vec<PlannedPair>,
    pub budget: Budget,
}

impl Plan {
    /// The units of work: every band of every pair's sweep, pair by pair.
    pub fn units(&self) -> usize {
        self.pairs.iter().map(|p| p.layout.bands()).sum()
    }

    /// The bands of each pair that units `u` hold: (pair, bands) in order.
    pub fn bands_of(&self, u: std::ops::Range<usize>) -> Vec<(usize, std::ops::Range<usize>)> {
        let mut out = Vec::new();
        let mut first = 0;
        for (k, pair) in self.pairs.iter().enumerate() {
            let n = pair.layout.bands();
            let (a, b) = (u.start.max(first), u.end.min(first + n));
            if a < b {
                out.push((k, a - first..b - first));
            }
            first += n;
        }
        out
    }
}

/// The orientations, heights, pairs, mappings and sweep parameters of a project, with each
/// pair's work checked against the budget.
pub fn plan(
    p: &Project,
    photos: &[PhotoGeometry],
    max_memory_mb: Option<u64>,
) -> Result<Plan, MatchingError> {
    let oriented = orient(p, photos)?;
    let (sensors, heights) = (&oriented.sensors, oriented.heights);
    let budget = Budget {
        max_memory_mb: max_memory_mb.unwrap_or(p.limits.max_memory_mb),
        max_candidates: p.limits.max_candidates_g * 1e9,
    };
    let m = &p.matching;
    let mut pairs = Vec::new();
    for &(i, j) in &oriented.overlapping {
        let (l, r) = (&sensors[i], &sensors[j]);
        let (li, ri) = (&p.photos[i].id, &p.photos[j].id);
        // A line scanner's (or its RPCs') mappings may take seed 004's extended terms.
        let scanner = |s: &PhotoSensor| s.frame().is_none();
        let set = if scanner(l) || scanner(r) {
            TermSet::Extended
        } else {
            TermSet::Basic
        };
        let grid = m
            .pmf_grid
            .map(|[n, levels]| SampleGrid { n, levels })
            .unwrap_or_default();
        let pmfs = PmfSet::from_sensors_on(l, r, heights, m.order, grid, set).map_err(|e| {
            MatchingError::Mappings {
                left: li.clone(),
                right: ri.clone(),
                message: e.to_string(),
            }
        })?;
        let (w, h) = l.image_size();
        let h_step = m
            .h_step
            .or_else(|| step_for_parallax(&pmfs.left_to_right, w, h, heights, 0.5))
            .unwrap_or(1.0);
        let params = PmfDtmParams {
            sweep: SweepParams {
                h_min: heights[0],
                h_max: heights[1],
                h_step,
                window: m.window,
                threshold: m.threshold,
                subpixel: m.subpixel,
                stride: m.stride,
                ..Default::default()
            },
            regions: RegionParams {
                search_distance: m.search_distance,
                height_threshold: m.height_threshold.unwrap_or(1.5 * h_step),
                population_threshold: m.population_threshold,
            },
            cell_m: p.cell_m,
        };
        let (a, b) = (&photos[i].window, &photos[j].window);
        estimate((a.width, a.height), (b.width, b.height), &params, &budget).map_err(|source| {
            MatchingError::Pair {
                left: li.clone(),
                right: ri.clone(),
                cause: source,
            }
        })?;
        pairs.push(PlannedPair {
            left: i,
            right: j,
            pmfs,
            layout: SweepLayout::new(a.width, a.height, &params.sweep),
            params,
        });
    }
    Ok(Plan {
        oriented,
        pairs,
        budget,
    })
}
