//! Everything the sweep decides before it sweeps, from the project and the photos' geometry
//! alone (the same on every machine of a tiled run): each overlapping pair's mapping
//! functions from the two sensors (seed 004 §4) or fitted to the control points the two
//! photos share (seed 000), its height step and parameters, its work
//! checked against the budget.

use crate::coords::PixelView;
use crate::geometry::{PhotoSensor, Sensor};
use crate::matching::block::orient::{orient, Oriented};
use crate::matching::block::photo::PhotoGeometry;
use crate::matching::error::MatchingError;
use crate::matching::mapping::given::MappingsFile;
use crate::matching::mapping::pmf_set::{SampleGrid, TermSet};
use crate::matching::methods::sweep::height_sweep::{step_for_parallax, SweepLayout, SweepParams};
use crate::matching::methods::sweep::pair_model::{estimate, Budget, PmfDtmParams};
use crate::matching::methods::sweep::regions::RegionParams;
use crate::matching::project::{Kind, Mappings, Observation, Project};
use crate::matching::{PmfSet, StereoPoint};

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

/// The points of `kind` with ground coordinates that photos `a` and `b` both show, as seed
/// 000 fits a pair's mappings to them: each photo's pixel in the view of it that was read.
fn shared_points(
    obs: &[Observation],
    kind: Kind,
    (a, wa): (&str, PixelView),
    (b, wb): (&str, PixelView),
) -> Vec<StereoPoint> {
    let in_window = |o: &Observation, w: PixelView| {
        let (x, y) = w.to_read(o.col, o.row);
        [x, y]
    };
    // Photo b's points by id: a points file may hold a million observations.
    // The first of an id, as a search from the top would find it.
    let mut in_b: std::collections::HashMap<&str, &Observation> = Default::default();
    for q in obs.iter().filter(|q| q.kind == kind && q.photo == b) {
        in_b.entry(q.id.as_str()).or_insert(q);
    }
    obs.iter()
        .filter(|o| o.kind == kind && o.photo == a)
        .filter_map(|o| {
            let other = *in_b.get(o.id.as_str())?;
            Some(StereoPoint {
                id: o.id.clone(),
                left: in_window(o, wa),
                right: in_window(other, wb),
                ground: o.ground?,
            })
        })
        .collect()
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
    // A mappings file is read once, before the pairs.
    let given = match (m.mappings, &m.mappings_file) {
        (Mappings::File, Some(f)) => {
            let ids: Vec<&str> = p.photos.iter().map(|ph| ph.id.as_str()).collect();
            let file =
                MappingsFile::read(f, &ids).map_err(|message| MatchingError::GivenMappings {
                    path: f.clone(),
                    message,
                })?;
            Some((f, file))
        }
        (Mappings::File, None) => {
            return Err(MatchingError::GivenMappings {
                path: p.path.clone(),
                message: "[matching] mappings = \"file\" names no mappings_file".into(),
            })
        }
        _ => None,
    };
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
        let failed = |message: String| MatchingError::Mappings {
            left: li.clone(),
            right: ri.clone(),
            message,
        };
        let pmfs = match (&given, m.mappings) {
            (Some((f, given)), _) => {
                let set = given
                    .pair(li, ri)
                    .map_err(|message| MatchingError::GivenMappings {
                        path: (*f).clone(),
                        message,
                    })?;
                set.in_views(photos[i].view, photos[j].view)
            }
            (None, Mappings::Points) => {
                let shared = |kind| {
                    shared_points(
                        &oriented.observations,
                        kind,
                        (li, photos[i].view),
                        (ri, photos[j].view),
                    )
                };
                PmfSet::from_points_with(m.order, set, &shared(Kind::Gcp), &shared(Kind::Cp))
                    .map_err(|e| failed(format!(
                        "fitted to the control points both photos show ([matching] mappings = \"points\"): {e}"
                    )))?
            }
            (None, _) => PmfSet::from_sensors_on(l, r, heights, m.order, grid, set)
                .map_err(|e| failed(format!("from the sensors: {e}")))?,
        };
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
        let (a, b) = (photos[i].view.size(), photos[j].view.size());
        estimate(a, b, &params, &budget).map_err(|source| MatchingError::Pair {
            left: li.clone(),
            right: ri.clone(),
            cause: source,
        })?;
        pairs.push(PlannedPair {
            left: i,
            right: j,
            pmfs,
            layout: SweepLayout::new(a.0, a.1, &params.sweep),
            params,
        });
    }
    Ok(Plan {
        oriented,
        pairs,
        budget,
    })
}
