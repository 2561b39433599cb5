//! The sweep over N photos (project format 2): every photo becomes a [`Sensor`] (its camera
//! and orientation, given or resected from the control points), every pair whose footprints
//! overlap gets mapping functions from the two sensors (seed 004 §4) and seed 000's sweep,
//! and the heights of all pairs are merged into one grid in the project's CRS.

pub mod height_sweep;
pub mod pair_model;
pub mod plan;
pub mod regions;
pub mod tiles;

use crate::coords::{GroundM, PixelXY};
use crate::geometry::control_fit::ControlFit;
use crate::geometry::{Crs, PhotoSensor, Resection, Sensor};
use crate::matching::accuracy::averaging::{remove_window_averaging, AveragingReport, Kernel};
use crate::matching::accuracy::figures::ModelFigures;
use crate::matching::accuracy::precision::{variance_factor, VarianceFactor};
use crate::matching::block::orient::{corrected_lines, Oriented};
use crate::matching::block::photo::Photo;
use crate::matching::block::photo::PhotoGeometry;
use crate::matching::error::MatchingError;
use crate::matching::grid::ElevationGrid;
use crate::matching::mapping::given::{MappingsFile, PairMappings};
use crate::matching::mapping::pmf_set::FitReport;
use crate::matching::methods::context::Run;
use crate::matching::methods::sweep::height_sweep::{sweep_bands, HeightMap, SweptBands};
use crate::matching::methods::sweep::pair_model::{pmf_dtm_from_heights, PmfDtmReport};
use crate::matching::methods::sweep::plan::{plan, Plan};
use crate::matching::products::outputs::MAPPINGS;
use crate::matching::project::Project;
use crate::matching::MatchedPoint;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// One pair's part of the run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PairReport {
    pub left: String,
    pub right: String,
    /// Height step used, m (half a pixel of parallax unless the project gave one).
    pub h_step_m: f64,
    pub pmf: Vec<FitReport>,
    pub dtm: PmfDtmReport,
    /// Matched points it added to the merged model.
    pub points: usize,
}

/// `report.json` of a format-2 run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepReport {
    pub project: PathBuf,
    pub crs: Crs,
    /// Photos resected from the control points (the others had their orientation given).
    pub resected: Vec<(String, Resection)>,
    /// Given models corrected by their control points.
    #[serde(default)]
    pub corrected: Vec<(String, ControlFit)>,
    pub heights_m: [f64; 2],
    pub extent: [f64; 4],
    pub pairs: Vec<PairReport>,
    pub points: usize,
    /// How the pairs' node heights disagree against their σ (from the pairs' redundancy);
    /// `None` where no node was seen by two pairs often enough to estimate it. Reported, not
    /// applied: pairs that share a photo share its noise and the terrain's averaging, which
    /// their difference cannot show (on tests/data/validation it came out 0.76 where the true
    /// errors were 1.9 × σ).
    pub variance_factor: Option<VarianceFactor>,
    /// The window averaging taken out of the nodes (see [`crate::matching::accuracy::averaging`]).
    #[serde(default)]
    pub averaging: Option<AveragingReport>,
    /// The RMS over the nodes of the height σ the orientations' own uncertainty gives (see
    /// [`crate::matching::accuracy::orientation_error`]), m; in quality.tif's σ. `None` where every orientation
    /// was taken as exact.
    #[serde(default)]
    pub orientation_sigma_m: Option<f64>,
    #[serde(flatten)]
    pub model: ModelFigures,
}

impl SweepReport {
    /// The figures a person looks at first, for report.html.
    pub fn summary(&self) -> Vec<(String, String)> {
        let mut v = vec![(
            "heights tried".into(),
            format!("{:.1} … {:.1} m", self.heights_m[0], self.heights_m[1]),
        )];
        for (id, r) in &self.resected {
            v.push((
                format!("photo {id}"),
                format!(
                    "resected from {} control points, σ0 {:.4} mm on the photo",
                    r.residuals_mm.len(),
                    r.sigma0_mm
                ),
            ));
        }
        v.extend(corrected_lines(&self.corrected));
        for pr in &self.pairs {
            v.push((
                format!("photos {} × {}", pr.left, pr.right),
                format!(
                    "step {:.2} m, {:.1} % matched, {} points kept",
                    pr.h_step_m, pr.dtm.matched_percent, pr.points
                ),
            ));
            for w in pr.dtm.warnings() {
                v.push(("warning".into(), w));
            }
        }
        if let Some(a) = &self.averaging {
            v.push((
                "window averaging".into(),
                format!(
                    "windows of {:.1} m on the ground: the terrain's curvature {} {:.3} m RMS (at most {:.3} m)",
                    a.kernel.window_m,
                    if a.moved { "moved the nodes by" } else { "counted in σ (nodes finer than the windows), a bias of" },
                    a.rms_correction_m,
                    a.max_correction_m
                ),
            ));
        }
        if let Some(o) = self.orientation_sigma_m {
            v.push((
                "orientation".into(),
                format!(
                    "the photos' orientations add σ {o:.3} m (RMS over the nodes) to every height"
                ),
            ));
        }
        if let Some(f) = &self.variance_factor {
            v.push((
                "pairs' agreement".into(),
                format!(
                    "node heights of two pairs differ {:.2} × their σ (from {} nodes; pairs that share a photo share errors their difference cannot show)",
                    f.s0, f.comparisons
                ),
            ));
        }
        v.extend(self.model.lines());
        v
    }
}

