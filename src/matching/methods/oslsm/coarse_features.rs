//! Seed 001's feature route to the coarse DEM (3.2) over whole photos: the reference photo
//! and each photo overlapping it are cut into conjugate (epipolar) line pairs, each pair's
//! grey-value profiles into edges with their property lists, the edges matched as strings
//! ([`crate::matching::methods::oslsm::edge_strings`]), and each matched pair intersected for its height.
//!
//! The line pairs come from the sensors alone ([`crate::geometry::Sensor`], so a pushbroom's
//! curved epipolar lines are followed too): through a reference pixel q, the ray's points at
//! two heights project into the other photo at a and b; the other photo's ray through a,
//! taken back to the reference at the second height, lands at c, and q–c is the epipolar
//! line's direction there. A line is traced in unit steps from a start on the perpendicular
//! through the reference's centre, its direction renewed every few steps; its conjugate is
//! the reference line's ground points at the middle height seen in the other photo, so that
//! a point at another height appears shifted along it by its parallax.
//!
//! Matching runs coarse to fine (smoothing σ 8, 4 and 2 px). The coarsest level's few
//! strong edges are matched over the whole height range, line by line; their disparities are
//! binned by reference pixel (cells of 3σ) and the median over the 3 × 3 cells around an edge
//! (the lines beside each other vote) guides the next level there; each finer level looks
//! only near the disparity the coarser pairs give (interpolated along the line, after pairs
//! that disagree with their neighbours are dropped). The heights are then checked against
//! those around them, gridded by the median at each node, nodes off their neighbours'
//! median by more than the caller's limit (three pixels of parallax) are dropped, and the
//! holes are filled (by the caller).
//!
//! Known limit: the coarsest level gives about one mutual match a line; on a long base over
//! a steep slope (one profile compressed by a third against the other, so that the edges'
//! amplitudes and widths no longer agree) a third of them are wrong there, and the finer
//! levels follow them. The sweep is then the better start.

use crate::coords::{GroundM, PixelXY};
use crate::matching::methods::oslsm::edge_strings::{
    edges, match_strings, CostWeights, EdgeParams, Window,
};
use crate::matching::methods::oslsm::PhotoView;
use crate::matching::progress::Progress;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Smoothing of the profiles at each level, coarse to fine, px.
pub const LEVELS_SIGMA_PX: [f64; 3] = [8.0, 4.0, 2.0];
/// Epipolar lines are this far apart across the base, reference px.
pub const LINE_SPACING_PX: f64 = 2.0;
/// An edge's smoothed gradient must stand this many times above the noise's.
const EDGE_SNR: f64 = 4.0;
/// The direction of a line is renewed every this many steps.
const RENEW_STEPS: usize = 8;
/// Profiles shorter than this (samples) are not matched.
const MIN_PROFILE: usize = 48;

/// What the feature route found, for the report.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FeatureReport {
    /// Photo id of each pair's other photo, with its line pairs, edges (reference and
    /// other, finest level), matched pairs and points kept (height within the range).
    pub pairs: Vec<FeaturePairReport>,
    /// Points over all photo pairs.
    pub points: usize,
    /// Points dropped as off the median of those around them (or with too few around),
    /// grid nodes dropped as off their neighbours, and nodes with a height left.
    pub rejected: usize,
    pub blunders: usize,
    pub nodes: usize,
    /// The grid's cell, m, and the nodes without a height filled from their neighbours
    /// (by the caller).
    pub cell_m: f64,
    pub holes_filled: usize,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FeaturePairReport {
    pub photo: String,
    pub lines: usize,
    pub edges_reference: usize,
    pub edges_other: usize,
    pub matched: usize,
    pub points: usize,
}

/// One conjugate line pair: reference samples in unit steps and their conjugates in the other
/// photo (the reference's ground points at the middle height), with both grey profiles.
#[derive(Debug, Clone, Default)]
pub struct LinePair {
    pub reference: Vec<PixelXY>,
    pub other: Vec<PixelXY>,
    pub left: Vec<f64>,
    pub right: Vec<f64>,
}

