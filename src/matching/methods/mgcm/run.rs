//! The hierarchical multiphoto matching over a format-2 project (seed 002, "Automatic D.T.M.
//! measurements"): one reference photo carries the templates and every photo overlapping it
//! is searched at once. Pyramids of all of them; at the top a height sweep (mean correlation
//! over the search photos) on a regular grid gives first heights, refined there by the
//! constrained matching with two shifts; at each level below, the grid's heights (blunders
//! removed, holes filled from their neighbours) are the approximations of the next; at the
//! finest level the interest operator's points are matched with the full model, every ray
//! tested, and the points tested against their neighbours. The points, a DEM interpolated from
//! them with its σ, the point files with every refused point and ray and why, and seed 002's
//! accuracy analysis against the reference are written as the sweep's outputs are.

use crate::coords::PixelXY;
use crate::geometry::Sensor;
use crate::matching::accuracy::averaging::{remove_window_averaging, AveragingReport, Kernel};
use crate::matching::accuracy::figures::ModelFigures;
use crate::matching::accuracy::tables::{analyse, Accuracy};
use crate::matching::block::geometry::{block, flying_height, parallax_per_m, references_covering};
use crate::matching::block::orient::Oriented;
use crate::matching::error::MatchingError;
use crate::matching::grid::ElevationGrid;
use crate::matching::methods::context::{ReportHead, Run};
use crate::matching::methods::mgcm::adjust::{
    local_shape, template, AdjustParams, PointFailure, View,
};
use crate::matching::methods::mgcm::config::{auto_cell, MgcmConfig};
use crate::matching::methods::mgcm::interest::{epipolar_direction, select};
use crate::matching::methods::mgcm::point::{match_point, PointResult, RayTests};
use crate::matching::methods::mgcm::pyramid::{levels_for, pyramid, AtLevel, Textured};
use crate::matching::products::outputs;
use crate::matching::progress::Progress;
use crate::matching::MatchedPoint;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// One pyramid level's part of the run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelReport {
    pub level: usize,
    /// The reference image's size at this level, px.
    pub size: [usize; 2],
    /// Grid nodes (or, at level 0, selected points) tried, matched, and refused as blunders.
    pub tried: usize,
    pub matched: usize,
    pub blunders: usize,
}

/// Why a point of the finest level was refused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Refusal {
    /// The matching itself failed (see the failure).
    Matching { failure: PointFailure },
    /// Its height lies away from the plane through its neighbours by more than they allow.
    Neighbourhood { residual_m: f64, limit_m: f64 },
    /// Its σ₀ is many times its neighbours'.
    Sigma0 { ratio: f64 },
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refusal::Matching { failure } => write!(f, "{failure}"),
            Refusal::Neighbourhood {
                residual_m,
                limit_m,
            } => write!(
                f,
                "{residual_m:+.2} m from its neighbours' plane (limit {limit_m:.2} m)"
            ),
            Refusal::Sigma0 { ratio } => write!(f, "σ0 {ratio:.1} × its neighbours'"),
        }
    }
}

/// A finest-level point as it is written: the matching's result and the verdict.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FinePoint {
    pub result: PointResult,
    pub refusal: Option<Refusal>,
}

/// `report.json` of an MGCM run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MgcmReport {
    /// The project, the method, the CRS and the orientations the model took.
    #[serde(flatten)]
    pub head: ReportHead,
    /// The photo carrying the templates, and the photos searched.
    pub reference: String,
    pub searched: Vec<String>,
    /// Every reference with the photos searched from it: the first is `reference`; more
    /// where some overlapping pair has neither photo as a reference.
    #[serde(default)]
    pub references: Vec<(String, Vec<String>)>,
    pub heights_m: [f64; 2],
    pub extent: [f64; 4],
    pub config: MgcmConfig,
    pub levels: Vec<LevelReport>,
    /// Finest-level points: selected, kept, and how many rays the kept ones have (index =
    /// rays including the reference).
    pub selected: usize,
    pub kept: usize,
    pub rays_histogram: Vec<usize>,
    /// Mean height error per pixel of parallax along the widest epipolar line, m/px.
    pub m_per_px: f64,
    pub seconds: f64,
    pub points_per_second: f64,
    /// The patches' averaging taken out of the nodes (see [`crate::matching::accuracy::averaging`]).
    #[serde(default)]
    pub averaging: Option<AveragingReport>,
    #[serde(flatten)]
    pub model: ModelFigures,
    /// Seed 002's accuracy analysis of the points against the reference model.
    pub accuracy: Option<Accuracy>,
    /// What makes the run doubtful (the heights tried missing the terrain, …).
    #[serde(default)]
    pub warnings: Vec<String>,
}

