//! The object-space matching over a format-2 project (seed 001): the sweep, the feature route
//! or a file gives the coarse DEM (the first two kept in `coarse/`), the DEM's nodes become
//! the posts, the reference photo's footprint is
//! cut into groundels of about a ground pixel, and the heights, the reflectance and each
//! photo's offset and gain are adjusted patch by patch from every photo overlapping the
//! reference. Written as the sweep's outputs are (dem.tif with the posts refined from the grey
//! values, quality.tif with their σ), with the reflectance as an orthophoto
//! (reflectance.tif, the reference photo's grey values) and the convergence plot.

use crate::coords::PixelXY;
use crate::geometry::Sensor;
use crate::matching::accuracy::figures::ModelFigures;
use crate::matching::block::geometry::{block, parallax_per_m};
use crate::matching::block::orient::Oriented;
use crate::matching::error::MatchingError;
use crate::matching::grid::{Comparison, ElevationGrid, NodeQuality};
use crate::matching::methods::context::{ReportHead, Run};
use crate::matching::methods::oslsm::coarse_features::{
    feature_grid, FeatureReport, LINE_SPACING_PX,
};
use crate::matching::methods::oslsm::config::OslsmConfig;
use crate::matching::methods::oslsm::grids::Grids;
use crate::matching::methods::oslsm::patches::{refine_block, PatchReport};
use crate::matching::methods::oslsm::plot::convergence_plot;
use crate::matching::methods::oslsm::PhotoView;
use crate::matching::products::outputs;
use crate::matching::products::write::check_out_dir;
use crate::matching::project::matchers::CoarseSource;
use crate::matching::MatchedPoint;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A photo's offset and gain over the patches that see it (each patch has its own: seed
/// 001's local radiometric correction), against the reference photo's grey values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhotoRadiometry {
    pub id: String,
    pub patches: usize,
    pub offset_median: f64,
    pub gain_median: f64,
    pub gain_min: f64,
    pub gain_max: f64,
}

/// `report.json` of an object-space run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OslsmReport {
    /// The project, the method, the CRS and the orientations the model took.
    #[serde(flatten)]
    pub head: ReportHead,
    /// The radiometric datum and the photo whose footprint is modelled.
    pub reference: String,
    /// The photos adjusted with it.
    pub others: Vec<String>,
    pub heights_m: [f64; 2],
    pub extent: [f64; 4],
    pub config: OslsmConfig,
    /// Posts (the DEM's nodes) and groundels, m; groundels along a post cell's side.
    pub post_m: f64,
    /// The project's `[dem] cell_m`; `post_m` is a multiple of it where the project's
    /// posts were too close for the groundels.
    #[serde(default)]
    pub asked_post_m: f64,
    pub groundel_m: f64,
    pub groundels_per_cell: usize,
    pub groundels: usize,
    /// Height per pixel of parallax at the reference's centre, m.
    pub m_per_px: f64,
    /// The coarse model from the sweep (in `coarse/`) against the reference DEM, and the
    /// nodes it had no height for (filled from their neighbours before the adjustment).
    pub coarse_comparison: Option<Comparison>,
    /// Where the coarse model came from: the sweep (its outputs in coarse/), the feature
    /// route (its grid and record in coarse/) or the file.
    pub coarse_source: String,
    pub coarse_holes_filled: usize,
    /// The feature route's line pairs, edges, matches and points, when it made the coarse
    /// model.
    #[serde(default)]
    pub coarse_features: Option<FeatureReport>,
    pub radiometry: Vec<PhotoRadiometry>,
    pub patches: Vec<PatchReport>,
    /// Posts refined from the grey values (the DEM's other nodes are nodata).
    pub refined_posts: usize,
    /// Memory estimated before the adjustment, MiB.
    pub memory_estimate_mib: u64,
    pub seconds: f64,
    /// Groundels adjusted per second (the adjustment alone).
    pub groundels_per_second: f64,
    #[serde(flatten)]
    pub model: ModelFigures,
    #[serde(default)]
    pub warnings: Vec<String>,
}