/// The epipolar direction (unit) in the reference photo at `q`, heights `h`; `None` where a
/// ray misses a height or the photos have no base.
pub fn epipolar_direction(r: PhotoView, k: PhotoView, q: PixelXY, h: [f64; 2]) -> Option<[f64; 2]> {
    let a = k
        .sensor
        .ground_to_image(r.sensor.image_to_ground(q, h[0])?)?;
    let c = r
        .sensor
        .ground_to_image(k.sensor.image_to_ground(a, h[1])?)?;
    let (dx, dy) = (c.col - q.col, c.row - q.row);
    let n = dx.hypot(dy);
    (n.is_finite() && n > 1e-6).then(|| [dx / n, dy / n])
}

fn inside(img: &crate::image::ImageF32, q: PixelXY) -> bool {
    q.col >= 0.5
        && q.row >= 0.5
        && q.col <= img.width as f64 - 0.5
        && q.row <= img.height as f64 - 0.5
}

/// The conjugate line pairs of reference `r` and photo `k` over heights `h` (lo, hi), lines
/// `spacing` px apart: each the contiguous run of samples both photos frame.
pub fn line_pairs(r: PhotoView, k: PhotoView, h: [f64; 2], spacing: f64) -> Vec<LinePair> {
    let Some(plan) = LinePlan::new(r, k, h, spacing) else {
        return Vec::new();
    };
    (0..plan.starts)
        .into_par_iter()
        .flat_map_iter(|s| plan.runs(r, k, s))
        .collect()
}

/// Where the lines start: along the perpendicular through the reference's centre, far
/// enough for every corner. A line's runs are traced when needed and let go, so that a large
/// photo's line pairs are never all in memory at once.
struct LinePlan {
    centre: PixelXY,
    e: [f64; 2],
    reach: f64,
    spacing: f64,
    starts: usize,
    h: [f64; 2],
}

impl LinePlan {
    fn new(r: PhotoView, k: PhotoView, h: [f64; 2], spacing: f64) -> Option<LinePlan> {
        let (w, ht) = (r.image.width as f64, r.image.height as f64);
        let centre = PixelXY::new(0.5 * w, 0.5 * ht);
        let e = epipolar_direction(r, k, centre, h)?;
        let reach = 0.5 * w.hypot(ht);
        Some(LinePlan {
            centre,
            e,
            reach,
            spacing,
            starts: (2.0 * reach / spacing).ceil() as usize + 1,
            h,
        })
    }

    /// The runs of line `s`.
    fn runs(&self, r: PhotoView, k: PhotoView, s: usize) -> Vec<LinePair> {
        let n = [-self.e[1], self.e[0]];
        let off = -self.reach + s as f64 * self.spacing;
        let start = PixelXY::new(self.centre.col + off * n[0], self.centre.row + off * n[1]);
        let mid = 0.5 * (self.h[0] + self.h[1]);
        trace(r, k, start, self.e, self.h, mid, self.reach)
    }
}

/// The samples of one line through `start` (both ways, `reach` px each), split into the runs
/// both photos frame.
fn trace(
    r: PhotoView,
    k: PhotoView,
    start: PixelXY,
    e0: [f64; 2],
    h: [f64; 2],
    mid: f64,
    reach: f64,
) -> Vec<LinePair> {
    let steps = (2.0 * reach).ceil() as usize;
    // Walk back to the far end first, then forward: one list in order.
    let walk = |from: PixelXY, sign: f64, n: usize| -> Vec<PixelXY> {
        let mut v = Vec::with_capacity(n);
        let mut q = from;
        let mut e = e0;
        for i in 0..n {
            if i % RENEW_STEPS == 0 {
                if let Some(d) = epipolar_direction(r, k, q, h) {
                    // Keep the sense of the start's direction.
                    e = if d[0] * e0[0] + d[1] * e0[1] >= 0.0 {
                        d
                    } else {
                        [-d[0], -d[1]]
                    };
                }
            }
            q = PixelXY::new(q.col + sign * e[0], q.row + sign * e[1]);
            v.push(q);
        }
        v
    };
    let mut back = walk(start, -1.0, steps / 2);
    back.reverse();
    let fwd = walk(start, 1.0, steps / 2);
    let all = back.into_iter().chain(std::iter::once(start)).chain(fwd);
    let mut out = Vec::new();
    let mut cur = LinePair::default();
    let mut flush = |cur: &mut LinePair| {
        let run = std::mem::take(cur);
        if run.reference.len() >= MIN_PROFILE {
            out.push(run);
        }
    };
    for q in all {
        let sample = inside(r.image, q)
            .then(|| {
                let p = k
                    .sensor
                    .ground_to_image(r.sensor.image_to_ground(q, mid)?)?;
                let a = r.image.bilinear(q.col, q.row)?;
                let b = k.image.bilinear(p.col, p.row)?;
                Some((p, a as f64, b as f64))
            })
            .flatten();
        match sample {
            Some((p, a, b)) => {
                cur.reference.push(q);
                cur.other.push(p);
                cur.left.push(a);
                cur.right.push(b);
            }
            None => flush(&mut cur),
        }
    }
    flush(&mut cur);
    out
}