impl MgcmReport {
    pub fn summary(&self) -> Vec<(String, String)> {
        let mut v = self.head.lines(
            format!(
                "multiphoto geometrically constrained matching: {}",
                if self.references.is_empty() {
                    format!(
                        "photo {} against {}",
                        self.reference,
                        self.searched.join(", ")
                    )
                } else {
                    self.references
                        .iter()
                        .map(|(r, o)| format!("photo {r} against {}", o.join(", ")))
                        .collect::<Vec<_>>()
                        .join("; ")
                }
            ),
            self.heights_m,
        );
        for l in &self.levels {
            v.push((
                format!("level {}", l.level),
                format!(
                    "{} × {} px: {} tried, {} matched, {} blunders",
                    l.size[0], l.size[1], l.tried, l.matched, l.blunders
                ),
            ));
        }
        v.push((
            "points".into(),
            format!(
                "{} selected, {} kept ({:.0} points/s)",
                self.selected, self.kept, self.points_per_second
            ),
        ));
        v.extend(self.model.lines());
        for w in &self.warnings {
            v.push(("warning".into(), w.clone()));
        }
        if let Some(a) = &self.accuracy {
            let v1 = &a.versions[0];
            v.push((
                "points against the reference".into(),
                format!(
                    "RMS {:.3} m ({:.3} ‰ hg, {:.3} px of parallax), max {:.2} m; {} undetected blunders ({:.2} %)",
                    v1.rms_m,
                    v1.rms_permille,
                    v1.rms_m / self.m_per_px,
                    v1.max_abs_m,
                    a.undetected,
                    a.undetected_percent
                ),
            ));
            if let Some(p) = &a.precision {
                v.push((
                    "σ against the true error".into(),
                    format!(
                        "RMS(error/σ) {:.2} without the bias, {:.2} with it; {:.0} % within 2σ",
                        p.rms_ratio, p.rms_ratio_with_bias, p.within_2_sigma_percent
                    ),
                ));
            }
        }
        v
    }
}

/// Heights on a regular grid of one level's reference image: node (i, j) at pixel
/// (margin + i·spacing, margin + j·spacing).
#[derive(Debug, Clone)]
struct LevelGrid {
    spacing: usize,
    margin: usize,
    cols: usize,
    rows: usize,
    z: Vec<f64>,
}

impl LevelGrid {
    fn new(width: usize, height: usize, spacing: usize, margin: usize) -> Option<LevelGrid> {
        if width <= 2 * margin + spacing || height <= 2 * margin + spacing {
            return None;
        }
        let cols = (width - 2 * margin) / spacing + 1;
        let rows = (height - 2 * margin) / spacing + 1;
        Some(LevelGrid {
            spacing,
            margin,
            cols,
            rows,
            z: vec![f64::NAN; cols * rows],
        })
    }

    fn pixel(&self, i: usize, j: usize) -> (usize, usize) {
        (
            self.margin + i * self.spacing,
            self.margin + j * self.spacing,
        )
    }

    /// Bilinear height at continuous point (x, y) of this level (clamped to the nodes).
    fn at(&self, x: f64, y: f64) -> f64 {
        let s = self.spacing as f64;
        let u = ((x - 0.5 - self.margin as f64) / s).clamp(0.0, (self.cols - 1) as f64);
        let v = ((y - 0.5 - self.margin as f64) / s).clamp(0.0, (self.rows - 1) as f64);
        let (i, j) = (
            (u as usize).min(self.cols.saturating_sub(2)),
            (v as usize).min(self.rows.saturating_sub(2)),
        );
        let (fu, fv) = (u - i as f64, v - j as f64);
        let i1 = (i + 1).min(self.cols - 1);
        let j1 = (j + 1).min(self.rows - 1);
        let z = |a: usize, b: usize| self.z[b * self.cols + a];
        let top = z(i, j) + fu * (z(i1, j) - z(i, j));
        let bottom = z(i, j1) + fu * (z(i1, j1) - z(i, j1));
        top + fv * (bottom - top)
    }

    /// Blunders: a node further than `limit` from the median of its (at least 3) neighbours
    /// is removed; the number removed.
    fn remove_blunders(&mut self, limit: f64) -> usize {
        crate::matching::grid::remove_blunders(&mut self.z, self.cols, self.rows, limit)
    }

    /// Holes filled with the mean of their neighbours, ring by ring; false when the grid has
    /// no height at all.
    fn fill_holes(&mut self) -> bool {
        crate::matching::grid::fill_holes(&mut self.z, self.cols, self.rows).is_some()
    }
}