/// Cov(δq_i, δq_j) (px² of the pixels read) at `g` of photos `i` and `j` resected from shared
/// control: J_i·C_ij·J_jᵀ, the partials (the whole images' pixels) divided by each view's
/// factor.
fn shared_pointing(plan: &Plan, i: usize, j: usize, g: GroundM) -> Option<[[f64; 2]; 2]> {
    let c = plan.oriented.shared_orientation.between(i, j)?;
    let (si, sj) = (&plan.oriented.sensors[i], &plan.oriented.sensors[j]);
    let ji = si.frame()?.exterior_partials(g)?;
    let jj = sj.frame()?.exterior_partials(g)?;
    let f = si.pixel_factor() * sj.pixel_factor();
    Some(crate::geometry::sensor::propagate_between(&ji, &c, &jj).map(|r| r.map(|v| v / f)))
}

/// Adds to each node's σ the orientations' part: the σ of the mean of the heights the pairs
/// whose photos both see the ground there intersect, from the photos' pointing covariances
/// and the covariances of photos resected from shared control
/// ([`crate::matching::accuracy::orientation_error::height_sigma`]). Returns its RMS over the nodes, `None` where
/// no photo has a pointing covariance.
fn add_orientation_sigma(grid: &ElevationGrid, sigma: &mut [f32], plan: &Plan) -> Option<f64> {
    use rayon::prelude::*;
    let inside = |s: &PhotoSensor, g: GroundM| {
        let (w, h) = s.image_size();
        s.ground_to_image(g)
            .is_some_and(|q| q.col >= 0.0 && q.row >= 0.0 && q.col <= w as f64 && q.row <= h as f64)
    };
    let centre = grid.node(grid.cols / 2, grid.rows / 2);
    let mid = grid.z.iter().copied().find(|z| z.is_finite())? as f64;
    let g0 = GroundM::new(centre[0], centre[1], mid);
    if plan
        .oriented
        .sensors
        .iter()
        .all(|s| s.pointing_covariance(g0).is_none())
    {
        return None;
    }
    // The orientations' part changes slowly across a model (a tilt, a shift): taken on a
    // lattice of at most SAMPLES × SAMPLES nodes, each node takes its nearest sample's. (Each
    // sample costs some forty projections per pair; on every node it doubled `rig demo`'s
    // model's time.)
    const SAMPLES: usize = 48;
    let step = grid.cols.max(grid.rows).div_ceil(SAMPLES).max(1);
    let (sc, sr) = (grid.cols.div_ceil(step), grid.rows.div_ceil(step));
    let sample = |c: usize, r: usize| -> Option<f64> {
        // The sample's own height, else the nearest with one in its block.
        let mut g = None;
        'find: for rr in r..(r + step).min(grid.rows) {
            for cc in c..(c + step).min(grid.cols) {
                let z = grid.z[rr * grid.cols + cc] as f64;
                if z.is_finite() {
                    let [x, y] = grid.node(cc, rr);
                    g = Some(GroundM::new(x, y, z));
                    break 'find;
                }
            }
        }
        let g = g?;
        let seeing: Vec<(usize, usize)> = plan
            .pairs
            .iter()
            .map(|p| (p.left, p.right))
            .filter(|&(i, j)| {
                inside(&plan.oriented.sensors[i], g) && inside(&plan.oriented.sensors[j], g)
            })
            .collect();
        crate::matching::accuracy::orientation_error::height_sigma(
            &plan.oriented.sensors,
            &seeing,
            g,
            &|i, j| shared_pointing(plan, i, j, g),
        )
        .map(|s| s * s)
    };
    let lattice: Vec<Option<f64>> = (0..sc * sr)
        .into_par_iter()
        .map(|k| sample((k % sc) * step, (k / sc) * step))
        .collect();
    let per_node: Vec<Option<f64>> = (0..grid.z.len())
        .map(|i| lattice[(i / grid.cols / step) * sc + (i % grid.cols) / step])
        .collect();
    let (mut ss, mut n) = (0.0, 0usize);
    for (s, v) in sigma.iter_mut().zip(&per_node) {
        if let (Some(v), true) = (v, s.is_finite()) {
            *s = (*s as f64).hypot(v.sqrt()) as f32;
            ss += v;
            n += 1;
        }
    }
    // Pointing covariances of zero (an RPC stating no error) say nothing either.
    (n > 0 && ss > 0.0).then(|| (ss / n as f64).sqrt())
}