/// σ of the white noise in a profile: the median absolute second difference (over √6 and
/// the normal's 0.6745). Texture adds to it, so it errs high: fewer, surer edges.
fn noise_sigma(p: &[f64]) -> f64 {
    let mut d: Vec<f64> = p
        .windows(3)
        .map(|w| (w[0] - 2.0 * w[1] + w[2]).abs())
        .collect();
    if d.is_empty() {
        return 0.0;
    }
    let mid = d.len() / 2;
    *d.select_nth_unstable_by(mid, f64::total_cmp).1 / (0.6745 * 6f64.sqrt())
}

/// How much of white noise's σ a Gaussian of σ `s` followed by a central difference passes
/// (the root sum of squares of the combined kernel).
fn gradient_noise_gain(s: f64) -> f64 {
    let r = (3.0 * s).ceil().max(1.0) as i64;
    let k: Vec<f64> = (-r..=r)
        .map(|i| (-((i * i) as f64) / (2.0 * s * s)).exp())
        .collect();
    let sum: f64 = k.iter().sum();
    let at = |i: i64| -> f64 {
        if i < -r || i > r {
            0.0
        } else {
            k[(i + r) as usize] / sum
        }
    };
    (-r - 1..=r + 1)
        .map(|i| {
            let c = 0.5 * (at(i + 1) - at(i - 1));
            c * c
        })
        .sum::<f64>()
        .sqrt()
}

/// One matched edge pair at the finest level: positions along the line (samples).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineMatch {
    pub left: f64,
    pub right: f64,
}

/// Matches one line pair's profiles at smoothing `levels` (σ px, coarse to fine): the first
/// level's edges within `first` (of their position), each further level's within 1.5 of the
/// previous σ of the disparity the previous level's pairs give (interpolated along the line).
/// The last level's pairs (those agreeing with their neighbours along the line), and the
/// edges found there on either side.
pub fn match_levels(
    lp: &LinePair,
    levels: &[f64],
    first: &dyn Fn(f64) -> Window,
) -> (Vec<LineMatch>, usize, usize) {
    let noise = noise_sigma(&lp.left).max(noise_sigma(&lp.right)).max(1e-9);
    let weights = CostWeights {
        disparity: 0.0,
        ..CostWeights::default()
    };
    let mut prev: Vec<LineMatch> = Vec::new();
    let mut counts = (0, 0);
    for (level, &s) in levels.iter().enumerate() {
        let p = EdgeParams {
            sigma_px: s,
            min_amplitude: EDGE_SNR * noise * gradient_noise_gain(s),
        };
        let (le, re) = (edges(&lp.left, &p), edges(&lp.right, &p));
        counts = (le.len(), re.len());
        let coarser = levels[level.saturating_sub(1)];
        let guide = clean(&prev, coarser);
        if level > 0 && guide.len() < 2 {
            return (Vec::new(), counts.0, counts.1);
        }
        let slack = 1.5 * coarser;
        let window = |at: f64| -> Window {
            if level == 0 {
                return first(at);
            }
            let d = interpolate(&guide, at);
            Window {
                range: [d - slack, d + slack],
                expected: d,
            }
        };
        let pairs = match_strings(&le, &re, &window, &weights);
        prev = pairs
            .iter()
            .map(|pr| LineMatch {
                left: le[pr.left].at,
                right: re[pr.right].at,
            })
            .collect();
    }
    let last = levels.last().copied().unwrap_or(1.0);
    (clean(&prev, last), counts.0, counts.1)
}

/// The coarsest level's disparities binned by their reference pixel (cells of `cell` px):
/// the median of those in the 3 × 3 cells around a pixel is the guide of the finer levels
/// there. A mismatch on one line is outvoted by the lines beside it, which see the same
/// field borders.
struct Guide {
    cell: f64,
    bins: std::collections::HashMap<(i64, i64), Vec<f64>>,
}