/// The multi-photo height sweep at the top level: the height whose patches correlate best
/// with the template, on average over the search photos that see them.
fn sweep_height(
    reference: View<'_>,
    q0: (usize, usize),
    searches: &[View<'_>],
    heights: [f64; 2],
    step: f64,
    half: usize,
) -> Option<f64> {
    let tpl = template(reference.image, q0.0, q0.1, half).ok()?;
    let qc = PixelXY::new(q0.0 as f64 + 0.5, q0.1 as f64 + 0.5);
    let mid = 0.5 * (heights[0] + heights[1]);
    let shapes: Vec<Option<[[f64; 2]; 2]>> = searches
        .iter()
        .map(|s| local_shape(reference.sensor, s.sensor, qc, mid))
        .collect();
    // At most 100 000 heights: a finer step than that is widened, never the range cut.
    let step = step.max((heights[1] - heights[0]) / 1e5);
    let n = (((heights[1] - heights[0]) / step).ceil().clamp(0.0, 1e5)) as usize + 1;
    let mut best: Option<(f64, f64)> = None;
    let mut g = Vec::with_capacity(tpl.values.len());
    let h = half as i64;
    for k in 0..n.min(100_000) {
        let z = heights[0] + k as f64 * step;
        let Some(p) = reference.sensor.image_to_ground(qc, z) else {
            continue;
        };
        let (mut sum, mut seen) = (0.0, 0);
        for (s, shape) in searches.iter().zip(&shapes) {
            let (Some(c), Some(m)) = (s.sensor.ground_to_image(p), shape) else {
                continue;
            };
            g.clear();
            let mut ok = true;
            'patch: for v in -h..=h {
                for u in -h..=h {
                    let (du, dv) = (u as f64, v as f64);
                    match s.image.image.bilinear(
                        c.col + m[0][0] * du + m[0][1] * dv,
                        c.row + m[1][0] * du + m[1][1] * dv,
                    ) {
                        Some(x) => g.push(x as f64),
                        None => {
                            ok = false;
                            break 'patch;
                        }
                    }
                }
            }
            if ok {
                sum += crate::correlation::ncc(&tpl.values, &g);
                seen += 1;
            }
        }
        if seen > 0 {
            let score = sum / seen as f64;
            if best.is_none_or(|b| score > b.1) {
                best = Some((z, score));
            }
        }
    }
    best.filter(|b| b.1 > 0.3).map(|b| b.0)
}

/// The grey range (1st to 99th percentile) of an image, from a sample of its pixels.
fn grey_range(img: &crate::image::ImageF32) -> f64 {
    let step = (img.data.len() / 100_000).max(1);
    let mut v: Vec<f32> = img.data.iter().step_by(step).copied().collect();
    if v.is_empty() {
        return 0.0;
    }
    v.sort_unstable_by(f32::total_cmp);
    let at = |f: f64| v[((v.len() - 1) as f64 * f) as usize] as f64;
    at(0.99) - at(0.01)
}