/// One pair's swept bands, with the seconds they took.
#[derive(Debug, Clone)]
pub struct PairPart {
    pub pair: usize,
    pub bands: SweptBands,
    pub seconds: f64,
}

/// Sweeps units `units` of the plan (see [`Plan::units`]); `photos[k]` must hold every photo
/// of the pairs these units touch.
pub fn sweep_units(
    p: &Project,
    plan: &Plan,
    units: std::ops::Range<usize>,
    photos: &[Option<&Photo>],
    progress: &dyn crate::matching::progress::Progress,
) -> Result<Vec<PairPart>, MatchingError> {
    let mut parts = Vec::new();
    for (k, bands) in plan.bands_of(units) {
        let pair = &plan.pairs[k];
        let (li, ri) = (&p.photos[pair.left].id, &p.photos[pair.right].id);
        let get = |i: usize| {
            photos
                .get(i)
                .copied()
                .flatten()
                .ok_or_else(|| MatchingError::Photo {
                    id: p.photos[i].id.clone(),
                    message: "not loaded for the sweep (a defect of the caller)".into(),
                })
        };
        let (l, r) = (get(pair.left)?, get(pair.right)?);
        let t = std::time::Instant::now();
        let swept = sweep_bands(
            &l.image,
            &r.image,
            &pair.pmfs.left_to_right,
            &pair.params.sweep,
            bands,
            &crate::matching::progress::Prefixed {
                inner: progress,
                prefix: format!("photos {li} × {ri}: "),
            },
        );
        parts.push(PairPart {
            pair: k,
            bands: swept,
            seconds: t.elapsed().as_secs_f64(),
        });
    }
    Ok(parts)
}

/// The sweep of every overlapping pair of `run`'s photos, merged into one model.
pub fn run(run: &Run) -> Result<SweepReport, MatchingError> {
    let geometry: Vec<PhotoGeometry> = run.photos.iter().map(Photo::geometry).collect();
    let plan = plan(run.project, &geometry, run.max_memory_mb)?;
    let refs: Vec<Option<&Photo>> = run.photos.iter().map(Some).collect();
    let parts = sweep_units(run.project, &plan, 0..plan.units(), &refs, run.progress)?;
    finish(run, &plan, parts)
}