impl Guide {
    fn key(&self, q: PixelXY) -> (i64, i64) {
        (
            (q.col / self.cell).floor() as i64,
            (q.row / self.cell).floor() as i64,
        )
    }

    fn new(cell: f64, points: impl Iterator<Item = (PixelXY, f64)>) -> Guide {
        let mut g = Guide {
            cell,
            bins: Default::default(),
        };
        for (q, d) in points {
            let k = g.key(q);
            g.bins.entry(k).or_default().push(d);
        }
        g
    }

    /// The median disparity around `q`, if at least 3 are there.
    fn at(&self, q: PixelXY) -> Option<f64> {
        let (bx, by) = self.key(q);
        let mut v: Vec<f64> = Vec::new();
        for dx in -1..=1 {
            for dy in -1..=1 {
                if let Some(b) = self.bins.get(&(bx + dx, by + dy)) {
                    v.extend_from_slice(b);
                }
            }
        }
        if v.len() < 3 {
            return None;
        }
        let mid = v.len() / 2;
        Some(*v.select_nth_unstable_by(mid, f64::total_cmp).1)
    }
}

/// The pairs whose disparity lies within 2σ (of their level) of the median of their four
/// neighbours' on either side along the line (a mismatch differs; the terrain does not jump
/// between neighbouring edges).
fn clean(m: &[LineMatch], s: f64) -> Vec<LineMatch> {
    let d: Vec<f64> = m.iter().map(|x| x.right - x.left).collect();
    (0..m.len())
        .filter(|&i| {
            let mut n: Vec<f64> = (i.saturating_sub(4)..(i + 5).min(m.len()))
                .filter(|&j| j != i)
                .map(|j| d[j])
                .collect();
            if n.len() < 2 {
                return false;
            }
            let mid = n.len() / 2;
            let med = *n.select_nth_unstable_by(mid, f64::total_cmp).1;
            (d[i] - med).abs() <= 2.0 * s
        })
        .map(|i| m[i])
        .collect()
}

/// The disparity at `at` along the line from pairs in order: linear between the two around
/// it, the nearest's beyond the ends.
fn interpolate(m: &[LineMatch], at: f64) -> f64 {
    let i = m.partition_point(|x| x.left < at);
    let d = |x: &LineMatch| x.right - x.left;
    if i == 0 {
        return d(&m[0]);
    }
    if i == m.len() {
        return d(&m[m.len() - 1]);
    }
    let (a, b) = (&m[i - 1], &m[i]);
    let t = if b.left > a.left {
        (at - a.left) / (b.left - a.left)
    } else {
        0.0
    };
    d(a) + t * (d(b) - d(a))
}

/// The sample at continuous index `t` of a polyline.
fn along(v: &[PixelXY], t: f64) -> Option<PixelXY> {
    if !(t >= 0.0 && t <= (v.len() - 1) as f64) {
        return None;
    }
    let i = (t.floor() as usize).min(v.len().saturating_sub(2));
    let f = t - i as f64;
    let (a, b) = (v[i], v[(i + 1).min(v.len() - 1)]);
    Some(PixelXY::new(
        a.col + f * (b.col - a.col),
        a.row + f * (b.row - a.row),
    ))
}

/// The height at which the reference's ray through `q` meets the other photo at `p` along
/// the line (direction `u` in the other photo): Newton on the along-line offset, from the
/// middle height; `None` if it does not converge or the ray misses.
pub fn intersect(
    r: PhotoView,
    k: PhotoView,
    q: PixelXY,
    p: PixelXY,
    u: [f64; 2],
    mid: f64,
) -> Option<f64> {
    let phi = |h: f64| -> Option<f64> {
        let f = k.sensor.ground_to_image(r.sensor.image_to_ground(q, h)?)?;
        Some((f.col - p.col) * u[0] + (f.row - p.row) * u[1])
    };
    let mut h = mid;
    for _ in 0..8 {
        let (a, b) = (phi(h + 0.5)?, phi(h - 0.5)?);
        let slope = a - b;
        if slope.is_nan() || slope.abs() <= 1e-9 {
            return None;
        }
        let step = phi(h)? / slope;
        h -= step;
        if !h.is_finite() {
            return None;
        }
        if step.abs() < 1e-4 {
            return Some(h);
        }
    }
    None
}