/// Matches the nodes of one level, from approximations `approx` (None: the top level's sweep).
#[allow(clippy::too_many_arguments)]
fn match_level(
    reference: View<'_>,
    searches: &[View<'_>],
    grid: &mut LevelGrid,
    approx: Option<&LevelGrid>,
    heights: [f64; 2],
    step: f64,
    p: &AdjustParams,
    tests: &RayTests,
) -> LevelOutcome {
    let nodes: Vec<(usize, usize)> = (0..grid.rows)
        .flat_map(|j| (0..grid.cols).map(move |i| (i, j)))
        .collect();
    // Per node: the matched height, and where the sweep put it (-1 at the lowest height
    // tried, 1 at the highest, 0 between; None without a sweep).
    let found: Vec<(f64, Option<i8>)> = nodes
        .par_iter()
        .map(|&(i, j)| {
            let q = grid.pixel(i, j);
            let (z0, bound) = match approx {
                // Level k + 1's continuous point is this level's halved.
                Some(a) => (
                    a.at((q.0 as f64 + 0.5) / 2.0, (q.1 as f64 + 0.5) / 2.0),
                    None,
                ),
                None => match sweep_height(reference, q, searches, heights, step, p.half) {
                    Some(z) => {
                        let at = if z < heights[0] + step {
                            -1
                        } else if z > heights[1] - step {
                            1
                        } else {
                            0
                        };
                        (z, Some(at))
                    }
                    None => return (f64::NAN, None),
                },
            };
            match match_point(reference, q, searches, z0, p, tests).solution {
                Ok(s) => (s.ground.z, bound),
                Err(_) => (f64::NAN, bound),
            }
        })
        .collect();
    grid.z = found.iter().map(|f| f.0).collect();
    let count = |b: i8| found.iter().filter(|f| f.1 == Some(b)).count();
    LevelOutcome {
        matched: grid.z.iter().filter(|v| v.is_finite()).count(),
        swept: found.iter().filter(|f| f.1.is_some()).count(),
        at_bounds: [count(-1), count(1)],
    }
}

/// One level's matching: heights found, and at the top where the sweep found them.
struct LevelOutcome {
    matched: usize,
    /// Nodes the sweep gave a height, and those within a step of the lowest and the
    /// highest height tried (a pile there: the terrain reaches beyond).
    swept: usize,
    at_bounds: [usize; 2],
}

/// A share of the top level's sweep heights at a bound of the range above which a run
/// warns, %: the coarse top level has a few hundred nodes, some of them flat.
const PILE_WARNING_PERCENT: f64 = 10.0;

/// What the patch model leaves of the terrain (a crease between two slopes, a knoll: no
/// affine follows them) and of resampling, px of parallax, added to every point's σ_Z. The
/// residuals show it only in part (it is one smooth misfit across the patch, which the
/// adjustment absorbs as well as it can). Calibrated on simulated blocks: noise-free and
/// with 100 and 200 grey values of noise, seeds 3 and 5 (see docs/matchers.md).
pub const MODEL_FLOOR_PX: f64 = 0.03;

/// A point whose σ₀ is this many times its neighbours' median is refused: its patch is not
/// the template's in a way the affine does not follow (a crease of the terrain, an
/// occlusion), and its height errs by more than its σ says.
const SIGMA0_RATIO: f64 = 2.0;

/// A kept point as its neighbours see it: index, template pixel, Z, σ₀, σ_Z.
type Neighbour = (usize, (f64, f64), f64, f64, f64);

/// Tests every finest-level point against its neighbours (those kept in the cells around it):
/// its height against their plane, its σ₀ against theirs.
fn neighbourhood_tests(points: &mut [FinePoint], radius_px: f64, m_per_px: f64) {
    let kept: Vec<Neighbour> = points
        .iter()
        .enumerate()
        .filter_map(|(k, p)| {
            let s = p.result.solution.as_ref().ok()?;
            let (c, r) = p.result.pixel;
            // σ_Z without the orientations' part: neighbours share it, their plane absorbs
            // it, and counting it would loosen the test in resected blocks.
            let local = (s.sigma[2].powi(2) - s.sigma_orientation[2].powi(2))
                .max(0.0)
                .sqrt();
            Some((k, (c as f64, r as f64), s.ground.z, s.sigma0, local))
        })
        .collect();
    let mut buckets: std::collections::HashMap<(i64, i64), Vec<usize>> = Default::default();
    for (i, o) in kept.iter().enumerate() {
        let key = ((o.1 .0 / radius_px) as i64, (o.1 .1 / radius_px) as i64);
        buckets.entry(key).or_default().push(i);
    }
    let verdicts: Vec<(usize, Option<Refusal>)> = kept
        .par_iter()
        .map(|&(k, (c, r), z, s0, sz)| {
            let (bc, br) = ((c / radius_px) as i64, (r / radius_px) as i64);
            let near: Vec<&Neighbour> = (bc - 1..=bc + 1)
                .flat_map(|u| (br - 1..=br + 1).map(move |v| (u, v)))
                .filter_map(|key| buckets.get(&key))
                .flatten()
                .map(|&i| &kept[i])
                .filter(|o| {
                    o.0 != k && ((o.1 .0 - c).powi(2) + (o.1 .1 - r).powi(2)).sqrt() < radius_px
                })
                .collect();
            if near.len() < 5 {
                return (k, None);
            }
            let mut s0s: Vec<f64> = near.iter().map(|o| o.3).collect();
            let mid = s0s.len() / 2;
            let med = *s0s.select_nth_unstable_by(mid, f64::total_cmp).1;
            if med > 0.0 && s0 > SIGMA0_RATIO * med {
                return (k, Some(Refusal::Sigma0 { ratio: s0 / med }));
            }
            // z = a + b·dc + c·dr through the neighbours.
            let mut nm = nalgebra::Matrix3::<f64>::zeros();
            let mut b = nalgebra::Vector3::<f64>::zeros();
            for o in &near {
                let a =
                    nalgebra::Vector3::new(1.0, (o.1 .0 - c) / radius_px, (o.1 .1 - r) / radius_px);
                nm += a * a.transpose();
                b += a * o.2;
            }
            let Some(sol) = nm.try_inverse().map(|i| i * b) else {
                return (k, None);
            };
            let mut res: Vec<f64> = near
                .iter()
                .map(|o| {
                    (o.2 - sol[0]
                        - sol[1] * (o.1 .0 - c) / radius_px
                        - sol[2] * (o.1 .1 - r) / radius_px)
                        .abs()
                })
                .collect();
            let mid = res.len() / 2;
            let mad = *res.select_nth_unstable_by(mid, f64::total_cmp).1;
            let scale = 1.4826 * mad;
            let limit = (4.0 * (scale * scale + sz * sz).sqrt()).max(m_per_px);
            let residual = z - sol[0];
            if residual.abs() > limit {
                (
                    k,
                    Some(Refusal::Neighbourhood {
                        residual_m: residual,
                        limit_m: limit,
                    }),
                )
            } else {
                (k, None)
            }
        })
        .collect();
    for (k, v) in verdicts {
        points[k].refusal = v;
    }
}

/// Runs the MGCM of `run`'s project on its photos.
pub fn run(run: &Run) -> Result<MgcmReport, MatchingError> {
    let started = std::time::Instant::now();
    let (p, photos, out) = (run.project, run.photos, run.out);
    let (max_memory_mb, progress) = (run.max_memory_mb, run.progress);
    let cfg = p.matching.mgcm.clone();
    let b = block(p, photos, cfg.reference.as_deref(), "matching.mgcm")?;
    let (mid, r, others) = (b.mid, b.reference, b.others);
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
    // The references: the one named, or enough of them that every overlapping pair has one
    // (a strip's first photo sees only its half of the second's overlap with the third).
    let references = match cfg.reference {
        Some(_) => vec![(r, others)],
        None => references_covering(r, others, &overlapping),
    };
    // Memory: every pyramid (image and two gradients, 4/3 of level 0's pixels).
    let mut used: Vec<usize> = references
        .iter()
        .flat_map(|(r, o)| std::iter::once(*r).chain(o.iter().copied()))
        .collect();
    used.sort_unstable();
    used.dedup();
    let bytes: u64 = used
        .iter()
        .map(|&k| (photos[k].image.data.len() as u64) * 4 * 3 * 4 / 3)
        .sum();
    let limit = max_memory_mb.unwrap_or(p.limits.max_memory_mb) << 20;
    if bytes > limit {
        return Err(MatchingError::Memory(format!(
            "the pyramids of {} photos need {} MiB; the limit is {} MiB ([limits] max_memory_mb or --max-memory)",
            used.len(),
            bytes >> 20,
            limit >> 20
        )));
    }
    // Levels every photo's pyramid has (the first reference is among them).
    let levels = used
        .iter()
        .map(|&k| levels_for(photos[k].image.width, photos[k].image.height, cfg.top_px))
        .fold(usize::MAX, usize::min);
    progress.begin("pyramids", used.len() as u64);
    let pyr: Vec<(usize, Vec<Textured>)> = used
        .clone()
        .into_par_iter()
        .map(|k| {
            let t = pyramid(photos[k].image.clone(), levels);
            progress.advance(1);
            (k, t)
        })
        .collect();
    progress.end();
    let at = Shared {
        sensors: &sensors,
        pyr: &pyr,
        heights,
        mid,
        levels,
        cfg: &cfg,
        cell_m: p.cell_m,
        progress,
    };
    let mut runs = Vec::new();
    for (r, others) in &references {
        runs.push(match_reference(&at, *r, others)?);
    }
    let first = &runs[0];
    let m_per_px = first.m_per_px;
    let centre0 = first.centre;
    let mut level_reports = Vec::new();
    let mut warnings = Vec::new();
    let mut points: Vec<(usize, FinePoint)> = Vec::new();
    let mut fine_seconds = 0.0;
    for run in &runs {
        level_reports.extend(run.levels.iter().cloned());
        for w in &run.warnings {
            if !warnings.contains(w) {
                warnings.push(w.clone());
            }
        }
        points.extend(run.points.iter().cloned().map(|pt| (run.reference, pt)));
        fine_seconds += run.fine_seconds;
    }
    let kept: Vec<&FinePoint> = points
        .iter()
        .map(|(_, p)| p)
        .filter(|p| p.refusal.is_none())
        .collect();
    let most = references.iter().map(|(_, o)| o.len()).max().unwrap_or(0);
    let mut rays_histogram = vec![0usize; most + 2];
    let matched: Vec<MatchedPoint> = kept
        .iter()
        .filter_map(|p| {
            let s = p.result.solution.as_ref().ok()?;
            rays_histogram[s.rays.len() + 1] += 1;
            Some(MatchedPoint {
                ground: s.ground,
                corr: s.corr() as f32,
                sigma_m: s.sigma[2] as f32,
            })
        })
        .collect();
    // The DEM from the points.
    let budget = max_memory_mb.unwrap_or(p.limits.max_memory_mb);
    let mut grid = ElevationGrid::covering(extent, p.cell_m, budget)
        .map_err(|e| MatchingError::Grid(e.to_string()))?;
    // The points' spacing on the ground, the widest of the references'.
    let spacing_m = runs
        .iter()
        .map(|run| run.cell as f64 * run.gsd_m)
        .fold(f64::NAN, f64::max);
    // A ground pixel that cannot be found counts as a metre (as it did before references).
    let spacing_m = if spacing_m.is_finite() {
        spacing_m
    } else {
        runs.iter().map(|run| run.cell).max().unwrap_or(1) as f64
    };
    let radius_m = 1.6 * spacing_m;
    let mut quality = grid.fill_scattered(&matched, radius_m);
    // The patches' window on the ground, the widest of the references'.
    let window_m = runs
        .iter()
        .map(|run| cfg.patch as f64 * run.gsd_m)
        .fold(f64::NAN, f64::max);
    let averaging = remove_window_averaging(
        &mut grid,
        &mut quality,
        Kernel::scattered(window_m, spacing_m, radius_m),
    );
    tracing::info!(?averaging, "window averaging removed");
    let reference_dem = run.reference;
    let model = ModelFigures::check(p, reference_dem, &obs, grid, &quality.sigma_m);
    let hg = flying_height(&sensors[r], centre0, mid).unwrap_or(f64::NAN);
    // Blunders the matcher detected: points its tests refused (not those it could not try:
    // a flat template, one at the edge, a ray that cannot reach the height).
    let refused = points
        .iter()
        .filter(|(_, p)| match &p.refusal {
            None => false,
            Some(Refusal::Matching { failure }) => !matches!(
                failure,
                PointFailure::Flat | PointFailure::TemplateOutside | PointFailure::NoRay
            ),
            Some(_) => true,
        })
        .count();
    let accuracy = reference_dem.map(|g| {
        let d: Vec<(f64, f64)> = matched
            .iter()
            .filter_map(|m| {
                let z = g.interpolate(m.ground.x, m.ground.y);
                z.is_finite().then_some((m.ground.z - z, m.sigma_m as f64))
            })
            .collect();
        // A blunder is a wrong match: half a pixel of parallax at least.
        analyse(&d, refused, hg, 0.5 * m_per_px)
    });
    let seconds = started.elapsed().as_secs_f64();
    let report = MgcmReport {
        head: ReportHead {
            project: p.path.clone(),
            method: "mgcm".into(),
            crs: p.crs,
            resected,
            corrected,
        },
        reference: p.photos[r].id.clone(),
        searched: references[0]
            .1
            .iter()
            .map(|&k| p.photos[k].id.clone())
            .collect(),
        references: references
            .iter()
            .map(|(r, o)| {
                (
                    p.photos[*r].id.clone(),
                    o.iter().map(|&k| p.photos[k].id.clone()).collect(),
                )
            })
            .collect(),
        heights_m: heights,
        extent,
        config: cfg.clone(),
        levels: level_reports,
        selected: points.len(),
        kept: matched.len(),
        rays_histogram,
        m_per_px,
        seconds,
        points_per_second: points.len() as f64 / fine_seconds.max(1e-9),
        averaging,
        model,
        accuracy,
        warnings,
    };
    let write = |source| MatchingError::Write {
        dir: out.to_path_buf(),
        cause: source,
    };
    run.write_model(
        &report.model,
        &matched,
        &quality,
        &sensors,
        &report,
        &report.summary(),
    )?;
    let ids: Vec<&str> = p.photos.iter().map(|ph| ph.id.as_str()).collect();
    crate::atomic::write(
        &out.join(outputs::POINTS_CSV),
        points_csv(&points, &references, &ids).as_bytes(),
    )
    .map_err(write)?;
    if let Some(a) = &report.accuracy {
        crate::atomic::write(&out.join(outputs::ACCURACY_TXT), a.table().as_bytes())
            .map_err(write)?;
        crate::atomic::write_json(&out.join(outputs::ACCURACY_JSON), a).map_err(write)?;
    } else {
        for f in [outputs::ACCURACY_TXT, outputs::ACCURACY_JSON] {
            let _ = std::fs::remove_file(out.join(f));
        }
    }
    Ok(report)
}

/// What every reference's matching shares: the block's sensors and pyramids, the heights
/// and the configuration.
struct Shared<'a> {
    sensors: &'a [crate::geometry::PhotoSensor],
    pyr: &'a [(usize, Vec<Textured>)],
    heights: [f64; 2],
    mid: f64,
    levels: usize,
    cfg: &'a MgcmConfig,
    /// The DEM's post spacing, m.
    cell_m: f64,
    progress: &'a dyn Progress,
}