/// The run after the sweep, from its parts (of one machine or of all tiles): each pair's wrong
/// heights removed and its points, the merged grid, the variance factor, the comparisons and
/// the outputs in `out`.
pub fn finish(run: &Run, plan: &Plan, parts: Vec<PairPart>) -> Result<SweepReport, MatchingError> {
    let p = run.project;
    let o: &Oriented = &plan.oriented;
    let (sensors, obs) = (&o.sensors, &o.observations);
    let (heights, extent) = (o.heights, o.extent);
    let budget = plan.budget;
    let mut by_pair: Vec<(Vec<SweptBands>, f64)> = vec![(Vec::new(), 0.0); plan.pairs.len()];
    for part in parts {
        let slot = by_pair.get_mut(part.pair).ok_or_else(|| {
            MatchingError::Grid(format!(
                "a part of pair {} of {}",
                part.pair + 1,
                plan.pairs.len()
            ))
        })?;
        slot.0.push(part.bands);
        slot.1 += part.seconds;
    }
    let mut per_pair = Vec::new();
    let mut reports = Vec::new();
    for (pair, (bands, secs)) in plan.pairs.iter().zip(by_pair) {
        let (li, ri) = (&p.photos[pair.left].id, &p.photos[pair.right].id);
        let hm = HeightMap::from_bands(pair.layout, bands).map_err(|e| {
            MatchingError::Grid(format!("photos {li} × {ri}: the sweep's parts: {e}"))
        })?;
        let d = pmf_dtm_from_heights(hm, &pair.pmfs, &pair.params, &budget, secs).map_err(
            |source| MatchingError::Pair {
                left: li.clone(),
                right: ri.clone(),
                cause: source,
            },
        )?;
        let h_step = pair.params.sweep.h_step;
        tracing::info!(
            pair = %format!("{li} × {ri}"),
            h_step_m = h_step,
            matched_percent = d.report.matched_percent,
            points = d.points.len(),
            "pair swept"
        );
        reports.push(PairReport {
            left: li.clone(),
            right: ri.clone(),
            h_step_m: h_step,
            pmf: pair.pmfs.report.clone(),
            dtm: d.report,
            points: d.points.len(),
        });
        per_pair.push(d.points);
    }
    let mut grid = ElevationGrid::covering(extent, p.cell_m, budget.max_memory_mb)
        .map_err(|e| MatchingError::Grid(e.to_string()))?;
    // How the pairs agree, for the report (not applied: see `SweepReport::variance_factor`).
    let refs: Vec<&[MatchedPoint]> = per_pair.iter().map(|v| v.as_slice()).collect();
    let factor = variance_factor(&grid, &refs);
    tracing::info!(?factor, "variance factor from the pairs");
    // The window on the ground, from each pair's reference photo at its centre and the middle
    // height, weighted by the points the pair gave.
    let (mut ws, mut wn) = (0.0, 0.0);
    for (pair, pts) in plan.pairs.iter().zip(&per_pair) {
        let s = &sensors[pair.left];
        let (w, h) = s.image_size();
        let centre = PixelXY::new(0.5 * w as f64, 0.5 * h as f64);
        if let Some(g) = s.ground_pixel_m(centre, 0.5 * (heights[0] + heights[1])) {
            ws += pts.len() as f64 * g * pair.params.sweep.window as f64;
            wn += pts.len() as f64;
        }
    }
    let all: Vec<MatchedPoint> = per_pair.into_iter().flatten().collect();
    let pts: Vec<GroundM> = all.iter().map(|p| p.ground).collect();
    grid.fill_median(&pts);
    let mut quality = grid.quality(&all);
    let averaging = remove_window_averaging(
        &mut grid,
        &mut quality,
        Kernel::cell_mean(ws / wn.max(1.0), p.cell_m),
    );
    tracing::info!(?averaging, "window averaging removed");
    let orientation_sigma_m = add_orientation_sigma(&grid, &mut quality.sigma_m, plan);
    let model = ModelFigures::check(p, run.reference, obs, grid, &quality.sigma_m);
    let report = SweepReport {
        project: p.path.clone(),
        crs: p.crs,
        resected: o.resected.clone(),
        corrected: o.corrected.clone(),
        heights_m: heights,
        extent,
        pairs: reports,
        points: all.len(),
        variance_factor: factor,
        averaging,
        orientation_sigma_m,
        model,
    };
    run.write_model(
        &report.model,
        &all,
        &quality,
        sensors,
        &report,
        &report.summary(),
    )?;
    // Each pair's mappings in the whole images' pixels, for `mappings = "file"`.
    let view = |k: usize| run.photos[k].view;
    let mappings = MappingsFile {
        pairs: plan
            .pairs
            .iter()
            .map(|pair| PairMappings {
                left: p.photos[pair.left].id.clone(),
                right: p.photos[pair.right].id.clone(),
                mappings: pair.pmfs.from_views(view(pair.left), view(pair.right)),
            })
            .collect(),
    };
    crate::atomic::write_json(&run.out.join(MAPPINGS), &mappings).map_err(|cause| {
        MatchingError::Write {
            dir: run.out.to_path_buf(),
            cause,
        }
    })?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::FrameSensor;
    use crate::matching::block::orient::vertical_sensor;
    use crate::matching::methods::sweep::height_sweep::step_for_parallax;
    use crate::matching::PmfSet;

    fn vertical(x0: f64, z0: f64) -> FrameSensor {
        vertical_sensor(GroundM::new(x0, 0.0, z0), 153.0, 2000, 0.1)
    }

    /// Two vertical photos with base B at height Z₀: x-parallax p = f·B/(Z₀ − h) (in pixels of
    /// size s: /s), so dp/dh = f·B/(s·(Z₀ − h)²), largest at the top of the range; the step
    /// from the mapping functions is half a pixel of it there, in metres.
    #[test]
    fn the_step_is_half_a_pixel_of_parallax() {
        let (b, z0, heights) = (2500.0, 6900.0, [300.0, 700.0]);
        let (l, r) = (vertical(0.0, z0), vertical(b, z0));
        let set = PmfSet::from_sensors(&l, &r, heights, 3).unwrap();
        let got = step_for_parallax(&set.left_to_right, 2000, 2000, heights, 0.5).unwrap();
        let top = z0 - heights[1];
        let want = 0.5 / (153.0 * b / (0.1 * top * top));
        assert!((got - want).abs() < 0.01 * want, "{got} m vs {want} m");
        // A pair with no base has no parallax: its mappings cannot be fitted (nothing varies
        // with the height), or give no step.
        if let Ok(none) = PmfSet::from_sensors(&l, &vertical(0.0, z0), heights, 3) {
            let step = step_for_parallax(&none.left_to_right, 2000, 2000, heights, 0.5);
            assert_eq!(step, None);
        }
    }
}