/// The disparity (samples along the conjugate line) of height `h` at sample `i` of line pair
/// `lp`.
fn disparity_of(r: PhotoView, k: PhotoView, lp: &LinePair, i: usize, h: f64) -> Option<f64> {
    let j = (i + 1).min(lp.other.len() - 1);
    let i = j - 1;
    let (p, p1) = (lp.other[i], lp.other[j]);
    let u = [p1.col - p.col, p1.row - p.row];
    let uu = u[0] * u[0] + u[1] * u[1];
    let f = k
        .sensor
        .ground_to_image(r.sensor.image_to_ground(lp.reference[i], h)?)?;
    (uu > 1e-12).then(|| ((f.col - p.col) * u[0] + (f.row - p.row) * u[1]) / uu)
}

/// The coarsest level's pairs of line pair `lp` over the whole height range `h`: each as
/// its reference pixel and disparity.
fn coarse_pairs(r: PhotoView, k: PhotoView, lp: &LinePair, h: [f64; 2]) -> Vec<(PixelXY, f64)> {
    let m = lp.reference.len() / 2;
    let ends = [h[0], h[1]].map(|z| disparity_of(r, k, lp, m, z));
    let (Some(a), Some(b)) = (ends[0], ends[1]) else {
        return Vec::new();
    };
    let pad = 2.0 * LEVELS_SIGMA_PX[0];
    let range = [a.min(b) - pad, a.max(b) + pad];
    let full = |_: f64| Window {
        range,
        expected: 0.5 * (range[0] + range[1]),
    };
    let (pairs, _, _) = match_levels(lp, &LEVELS_SIGMA_PX[..1], &full);
    pairs
        .iter()
        .filter_map(|x| Some((along(&lp.reference, x.left)?, x.right - x.left)))
        .collect()
}

/// The feature route's ground points from reference `r` and photo `k` over heights `h`:
/// every line pair's finest matches intersected; heights outside the range (widened by a
/// tenth) are dropped.
pub fn pair_points(
    r: PhotoView,
    k: PhotoView,
    h: [f64; 2],
    id: &str,
    progress: &dyn Progress,
) -> (Vec<GroundM>, FeaturePairReport) {
    let Some(plan) = LinePlan::new(r, k, h, LINE_SPACING_PX) else {
        return (
            Vec::new(),
            FeaturePairReport {
                photo: id.to_string(),
                ..Default::default()
            },
        );
    };
    // Two passes over the lines, each traced afresh (its samples let go after).
    progress.begin(
        &format!("edges along the epipolar lines with photo {id}"),
        2 * plan.starts as u64,
    );
    let mid = 0.5 * (h[0] + h[1]);
    let margin = 0.1 * (h[1] - h[0]).abs();
    // Pass 1: the coarsest level over the whole height range, line by line.
    let coarse: Vec<(usize, Vec<(PixelXY, f64)>)> = (0..plan.starts)
        .into_par_iter()
        .map(|s| {
            let runs = plan.runs(r, k, s);
            let m: Vec<(PixelXY, f64)> = runs
                .iter()
                .flat_map(|lp| coarse_pairs(r, k, lp, h))
                .collect();
            progress.advance(1);
            (runs.len(), m)
        })
        .collect();
    let lines: usize = coarse.iter().map(|c| c.0).sum();
    // The lines beside each other vote on the coarse disparity.
    let guide = Guide::new(
        3.0 * LEVELS_SIGMA_PX[0],
        coarse.into_iter().flat_map(|c| c.1),
    );
    // Pass 2: the finer levels near the guide.
    let per: Vec<(Vec<GroundM>, usize, usize, usize)> = (0..plan.starts)
        .into_par_iter()
        .flat_map_iter(|s| {
            progress.advance(1);
            plan.runs(r, k, s)
        })
        .map(|lp| {
            let lp = &lp; // (owned by this closure: the run was traced for it)
            let slack = 1.5 * LEVELS_SIGMA_PX[0];
            let near = |at: f64| match along(&lp.reference, at).and_then(|q| guide.at(q)) {
                Some(d) => Window {
                    range: [d - slack, d + slack],
                    expected: d,
                },
                None => Window {
                    range: [f64::NAN; 2],
                    expected: f64::NAN,
                },
            };
            let (matches, nl, nr) = match_levels(lp, &LEVELS_SIGMA_PX[1..], &near);
            let pts: Vec<GroundM> = matches
                .iter()
                .filter_map(|x| {
                    let q = along(&lp.reference, x.left)?;
                    let p = along(&lp.other, x.right)?;
                    let i = (x.right.floor() as usize).min(lp.other.len() - 2);
                    let (a, b) = (lp.other[i], lp.other[i + 1]);
                    let (du, dv) = (b.col - a.col, b.row - a.row);
                    let n = du.hypot(dv);
                    let z = intersect(r, k, q, p, [du / n, dv / n], mid)?;
                    if z < h[0].min(h[1]) - margin || z > h[0].max(h[1]) + margin {
                        return None;
                    }
                    r.sensor.image_to_ground(q, z)
                })
                .collect();
            let n = matches.len();
            (pts, nl, nr, n)
        })
        .collect();
    progress.end();
    let mut rep = FeaturePairReport {
        photo: id.to_string(),
        lines,
        ..Default::default()
    };
    let mut pts = Vec::new();
    for (p, nl, nr, n) in per {
        rep.edges_reference += nl;
        rep.edges_other += nr;
        rep.matched += n;
        pts.extend(p);
    }
    rep.points = pts.len();
    (pts, rep)
}