/// One reference photo's matching: its pyramid levels and its finest points.
struct ReferenceRun {
    reference: usize,
    /// The reference image's centre, px.
    centre: PixelXY,
    levels: Vec<LevelReport>,
    points: Vec<FinePoint>,
    m_per_px: f64,
    /// The points' cell, px, and the reference's ground pixel, m.
    cell: usize,
    gsd_m: f64,
    warnings: Vec<String>,
    fine_seconds: f64,
}

/// The pyramid's levels and the finest points with reference `r` and search photos `others`.
fn match_reference(
    at: &Shared<'_>,
    r: usize,
    others: &[usize],
) -> Result<ReferenceRun, MatchingError> {
    let Shared {
        sensors,
        pyr,
        heights,
        mid,
        levels,
        cfg,
        cell_m,
        progress,
    } = *at;
    let (rw, rh) = {
        let t = &pyr.iter().find(|(i, _)| *i == r).expect("built").1[0];
        (t.image.width, t.image.height)
    };
    let sensor_at = |k: usize, level: usize| AtLevel {
        inner: &sensors[k],
        level,
    };
    let centre0 = PixelXY::new(0.5 * rw as f64, 0.5 * rh as f64);
    let gsd_m = sensors[r].ground_pixel_m(centre0, mid).unwrap_or(f64::NAN);
    let cell = cfg.cell.unwrap_or_else(|| auto_cell(cell_m, gsd_m));
    let search_sensors: Vec<&dyn Sensor> =
        others.iter().map(|&k| &sensors[k] as &dyn Sensor).collect();
    let px_per_m0 = parallax_per_m(&sensors[r], &search_sensors, centre0, mid);
    if px_per_m0.is_nan() || px_per_m0 <= 1e-9 {
        return Err(MatchingError::NoMatch(
            "the photos show no parallax with height (no base between them): nothing to match"
                .into(),
        ));
    }
    let m_per_px = 1.0 / px_per_m0;
    // Coarse to fine, on grids.
    let coarse = cfg.coarse();
    let tests = cfg.tests();
    let mut level_reports = Vec::new();
    let mut warnings = Vec::new();
    let mut previous: Option<LevelGrid> = None;
    for level in (1..=levels).rev() {
        let refs: Vec<AtLevel> = std::iter::once(r)
            .chain(others.iter().copied())
            .map(|k| sensor_at(k, level))
            .collect();
        let img = |k: usize| &pyr.iter().find(|(i, _)| *i == k).expect("built").1[level];
        let reference = View {
            image: img(r),
            sensor: &refs[0],
        };
        let searches: Vec<View> = others
            .iter()
            .zip(&refs[1..])
            .map(|(&k, s)| View {
                image: img(k),
                sensor: s,
            })
            .collect();
        let (w, h) = (reference.image.image.width, reference.image.image.height);
        let spacing = 2;
        let margin = coarse.half + 2;
        let Some(mut grid) = LevelGrid::new(w, h, spacing, margin) else {
            continue;
        };
        let scale = (1u64 << level) as f64;
        let step = 0.5 * m_per_px * scale;
        progress.begin(&format!("level {level}"), 1);
        let outcome = match_level(
            reference,
            &searches,
            &mut grid,
            previous.as_ref(),
            heights,
            step,
            &coarse,
            &tests,
        );
        let matched = outcome.matched;
        for (n, which, h) in [
            (outcome.at_bounds[0], "lowest", heights[0]),
            (outcome.at_bounds[1], "highest", heights[1]),
        ] {
            let share = 100.0 * n as f64 / outcome.swept.max(1) as f64;
            if share > PILE_WARNING_PERCENT {
                warnings.push(format!(
                    "{share:.0} % of the top level's sweep heights lie within a step of the {which} height tried ({h:.1} m): the terrain may reach beyond {:.1} … {:.1} m; widen [dem] heights",
                    heights[0], heights[1]
                ));
            }
        }
        let blunders = grid.remove_blunders(2.0 * m_per_px * scale);
        progress.advance(1);
        progress.end();
        tracing::info!(level, matched, blunders, "pyramid level matched");
        level_reports.push(LevelReport {
            level,
            size: [w, h],
            tried: grid.z.len(),
            matched,
            blunders,
        });
        if !grid.fill_holes() {
            return Err(MatchingError::NoMatch(format!(
                "no point of pyramid level {level} matched: do the photos overlap within [dem] heights {heights:?}?"
            )));
        }
        previous = Some(grid);
    }
    // The finest level.
    let img0 = |k: usize| &pyr.iter().find(|(i, _)| *i == k).expect("built").1[0];
    let reference = View {
        image: img0(r),
        sensor: &sensors[r],
    };
    let searches: Vec<View> = others
        .iter()
        .map(|&k| View {
            image: img0(k),
            sensor: &sensors[k],
        })
        .collect();
    let directions: Vec<[f64; 2]> = others
        .iter()
        .filter_map(|&k| epipolar_direction(&sensors[r], &sensors[k], centre0, mid, 10.0))
        .collect();
    let selected = select(
        &reference.image.image,
        &directions,
        &cfg.interest(grey_range(&reference.image.image), cell),
    );
    // The orientation's pointing error: the project's between photos given as exact, and
    // each resected photo's own through its sensor (the resection's covariance).
    let fine = cfg.fine();
    progress.begin("points", selected.len() as u64);
    let fine_started = std::time::Instant::now();
    let mut points: Vec<FinePoint> = selected
        .par_iter()
        .map(|pt| {
            let q = pt.pixel;
            let z0 = match &previous {
                Some(g) => g.at((q.0 as f64 + 0.5) / 2.0, (q.1 as f64 + 0.5) / 2.0),
                None => sweep_height(reference, q, &searches, heights, 0.5 * m_per_px, fine.half)
                    .unwrap_or(mid),
            };
            let mut result = match_point(reference, q, &searches, z0, &fine, &tests);
            if let Ok(s) = result.solution.as_mut() {
                s.sigma[2] = s.sigma[2].hypot(MODEL_FLOOR_PX * s.m_per_px);
            }
            progress.advance(1);
            FinePoint {
                result,
                refusal: None,
            }
        })
        .collect();
    progress.end();
    let fine_seconds = fine_started.elapsed().as_secs_f64();
    for pt in points.iter_mut() {
        if let Err(e) = &pt.result.solution {
            pt.refusal = Some(Refusal::Matching { failure: *e });
        }
    }
    neighbourhood_tests(&mut points, 2.5 * cell as f64, m_per_px);
    let kept: Vec<&FinePoint> = points.iter().filter(|p| p.refusal.is_none()).collect();
    // Points beyond the heights tried by more than a pixel of parallax: the pyramid's
    // approximations led the matching there and its tests passed them, but the top level's
    // sweep never looked there; where the terrain reaches beyond, some of it may be missed.
    let (below, above) = kept
        .iter()
        .filter_map(|p| p.result.solution.as_ref().ok())
        .fold((0usize, 0usize), |(b, a), s| {
            (
                b + usize::from(s.ground.z < heights[0] - m_per_px),
                a + usize::from(s.ground.z > heights[1] + m_per_px),
            )
        });
    if (below + above) * 100 > kept.len() && below + above >= 3 {
        warnings.push(format!(
            "{} of the {} points kept lie {} the heights tried ({:.1} … {:.1} m) by more than a pixel of parallax: the terrain reaches beyond them; widen [dem] heights",
            below + above,
            kept.len(),
            if above >= below { "above" } else { "below" },
            heights[0],
            heights[1]
        ));
    }
    level_reports.push(LevelReport {
        level: 0,
        size: [rw, rh],
        tried: points.len(),
        matched: kept.len(),
        blunders: points.len() - kept.len(),
    });
    Ok(ReferenceRun {
        reference: r,
        centre: centre0,
        levels: level_reports,
        points,
        m_per_px,
        cell,
        gsd_m,
        warnings,
        fine_seconds,
    })
}