impl OslsmReport {
    pub fn summary(&self) -> Vec<(String, String)> {
        let mut v = self.head.lines(
            format!(
                "object-space least-squares matching: photo {} (the radiometric datum) with {}",
                self.reference,
                self.others.join(", ")
            ),
            self.heights_m,
        );
        v.push((
            "grids".into(),
            format!(
                "posts every {:.2} m, {} groundels of {:.3} m ({} to a cell side), {:.3} m per px of parallax",
                self.post_m, self.groundels, self.groundel_m, self.groundels_per_cell, self.m_per_px
            ),
        ));
        if let Some(c) = &self.coarse_comparison {
            v.push((
                format!("coarse model ({})", self.coarse_source),
                c.summary(),
            ));
        }
        if let Some(f) = &self.coarse_features {
            let per: Vec<String> = f
                .pairs
                .iter()
                .map(|x| {
                    format!(
                        "photo {}: {} line pairs, {} + {} edges, {} matched, {} heights",
                        x.photo, x.lines, x.edges_reference, x.edges_other, x.matched, x.points
                    )
                })
                .collect();
            v.push((
                "feature route".into(),
                format!(
                    "{}; {} heights dropped as off those around them; a grid of {:.1} m: {} nodes with a height, {} dropped as off their neighbours, {} holes filled",
                    per.join("; "),
                    f.rejected,
                    f.cell_m,
                    f.nodes,
                    f.blunders,
                    f.holes_filled
                ),
            ));
        }
        let failed = self.patches.iter().filter(|p| p.failure.is_some()).count();
        let iters: Vec<usize> = self
            .patches
            .iter()
            .filter(|p| p.failure.is_none())
            .map(|p| p.iterations)
            .collect();
        v.push((
            "patches".into(),
            format!(
                "{} adjusted ({} … {} iterations), {failed} failed; {} posts refined; {:.0} groundels/s",
                iters.len(),
                iters.iter().min().unwrap_or(&0),
                iters.iter().max().unwrap_or(&0),
                self.refined_posts,
                self.groundels_per_second
            ),
        ));
        for r in &self.radiometry {
            v.push((
                format!("photo {}", r.id),
                format!(
                    "gain {:.4} (patches {:.4} … {:.4}), offset {:.1} against photo {}, over {} patches",
                    r.gain_median, r.gain_min, r.gain_max, r.offset_median, self.reference, r.patches
                ),
            ));
        }
        v.extend(self.model.lines());
        for w in &self.warnings {
            v.push(("warning".into(), w.clone()));
        }
        v
    }
}

/// Groundels along a post cell's side at the least: with fewer, a post's height rests on a
/// handful of grey values, each also carrying its own reflectance, and the patches swing
/// between neighbouring solutions (on a pushbroom triplet, 2 to a side left 323 of 342
/// patches unconverged; 6 converged 23 of 25).
pub const MIN_PER_CELL: usize = 4;

/// Bytes the adjustment holds at once for `groundels` in the block, `posts` per patch
/// (patch_posts²), `kp` photos and `threads` patches in flight: per groundel of the block its
/// merged reflectance and weight (f32 each, patches merged as they finish) and the
/// orthophoto's copy (f32); per patch in flight its dense normal matrices (one per worker
/// accumulating, the sum, the factor and the inverse: threads + 3) and its groundels'
/// observations, sight lines and reflectance. The photos are in memory already.
pub fn memory_bytes(
    groundels: u64,
    posts: u64,
    per_patch_groundels: u64,
    kp: u64,
    threads: u64,
) -> u64 {
    let nu = posts + crate::matching::methods::oslsm::solve::NR as u64 * kp;
    let block = groundels.saturating_mul(3 * 4);
    let normals = nu * nu * 8 * (threads + 3);
    let per_groundel = kp * (24 + 2) + 64;
    block.saturating_add(threads * (normals + per_patch_groundels * per_groundel))
}

/// The share of the terrain's bending between posts ([`crate::matching::methods::oslsm::grids::representation_sigma`])
/// kept in a post's σ once the facets' curvature bias is taken out of it
/// ([`crate::matching::methods::oslsm::grids::facet_bias`]): the bending a quadratic over 3 × 3 posts does not follow.
/// Measured on tests/data/validation (before σ took each post's own variance factor): with
/// all of it RMS(error/σ) was 1.12, 0.92 and 0.78 on the lidar, wide and close scenes; with
/// half, 1.24, 1.05 and 1.00; with half and the posts' own factors, 1.14, 1.06 and 1.20.
pub const FACET_UNRESOLVED: f64 = 0.5;

/// Posts within this many posts (Chebyshev) of one the coarse model has a height for are
/// reported.
const COARSE_REACH: usize = 1;