/// The coarse DEM from the feature route: reference `r` with each of `others` (photo and
/// id) over heights `h`, the points' median at each node of `grid` (its cell a few lines'
/// spacing on the ground, so that most nodes hold several points), nodes further than
/// `limit_m` from their neighbours' median dropped (twice: a cluster of mismatches shields
/// itself once). Holes are left for the caller to fill.
pub fn feature_grid(
    r: PhotoView,
    others: &[(PhotoView, String)],
    h: [f64; 2],
    grid: &mut crate::matching::grid::ElevationGrid,
    limit_m: f64,
    progress: &dyn Progress,
) -> FeatureReport {
    let mut report = FeatureReport::default();
    let mut pts = Vec::new();
    for (k, id) in others {
        let (p, rep) = pair_points(r, *k, h, id, progress);
        pts.extend(p);
        report.pairs.push(rep);
    }
    report.points = pts.len();
    let pts = consistent(&pts, 2.0 * grid.cell_m, limit_m);
    report.rejected = report.points - pts.len();
    grid.fill_median(&pts);
    let mut z: Vec<f64> = grid.z.iter().map(|&v| v as f64).collect();
    for _ in 0..2 {
        report.blunders +=
            crate::matching::grid::remove_blunders(&mut z, grid.cols, grid.rows, limit_m);
    }
    for (d, s) in grid.z.iter_mut().zip(&z) {
        *d = *s as f32;
    }
    report.nodes = grid.filled();
    report.cell_m = grid.cell_m;
    report
}

/// The points within `limit_m` of the median height of the others within about 1.5 `cell`
/// (those in the 3 × 3 cells of `cell` around their own), with at least 4 such others: a
/// mismatch lies off the terrain its neighbours (along its line and on the lines beside it)
/// agree on; an isolated point has nothing to vouch for it.
pub fn consistent(pts: &[GroundM], cell: f64, limit_m: f64) -> Vec<GroundM> {
    if pts.is_empty() || !(cell.is_finite() && cell > 0.0) {
        return Vec::new();
    }
    let key = |p: &GroundM| ((p.x / cell).floor() as i64, (p.y / cell).floor() as i64);
    let mut bins: std::collections::HashMap<(i64, i64), Vec<usize>> = Default::default();
    for (i, p) in pts.iter().enumerate() {
        bins.entry(key(p)).or_default().push(i);
    }
    pts.par_iter()
        .enumerate()
        .filter(|&(i, p)| {
            let (bx, by) = key(p);
            let mut z: Vec<f64> = Vec::new();
            for dx in -1..=1 {
                for dy in -1..=1 {
                    if let Some(v) = bins.get(&(bx + dx, by + dy)) {
                        z.extend(v.iter().filter(|&&j| j != i).map(|&j| pts[j].z));
                    }
                }
            }
            if z.len() < 4 {
                return false;
            }
            let mid = z.len() / 2;
            let med = *z.select_nth_unstable_by(mid, f64::total_cmp).1;
            (p.z - med).abs() <= limit_m
        })
        .map(|(_, p)| *p)
        .collect()
}