/// Every finest-level point, kept or refused, with its precision, its rays and the reasons:
/// `col`, `row` of the template in the reference photo (integer values at pixel centres, as
/// everywhere), X, Y, Z and their σ (m), the formal σ of Z, σ₀, iterations, mean correlation,
/// the rays used (photo ids), each used ray's figures (`id: ρ correlation, rms grey residual,
/// Δ constraint residual col/row px`, separated by `; `), `status` (kept or refused), `reason`,
/// and the rays refused (`id: reason`, separated by `; `).
fn points_csv(
    points: &[(usize, FinePoint)],
    references: &[(usize, Vec<usize>)],
    all_ids: &[&str],
) -> String {
    let mut s = String::from(
        "id,col,row,x,y,z,sigma_x,sigma_y,sigma_z,sigma_z_formal,sigma0,iterations,corr,rays,ray_figures,status,reason,refused_rays,reference\n",
    );
    let quote = |t: &str| format!("\"{}\"", t.replace('"', "'"));
    for (k, (reference, p)) in points.iter().enumerate() {
        let ids: Vec<&str> = references
            .iter()
            .find(|(r, _)| r == reference)
            .map(|(_, o)| o.iter().map(|&j| all_ids[j]).collect())
            .unwrap_or_default();
        let ids = ids.as_slice();
        let reference = all_ids[*reference];
        let (c, r) = p.result.pixel;
        let refused_rays = p
            .result
            .rejected
            .iter()
            .map(|j| format!("{}: {}", ids.get(j.photo).unwrap_or(&"?"), j.reason))
            .collect::<Vec<_>>()
            .join("; ");
        let status = if p.refusal.is_none() {
            "kept"
        } else {
            "refused"
        };
        let reason = p
            .refusal
            .as_ref()
            .map(|r| r.to_string())
            .unwrap_or_default();
        match &p.result.solution {
            Ok(sol) => {
                let rays: Vec<&str> = sol
                    .rays
                    .iter()
                    .map(|ray| *ids.get(ray.photo).unwrap_or(&"?"))
                    .collect();
                let figures: Vec<String> = sol
                    .rays
                    .iter()
                    .map(|ray| {
                        format!(
                            "{}: ρ {:.4}, rms {:.3}, Δ {:.3}/{:.3} px",
                            ids.get(ray.photo).unwrap_or(&"?"),
                            ray.corr,
                            ray.rms,
                            ray.constraint_px[0],
                            ray.constraint_px[1]
                        )
                    })
                    .collect();
                s += &format!(
                    "{},{},{},{:.3},{:.3},{:.3},{:.4},{:.4},{:.4},{:.4},{:.4},{},{:.4},{},{},{},{},{},{}\n",
                    k + 1,
                    c,
                    r,
                    sol.ground.x,
                    sol.ground.y,
                    sol.ground.z,
                    sol.sigma[0],
                    sol.sigma[1],
                    sol.sigma[2],
                    sol.sigma_formal[2],
                    sol.sigma0,
                    sol.iterations,
                    sol.corr(),
                    quote(&rays.join(" ")),
                    quote(&figures.join("; ")),
                    status,
                    quote(&reason),
                    quote(&refused_rays),
                    quote(reference)
                );
            }
            Err(_) => {
                s += &format!(
                    "{},{},{},,,,,,,,,,,,,{},{},{},{}\n",
                    k + 1,
                    c,
                    r,
                    status,
                    quote(&reason),
                    quote(&refused_rays),
                    quote(reference)
                );
            }
        }
    }
    s
}