/// Whether each node of a `cols` × `rows` grid lies within `reach` nodes (Chebyshev) of a
/// finite value of `z`.
fn near_a_height(z: &[f64], cols: usize, rows: usize, reach: usize) -> Vec<bool> {
    (0..cols * rows)
        .map(|k| {
            let (i, j) = (k % cols, k / cols);
            (j.saturating_sub(reach)..=(j + reach).min(rows - 1)).any(|jj| {
                (i.saturating_sub(reach)..=(i + reach).min(cols - 1))
                    .any(|ii| z[jj * cols + ii].is_finite())
            })
        })
        .collect()
}

/// Runs the object-space matching of `run`'s project on its photos.
pub fn run(run: &Run) -> Result<OslsmReport, MatchingError> {
    let p = run.project;
    let cfg = p.matching.oslsm.clone();
    let started = std::time::Instant::now();
    let b = block(p, run.photos, cfg.reference.as_deref(), "matching.oslsm")?;
    let Oriented {
        sensors,
        resected,
        corrected,
        heights,
        extent,
        overlapping,
        observations: obs,
        ..
    } = b.oriented;
    let (mid, r, others) = (b.mid, b.reference, b.others);
    let (photos, out, max_memory_mb, progress) =
        (run.photos, run.out, run.max_memory_mb, run.progress);
    // Every photo that overlaps another takes part (the reference's partners first): a patch
    // beyond the reference's footprint is matched from the photos that see it.
    let partners = others.clone();
    let mut others = others;
    for &(i, j) in &overlapping {
        for k in [i, j] {
            if k != r && !others.contains(&k) {
                others.push(k);
            }
        }
    }
    let (rw, rh) = (photos[r].image.width, photos[r].image.height);
    let centre = PixelXY::new(0.5 * rw as f64, 0.5 * rh as f64);
    let searches: Vec<&dyn Sensor> = partners
        .iter()
        .map(|&k| &sensors[k] as &dyn Sensor)
        .collect();
    let px_per_m = parallax_per_m(&sensors[r], &searches, centre, mid);
    if px_per_m.is_nan() || px_per_m <= 1e-9 {
        return Err(MatchingError::Oslsm(
            "the photos show no parallax with height (no base between them): nothing to match"
                .into(),
        ));
    }
    let m_per_px = 1.0 / px_per_m;
    let gsd = sensors[r].ground_pixel_m(centre, mid).ok_or_else(|| {
        MatchingError::Oslsm(format!(
            "photo {}: its centre's ray does not reach {mid:.0} m",
            p.photos[r].id
        ))
    })?;
    // The posts: the project's nodes, or where those are too close for the groundels (fewer
    // than MIN_PER_CELL to a side: the patches swing without converging) every k-th of them,
    // the finest multiple of cell_m that holds enough groundels (said in the warnings and
    // in report.json's `post_m` against `asked_post_m`).
    let asked_post_m = p.cell_m;
    let groundel_want = cfg.groundel_px * gsd;
    let fits = |post: f64| (post / groundel_want).round() >= MIN_PER_CELL as f64;
    let step = (1..=1024usize)
        .find(|&k| fits(k as f64 * asked_post_m))
        .unwrap_or(1);
    let post_m = step as f64 * asked_post_m;
    let mut early_warnings = Vec::new();
    if step > 1 {
        early_warnings.push(format!(
            "[dem] cell_m = {asked_post_m} m holds only {:.0} groundel(s) of {groundel_want:.2} m along a side (at least {MIN_PER_CELL}: posts that close are not fixed by the grey values and the patches swing without converging): the object-space matching puts its posts every {post_m} m ({step} × cell_m), the finest multiple of cell_m that holds {MIN_PER_CELL}; dem.tif has that spacing",
            (asked_post_m / groundel_want).round()
        ));
    }
    let per_cell = (post_m / groundel_want).round().max(1.0);
    if per_cell > 64.0 {
        return Err(MatchingError::Oslsm(format!(
            "{}: [dem] cell_m = {post_m} m holds {per_cell:.0} groundels of {:.2} m along a side (at most 64): use a smaller cell_m or a larger [matching.oslsm] groundel_px",
            p.path.display(),
            groundel_want
        )));
    }
    let per_cell = per_cell as usize;
    let groundel_m = post_m / per_cell as f64;
    // The posts: the model's nodes. Memory before anything large is made.
    let budget = max_memory_mb.unwrap_or(p.limits.max_memory_mb);
    let mut grid = ElevationGrid::covering(extent, post_m, budget)
        .map_err(|e| MatchingError::Grid(e.to_string()))?;
    let (cols, rows) = (grid.cols, grid.rows);
    let groundels = (cols.saturating_sub(1) as u64)
        * (rows.saturating_sub(1) as u64)
        * (per_cell as u64).pow(2);
    let side = cfg.patch_posts.min(cols.max(rows)) as u64;
    let threads = rayon::current_num_threads().max(1) as u64;
    let bytes = memory_bytes(
        groundels,
        side * side,
        (side.saturating_sub(1) * per_cell as u64).pow(2),
        (others.len() + 1) as u64,
        threads,
    );
    let limit = budget << 20;
    if bytes > limit {
        return Err(MatchingError::Oslsm(format!(
            "{groundels} groundels of {groundel_m:.2} m need about {} MiB; the limit is {} MiB ([limits] max_memory_mb or --max-memory; or a larger [matching.oslsm] groundel_px)",
            bytes >> 20,
            budget
        )));
    }
    let order: Vec<usize> = std::iter::once(r).chain(others.iter().copied()).collect();
    let views: Vec<PhotoView> = order
        .iter()
        .map(|&k| PhotoView {
            image: &photos[k].image,
            sensor: &sensors[k],
        })
        .collect();
    // The coarse model: the sweep's (all its outputs in coarse/), the feature route's (its
    // grid in coarse/dem.tif) or the project's file.
    let mut coarse_features = None;
    let mut warnings = early_warnings;
    let (cg, coarse_comparison) = match &cfg.coarse {
        CoarseSource::File(f) => {
            let path = p.path.parent().unwrap_or(Path::new(".")).join(f);
            let g = crate::matching::products::files::read_geotiff(&path).map_err(|e| {
                MatchingError::Oslsm(format!(
                    "{}: [matching.oslsm] coarse = \"{}\": {e}",
                    p.path.display(),
                    f.display()
                ))
            })?;
            let c = run.reference.map(|r| g.compare(|x, y| r.interpolate(x, y)));
            (g, c)
        }
        CoarseSource::Features => {
            let others_v: Vec<(PhotoView, String)> = (1..order.len())
                .map(|n| (views[n], p.photos[order[n]].id.clone()))
                .collect();
            // Nodes a few lines apart on the ground, so that most hold several points.
            let cell = post_m.max(4.0 * LINE_SPACING_PX * gsd);
            let mut g = ElevationGrid::covering(extent, cell, budget)
                .map_err(|e| MatchingError::Grid(e.to_string()))?;
            let rep = feature_grid(
                views[0],
                &others_v,
                heights,
                &mut g,
                3.0 * m_per_px,
                progress,
            );
            if rep.nodes == 0 {
                return Err(MatchingError::Oslsm(format!(
                    "the feature route matched no edges into heights within [dem] heights {:.0} … {:.0} m ({} points, {} line pairs): do the heights bracket the terrain, and do the photos show edges?",
                    heights[0],
                    heights[1],
                    rep.points,
                    rep.pairs.iter().map(|x| x.lines).sum::<usize>()
                )));
            }
            let dir = out.join(outputs::COARSE);
            std::fs::create_dir_all(&dir)
                .and_then(|_| {
                    crate::matching::products::files::write_geotiff(
                        &dir.join(outputs::DEM),
                        &g,
                        p.crs,
                    )
                })
                .map_err(|source| MatchingError::Write {
                    dir: dir.clone(),
                    cause: source,
                })?;
            // Compared where the edges gave heights; then filled for the posts.
            let c = run.reference.map(|r| g.compare(|x, y| r.interpolate(x, y)));
            let mut z: Vec<f64> = g.z.iter().map(|&v| v as f64).collect();
            let mut rep = rep;
            rep.holes_filled =
                crate::matching::grid::fill_holes(&mut z, g.cols, g.rows).unwrap_or(0);
            for (d, v) in g.z.iter_mut().zip(&z) {
                *d = *v as f32;
            }
            // The route's own record beside its grid (kept even if the refinement fails).
            crate::atomic::write_json(
                &dir.join("report.json"),
                &serde_json::json!({
                    "route": "features",
                    "features": rep,
                    "m_per_px": m_per_px,
                    "comparison": c,
                }),
            )
            .map_err(|source| MatchingError::Write {
                dir: dir.clone(),
                cause: source,
            })?;
            coarse_features = Some(rep);
            (g, c)
        }
        CoarseSource::Sweep => {
            let coarse = out.join(outputs::COARSE);
            check_out_dir(&coarse)?;
            let r = crate::matching::methods::sweep::run(&run.into_dir(&coarse))?;
            for pr in &r.pairs {
                for w in pr.dtm.warnings() {
                    warnings.push(format!(
                        "the sweep's coarse model, photos {} × {}: {w}",
                        pr.left, pr.right
                    ));
                }
            }
            let c = r.model.comparison.clone();
            (r.model.grid, c)
        }
    };
    let mut zc: Vec<f64> = (0..cols * rows)
        .map(|k| {
            let [x, y] = grid.node(k % cols, k / cols);
            cg.interpolate(x, y)
        })
        .collect();
    // Posts more than a post from any the coarse model has a height for start from heights
    // filled from afar, often pixels of parallax off, and least squares pulls in no further
    // (on the independent scenes such posts were 0.2–0.85 px off RMS against 0.07–0.1 px
    // elsewhere): they are adjusted with the rest, for the groundels around them, but not
    // reported.
    let supported = near_a_height(&zc, cols, rows, COARSE_REACH);
    let holes = crate::matching::grid::fill_holes(&mut zc, cols, rows).ok_or_else(|| {
        MatchingError::Oslsm(
            "the coarse model has no height over the photos: nothing to refine (the sweep's: see coarse/report.html; a [matching.oslsm] coarse file: is it in the project's CRS?)".into(),
        )
    })?;
    // Posts with Y north (grids.rs) from the grid's rows from the north.
    let grids = Grids {
        x0: grid.x0,
        y0: grid.y0 - (rows - 1) as f64 * post_m,
        post_m,
        cols,
        rows,
        z: (0..rows)
            .flat_map(|j| (0..cols).map(move |i| (rows - 1 - j) * cols + i))
            .map(|k| zc[k])
            .collect(),
        per_cell,
    };
    let adjust_started = std::time::Instant::now();
    let merged = refine_block(
        &views,
        &grids,
        cfg.layout(),
        &cfg.params(m_per_px),
        progress,
    )
    .map_err(|e| MatchingError::Oslsm(e.to_string()))?;
    let adjust_seconds = adjust_started.elapsed().as_secs_f64();
    // The model: posts refined from the grey values, with their σ: the adjustment's and
    // the terrain's bending between posts that the bilinear surface cannot follow.
    let bend = crate::matching::methods::oslsm::grids::representation_sigma(&merged.z, cols, rows);
    let mut sigma = vec![f32::NAN; cols * rows];
    for j in 0..rows {
        for i in 0..cols {
            let k = (rows - 1 - j) * cols + i;
            let l = j * cols + i;
            let s = merged.sigma_z[l].hypot(FACET_UNRESOLVED * bend[l]);
            if s.is_finite() && supported[k] {
                grid.z[k] = merged.z[l] as f32;
                sigma[k] = s as f32;
            } else {
                grid.z[k] = f32::NAN;
            }
        }
    }
    // The facets' curvature bias taken out of the posts (grids::facet_bias).
    let bias = crate::matching::methods::oslsm::grids::facet_bias(&grid);
    let mut points = Vec::new();
    for k in 0..cols * rows {
        if !grid.z[k].is_finite() {
            continue;
        }
        if bias[k].is_finite() {
            grid.z[k] += bias[k] as f32;
        }
        let [x, y] = grid.node(k % cols, k / cols);
        points.push(MatchedPoint {
            ground: crate::coords::GroundM::new(x, y, grid.z[k] as f64),
            corr: f32::NAN,
            sigma_m: sigma[k],
        });
    }
    let quality = NodeQuality {
        sigma_m: sigma,
        corr: vec![f32::NAN; cols * rows],
    };
    let refined_posts = points.len();
    if refined_posts == 0 {
        return Err(MatchingError::Oslsm(format!(
            "it refined no post: all {} patches failed (first: {}){}{}; is the coarse model within a pixel or two of parallax of the terrain, and do [dem] heights bracket it?",
            merged.patches.len(),
            merged
                .patches
                .iter()
                .find_map(|pr| pr.failure.as_ref())
                .map(|e| e.to_string())
                .unwrap_or_default(),
            warnings
                .iter()
                .map(|w| format!("; {w}"))
                .collect::<String>(),
            coarse_comparison
                .as_ref()
                .map(|c| format!("; the coarse model against the reference: {}", c.summary()))
                .unwrap_or_default()
        )));
    }
    // The reflectance as an orthophoto of groundel cells, rows from the north.
    let (gu, gv) = grids.groundels();
    let reflectance = ElevationGrid {
        x0: grids.x0 + 0.5 * groundel_m,
        y0: grids.y0 + (gv as f64 - 0.5) * groundel_m,
        cell_m: groundel_m,
        cols: gu,
        rows: gv,
        z: (0..gv)
            .flat_map(|rr| (0..gu).map(move |u| (gv - 1 - rr) * gu + u))
            .map(|k| merged.d[k])
            .collect(),
    };
    let radiometry: Vec<PhotoRadiometry> = (1..order.len())
        .map(|n| {
            let v: Vec<[f64; 2]> = merged
                .patches
                .iter()
                .filter_map(|pr| pr.radiometry.as_ref()?.get(n).copied().flatten())
                .collect();
            let median = |mut x: Vec<f64>| {
                x.sort_by(f64::total_cmp);
                x.get(x.len() / 2).copied().unwrap_or(f64::NAN)
            };
            let gains: Vec<f64> = v.iter().map(|a| a[1]).collect();
            PhotoRadiometry {
                id: p.photos[order[n]].id.clone(),
                patches: v.len(),
                offset_median: median(v.iter().map(|a| a[0]).collect()),
                gain_median: median(gains.clone()),
                gain_min: gains.iter().copied().fold(f64::NAN, f64::min),
                gain_max: gains.iter().copied().fold(f64::NAN, f64::max),
            }
        })
        .collect();
    let failed: Vec<&PatchReport> = merged
        .patches
        .iter()
        .filter(|pr| pr.failure.is_some())
        .collect();
    if !failed.is_empty() {
        warnings.push(format!(
            "{} of {} patches failed (their posts are nodata in dem.tif; see the patches in report.json): first {}",
            failed.len(),
            merged.patches.len(),
            failed[0]
                .failure
                .as_ref()
                .map(|e| e.to_string())
                .unwrap_or_default()
        ));
    }
    if holes * 4 > cols * rows {
        warnings.push(format!(
            "the coarse model has no height at {holes} of {} nodes (filled from their neighbours before the adjustment): it may be far off there",
            cols * rows
        ));
    }
    let model = ModelFigures::check(p, run.reference, &obs, grid, &quality.sigma_m);
    let report = OslsmReport {
        head: ReportHead {
            project: p.path.clone(),
            method: "oslsm".into(),
            crs: p.crs,
            resected,
            corrected,
        },
        reference: p.photos[r].id.clone(),
        others: others.iter().map(|&k| p.photos[k].id.clone()).collect(),
        heights_m: heights,
        extent,
        config: cfg.clone(),
        post_m,
        asked_post_m,
        groundel_m,
        groundels_per_cell: per_cell,
        groundels: gu * gv,
        m_per_px,
        coarse_comparison,
        coarse_source: match &cfg.coarse {
            CoarseSource::File(f) => f.display().to_string(),
            CoarseSource::Sweep => "the sweep, in coarse/".into(),
            CoarseSource::Features => "the feature route".into(),
        },
        coarse_holes_filled: holes,
        coarse_features,
        radiometry,
        patches: merged.patches.clone(),
        refined_posts,
        memory_estimate_mib: bytes >> 20,
        seconds: started.elapsed().as_secs_f64(),
        groundels_per_second: (gu * gv) as f64 / adjust_seconds.max(1e-9),
        model,
        warnings,
    };
    let write = |source| MatchingError::Write {
        dir: out.to_path_buf(),
        cause: source,
    };
    run.write_model(
        &report.model,
        &points,
        &quality,
        &sensors,
        &report,
        &report.summary(),
    )?;
    crate::matching::products::files::write_ortho(
        &out.join(outputs::REFLECTANCE),
        &reflectance,
        p.crs,
        &reflectance.z,
    )
    .map_err(write)?;
    convergence_plot(
        &report.patches,
        m_per_px,
        cfg.converged_px,
        &out.join(outputs::CONVERGENCE),
    )
    .map_err(write)?;
    Ok(report)
}
