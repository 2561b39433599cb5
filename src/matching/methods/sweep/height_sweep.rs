//! Height-sweep matching (seed 000 §2.2): for every pixel of the reference (left) photo the
//! heights from the lowest to the highest are tried in steps; each is mapped into the search
//! (right) photo by the image→image polynomials, so the search runs along the epipolar line
//! they describe, and the window there (resampled bilinearly) is compared with the reference
//! window by normalised cross-correlation — every height at every pixel, by the plane sweep of
//! [`crate::matching::plane_sweep`]. The best above a threshold gives the height, refined below the step
//! by least squares on a plane tilted across the window ([`crate::matching::plane_sweep::refine`]) or by a parabola.
//! Bands of rows run in parallel.

use crate::image::ImageF32;
use crate::matching::mapping::pmf::Mapping;
use crate::matching::plane_sweep::refine::{refine, Subpixel, Window, RHO_MAX};
use crate::matching::plane_sweep::winner::{winner, Unseen, Winner};
use crate::matching::plane_sweep::{score, Cells, Planes, Prepared};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepParams {
    pub h_min: f64,
    pub h_max: f64,
    pub h_step: f64,
    /// Side of the correlation window, px (odd; seed 000: 9).
    pub window: usize,
    /// Lowest correlation accepted (seed 000: 0.5).
    pub threshold: f64,
    /// Refine below the height step.
    pub refine: bool,
    /// How: least squares on a tilted plane (a pixel where it fails gets no height), or a
    /// parabola.
    pub subpixel: Subpixel,
    /// Match every `stride`-th pixel in each direction.
    pub stride: usize,
}

impl Default for SweepParams {
    fn default() -> Self {
        SweepParams {
            h_min: 0.0,
            h_max: 1000.0,
            h_step: 4.0,
            window: 9,
            threshold: 0.5,
            refine: true,
            subpixel: Subpixel::Lsm,
            stride: 1,
        }
    }
}

/// Heights per matched reference pixel: `h[i + j·cols]` belongs to reference pixel
/// (`col0 + i·stride`, `row0 + j·stride`); NaN where no height passed the threshold.
#[derive(Debug, Clone, PartialEq)]
pub struct HeightMap {
    pub cols: usize,
    pub rows: usize,
    pub col0: usize,
    pub row0: usize,
    pub stride: usize,
    pub h: Vec<f32>,
    pub corr: Vec<f32>,
    /// Standard deviation of each height, m (see [`height_sigma`]); NaN where the peak could
    /// not be refined.
    pub sigma: Vec<f32>,
    /// Candidate heights tried in all (for throughput figures).
    pub candidates: u64,
}

impl HeightMap {
    /// The reference pixel's centre (continuous coordinates) of cell (i, j).
    pub fn pixel(&self, i: usize, j: usize) -> [f64; 2] {
        [
            (self.col0 + i * self.stride) as f64 + 0.5,
            (self.row0 + j * self.stride) as f64 + 0.5,
        ]
    }

    pub fn matched(&self) -> usize {
        self.h.iter().filter(|v| v.is_finite()).count()
    }
}

/// The standard deviation of a height from its correlation peak, after Förstner's precision of
/// matching: σ_p² = σ_n² / Σ g′² over the n window pixels, with the noise-to-signal ratio from
/// the correlation, σ_n²/σ_g² = (1 − ρ)/ρ, and the gradients' share σ_g′²/σ_g² = |ρ″|/ρ from
/// the peak's curvature — so σ_h² = (1 − ρ) / (n·|ρ″|), ρ″ the second difference of the
/// correlation over the height steps divided by the step² (per m²): no pixel-to-metre factor
/// is needed, the curvature is already measured in height. `None` for a peak with no curvature.
pub fn height_sigma(rho: f64, second_difference: f64, step_m: f64, n: usize) -> Option<f64> {
    let sd = height_sigma_or_nan(rho, second_difference, step_m, n);
    (!sd.is_nan()).then_some(sd)
}

/// [`height_sigma`], NaN for None: without a branch, so that a row's σ are taken on vector
/// lanes.
#[inline(always)]
pub fn height_sigma_or_nan(rho: f64, second_difference: f64, step_m: f64, n: usize) -> f64 {
    let curvature = -second_difference / (step_m * step_m);
    let ok = rho.is_finite() && curvature.is_finite() && curvature > 0.0 && n > 0;
    let sd = ((1.0 - rho.min(RHO_MAX)) / (n as f64 * curvature)).sqrt();
    if ok {
        sd
    } else {
        f64::NAN
    }
}

/// Matches every `stride`-th reference pixel whose window lies inside `left`.
pub fn sweep(left: &ImageF32, right: &ImageF32, map: &Mapping, p: &SweepParams) -> HeightMap {
    sweep_with(left, right, map, p, &crate::matching::progress::Silent)
}

/// Rows of the height map matched together. The neighbours that bracket a pixel's height
/// where some heights are unseen are taken only within a band, so every band's result depends
/// on nothing outside it: bands run in parallel, and split between machines (`rig dtm --tile`)
/// they give the same bytes.
pub const BAND_ROWS: usize = 16;

/// Where the sweep's height map lies on the reference photo, from its size alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SweepLayout {
    pub cols: usize,
    pub rows: usize,
    pub col0: usize,
    pub row0: usize,
    pub stride: usize,
}

impl SweepLayout {
    /// The cells of every `stride`-th reference pixel whose window lies inside the photo.
    pub fn new(width: usize, height: usize, p: &SweepParams) -> SweepLayout {
        let k = p.window / 2;
        let s = p.stride.max(1);
        SweepLayout {
            cols: width.saturating_sub(2 * k).div_ceil(s),
            rows: height.saturating_sub(2 * k).div_ceil(s),
            col0: k,
            row0: k,
            stride: s,
        }
    }

    /// Bands of [`BAND_ROWS`] rows (the last may be shorter).
    pub fn bands(&self) -> usize {
        self.rows.div_ceil(BAND_ROWS)
    }

    /// The rows of bands `b0..b1`.
    pub fn band_rows(&self, bands: std::ops::Range<usize>) -> std::ops::Range<usize> {
        (bands.start * BAND_ROWS).min(self.rows)..(bands.end * BAND_ROWS).min(self.rows)
    }
}

/// The heights of some bands of a [`SweepLayout`]: rows `rows` of the height map.
#[derive(Debug, Clone, PartialEq)]
pub struct SweptBands {
    pub bands: std::ops::Range<usize>,
    pub rows: std::ops::Range<usize>,
    pub h: Vec<f32>,
    pub corr: Vec<f32>,
    pub sigma: Vec<f32>,
    pub candidates: u64,
}

/// [`sweep`], reporting the rows matched to `progress`.
pub fn sweep_with(
    left: &ImageF32,
    right: &ImageF32,
    map: &Mapping,
    p: &SweepParams,
    progress: &dyn crate::matching::progress::Progress,
) -> HeightMap {
    let l = SweepLayout::new(left.width, left.height, p);
    let b = sweep_bands(left, right, map, p, 0..l.bands(), progress);
    HeightMap::from_bands(l, vec![b]).expect("one part covering every band")
}

impl HeightMap {
    /// Joins parts of one layout that cover all its bands once, in any order.
    pub fn from_bands(l: SweepLayout, mut parts: Vec<SweptBands>) -> Result<HeightMap, String> {
        parts.sort_by_key(|b| b.bands.start);
        let mut next = 0;
        let n = l.rows * l.cols;
        let (mut h, mut corr, mut sigma) = (
            Vec::with_capacity(n),
            Vec::with_capacity(n),
            Vec::with_capacity(n),
        );
        let mut candidates = 0u64;
        for b in parts {
            if b.bands.start != next {
                return Err(format!(
                    "bands {next}…{} are missing or given twice",
                    b.bands.start.max(next + 1) - 1
                ));
            }
            let want = l.band_rows(b.bands.clone());
            let cells = want.len() * l.cols;
            if b.rows != want || [b.h.len(), b.corr.len(), b.sigma.len()] != [cells; 3] {
                return Err(format!(
                    "bands {}…{}: rows {:?} with {} cells, the layout has rows {want:?} with {cells}",
                    b.bands.start,
                    b.bands.end.saturating_sub(1),
                    b.rows,
                    b.h.len()
                ));
            }
            next = b.bands.end;
            h.extend(b.h);
            corr.extend(b.corr);
            sigma.extend(b.sigma);
            candidates = candidates.saturating_add(b.candidates);
        }
        if next != l.bands() {
            return Err(format!(
                "bands {next}…{} are missing",
                l.bands().max(next + 1) - 1
            ));
        }
        Ok(HeightMap {
            cols: l.cols,
            rows: l.rows,
            col0: l.col0,
            row0: l.row0,
            stride: l.stride,
            h,
            corr,
            sigma,
            candidates,
        })
    }
}

/// The offsets from a window's centre that least squares asks the mapping for
/// ([`refine`]'s contract).
const PROBES: [(f64, f64); 3] = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)];

/// Matches the rows of bands `bands` of the layout of `left` (see [`SweepLayout`]): each band
/// is one plane sweep over every height (see [`crate::matching::plane_sweep`]); per pixel the best
/// correlation above the threshold, refined below the step by least squares (or, where that
/// fails or is not asked for, a parabola). A pixel for which some height puts the window
/// beyond the right photo gets no height: the ground may be at that height.
pub fn sweep_bands(
    left: &ImageF32,
    right: &ImageF32,
    map: &Mapping,
    p: &SweepParams,
    bands: std::ops::Range<usize>,
    progress: &dyn crate::matching::progress::Progress,
) -> SweptBands {
    sweep_bands_guided(left, right, map, p, bands, progress, true)
}

/// [`sweep_bands`], coarse to fine where `guided` ([`guide`]), else over every height.
fn sweep_bands_guided(
    left: &ImageF32,
    right: &ImageF32,
    map: &Mapping,
    p: &SweepParams,
    bands: std::ops::Range<usize>,
    progress: &dyn crate::matching::progress::Progress,
    guided: bool,
) -> SweptBands {
    let l = SweepLayout::new(left.width, left.height, p);
    let bands = bands.start.min(l.bands())..bands.end.min(l.bands());
    let k = p.window / 2;
    let (s, cols) = (l.stride, l.cols);
    let rows = l.band_rows(bands.clone());
    let all_planes = planes_of(p);
    let guide = guided.then(|| guide(left, right, map, p, &l)).flatten();
    let (lp, rp) = (Prepared::new(left), Prepared::new(right));
    // Each band's tiles and their heights: one tile of every height, or those the coarser
    // level leaves open. The progress counts their candidates, so that its time left holds
    // where bands the coarse level saw take a few heights and the others all of them.
    let band_rows = |b: usize| (b * BAND_ROWS, ((b + 1) * BAND_ROWS).min(l.rows));
    let band_tiles: Vec<Vec<(usize, usize, usize, usize)>> = bands
        .clone()
        .map(|b| {
            guide
                .as_ref()
                .map_or_else(|| vec![(0, cols, 0, all_planes)], |g| g.tiles(b, &l, k))
        })
        .collect();
    let refine_units = if p.refine && p.subpixel == Subpixel::Lsm {
        LSM_UNITS
    } else {
        0
    };
    let work = |b: usize, tiles: &[(usize, usize, usize, usize)]| -> u64 {
        let (j0, j1) = band_rows(b);
        tiles
            .iter()
            .map(|&(i0, i1, _, n)| ((j1 - j0) * (i1 - i0) * (n + refine_units)) as u64)
            .sum()
    };
    let total: u64 = bands
        .clone()
        .zip(&band_tiles)
        .map(|(b, t)| work(b, t))
        .sum();
    progress.begin("sweep (candidate heights, least squares counted)", total);
    type Band = (Vec<f32>, Vec<f32>, Vec<f32>, u64);
    let parts: Vec<Band> = bands
        .clone()
        .zip(band_tiles)
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|(b, tiles)| {
            let (j0, j1) = band_rows(b);
            let rows_px: Vec<usize> = (j0..j1).map(|j| l.row0 + j * s).collect();
            let rows_n = rows_px.len();
            let n = rows_n * cols;
            let (mut h, mut corr, mut sigma) =
                (vec![f32::NAN; n], vec![f32::NAN; n], vec![f32::NAN; n]);
            let mut tried = 0u64;
            for (i0, i1, first_plane, n_planes) in tiles {
                let tile_cols = i1 - i0;
                let h0 = p.h_min + first_plane as f64 * p.h_step;
                let planes = Planes::Heights {
                    map,
                    h0,
                    step: p.h_step,
                    count: n_planes,
                };
                let cells = Cells {
                    col0: l.col0 + i0 * s,
                    stride: s,
                    cols: tile_cols,
                    rows: rows_px.clone(),
                };
                let scores = score(&lp, &rp, &planes, k, &cells);
                tried += (rows_n * tile_cols * n_planes) as u64;
                // Pass 1: winners the right photo saw at every height. Pass 2: a pixel for
                // which some heights are unseen keeps its best seen one only if its neighbours
                // of pass 1 bracket it and every height of that bracket is seen (the terrain
                // does not jump from all its neighbours to a height the photo cannot show).
                let mut first: Vec<Option<Winner>> = Vec::with_capacity(rows_n * tile_cols);
                for jj in 0..rows_n {
                    for i in 0..tile_cols {
                        first.push(winner(scores.cell(i, jj), Unseen::Refuse));
                    }
                }
                for (jj, &r) in rows_px.iter().enumerate() {
                    for i in 0..tile_cols {
                        let c = cells.col0 + i * s;
                        let cell = scores.cell(i, jj);
                        let w = match first[jj * tile_cols + i] {
                            Some(w) => w,
                            None => {
                                let Some(w) = winner(cell, Unseen::Skip) else {
                                    continue;
                                };
                                if !bracketed(&first, tile_cols, rows_n, i, jj, w.plane, cell) {
                                    continue;
                                }
                                w
                            }
                        };
                        if (w.score as f64) < p.threshold {
                            continue;
                        }
                        let (off, den) = w.parabola().unwrap_or((0.0, f64::NAN));
                        let mut t = w.plane as f64 + if p.refine { off } else { 0.0 };
                        let mut sd =
                            height_sigma(w.score as f64, den, p.h_step, p.window * p.window);
                        if p.refine && p.subpixel == Subpixel::Lsm {
                            let px = [c as f64 + 0.5, r as f64 + 0.5];
                            // The mapping at the three points least squares follows, each a
                            // function of the height alone (the same numbers as the whole
                            // polynomial's, for a third of the work).
                            let along = PROBES.map(|(u, v)| map.along_height(px[0] + u, px[1] + v));
                            let locate = |u: f64, v: f64, t: f64| {
                                let probe = PROBES.iter().position(|&o| o == (u, v));
                                match probe.and_then(|k| along[k].as_ref()) {
                                    Some([x, y]) => {
                                        let h = h0 + t * p.h_step;
                                        [x.eval(h), y.eval(h)]
                                    }
                                    None => planes.locate(px[0] + u, px[1] + v, t),
                                }
                            };
                            let win = Window { c, r, k };
                            match refine(left, win, right, &locate, t, 2.0) {
                                // Beyond the range: the ground is higher or lower than tried;
                                // kept at the bound, where the pile warning counts it.
                                Ok(f) => {
                                    t = f.t.clamp(0.0, (n_planes - 1) as f64);
                                    sd = Some(f.sigma_t * p.h_step);
                                }
                                // Where least squares cannot place the window (an occlusion,
                                // a fold, no texture along the line) the coarse peak is no
                                // better.
                                _ => continue,
                            }
                        }
                        let o = jj * cols + i0 + i;
                        h[o] = (h0 + t * p.h_step) as f32;
                        corr[o] = w.score;
                        sigma[o] = sd.map_or(f32::NAN, |v| v as f32);
                    }
                }
            }
            progress.advance(tried + (rows_n * cols * refine_units) as u64);
            (h, corr, sigma, tried)
        })
        .collect();
    progress.end();
    let cells = rows.len() * cols;
    let (mut h, mut corr, mut sigma) = (
        Vec::with_capacity(cells),
        Vec::with_capacity(cells),
        Vec::with_capacity(cells),
    );
    let mut candidates = 0;
    for (bh, bc, bs, t) in parts {
        h.extend(bh);
        corr.extend(bc);
        sigma.extend(bs);
        candidates += t;
    }
    SweptBands {
        bands,
        rows,
        h,
        corr,
        sigma,
        candidates,
    }
}

/// What least squares at a pixel costs in the sweep's progress, in candidate heights: 13 µs
/// against 31 ns a candidate (a 1 600² pair of `rig sim scene` read from 3 200 px scans, 2.4
/// million pixels refined: 21.3 s with it, 5.7 s with the parabola). Counted for every pixel
/// of a band (most are matched), so that the time left holds where bands differ in heights.
const LSM_UNITS: usize = 400;

/// The coarse level's guide stops where it would have fewer planes than this …
const GUIDE_PLANES: usize = 32;
/// … or a photo's shorter side fewer pixels than this.
const GUIDE_SIDE: usize = 64;

/// Map columns of a tile of the coarse-to-fine sweep.
const TILE_COLS: usize = 64;

/// Coarse to fine (seed 002 matches down a pyramid): where the sweep has many heights, the
/// photos `f` = 2ᴸ times smaller are swept first over the whole range with a step `f` times
/// larger (the same half pixel of parallax there). Each tile of the full-size sweep (a band's
/// rows, [`TILE_COLS`] columns) whose coarse cells — those under it and one around — hold a
/// height at nine in ten then tries only the heights they found, from their lowest to their
/// highest and two coarse steps beyond; a tile the coarse level did not cover so (an overlap's
/// edge, no texture) tries every height as before. The work then grows with the pixels and
/// the local relief where the coarse level sees the ground, and a pixel near the overlap's
/// edge inside a covered tile is no longer refused for heights its neighbourhood does not
/// reach. `None` where the sweep is small enough as it is.
fn guide(
    left: &ImageF32,
    right: &ImageF32,
    map: &Mapping,
    p: &SweepParams,
    l: &SweepLayout,
) -> Option<Guide> {
    let n = planes_of(p);
    let side = left
        .width
        .min(left.height)
        .min(right.width)
        .min(right.height);
    let mut level = 0;
    while n >> level > GUIDE_PLANES && side >> (level + 1) >= GUIDE_SIDE {
        level += 1;
    }
    if level == 0 || l.cols == 0 {
        return None;
    }
    let f = 1usize << level;
    let coarse_p = SweepParams {
        h_step: p.h_step * f as f64,
        subpixel: Subpixel::Parabola,
        stride: 1,
        ..p.clone()
    };
    let coarse = sweep(
        &left.averaged(f),
        &right.averaged(f),
        &map.coarser(f as f64),
        &coarse_p,
    );
    Some(Guide {
        coarse,
        f,
        margin: 2.0 * coarse_p.h_step,
        planes: n,
        h_min: p.h_min,
        h_step: p.h_step,
    })
}

/// The coarse level's heights, from which each tile takes its planes ([`guide`]).
struct Guide {
    coarse: HeightMap,
    /// How many times smaller the coarse photos are.
    f: usize,
    /// How far (m) beyond the coarse heights a tile searches.
    margin: f64,
    planes: usize,
    h_min: f64,
    h_step: f64,
}

impl Guide {
    /// Band `b`'s tiles: (first column, end column, first plane, planes).
    fn tiles(&self, b: usize, l: &SweepLayout, k: usize) -> Vec<(usize, usize, usize, usize)> {
        let hc = &self.coarse;
        let f = self.f;
        let rows = l.band_rows(b..b + 1);
        let top = (l.row0 + rows.start * l.stride).saturating_sub(k) / f;
        let bottom = (l.row0 + rows.end.saturating_sub(1) * l.stride + k) / f;
        // The coarse map's rows and (below) columns around the tile, empty where the tile lies
        // beyond the coarse map (its last pixels, which the coarse windows do not reach).
        let end = (bottom + 2).saturating_sub(hc.row0).min(hc.rows);
        let jc = top.saturating_sub(1 + hc.row0).min(end)..end;
        (0..l.cols)
            .step_by(TILE_COLS)
            .map(|i0| {
                let i1 = (i0 + TILE_COLS).min(l.cols);
                let left = (l.col0 + i0 * l.stride).saturating_sub(k) / f;
                let right = (l.col0 + (i1 - 1) * l.stride + k) / f;
                let end = (right + 2).saturating_sub(hc.col0).min(hc.cols);
                let ic = left.saturating_sub(1 + hc.col0).min(end)..end;
                let cells = jc.len() * ic.len();
                let (mut lo, mut hi, mut found) = (f64::MAX, f64::MIN, 0usize);
                for j in jc.clone() {
                    for z in &hc.h[j * hc.cols + ic.start..j * hc.cols + ic.end] {
                        if z.is_finite() {
                            lo = lo.min(*z as f64);
                            hi = hi.max(*z as f64);
                            found += 1;
                        }
                    }
                }
                if cells == 0 || found * 10 < cells * 9 {
                    return (i0, i1, 0, self.planes);
                }
                let n = self.planes;
                let plane = |z: f64| (z - self.h_min) / self.h_step;
                let first = (plane(lo - self.margin).floor().max(0.0) as usize).min(n - 1);
                let last = (plane(hi + self.margin).ceil().max(0.0) as usize).min(n - 1);
                (i0, i1, first, last.max(first) - first + 1)
            })
            .collect()
    }
}

/// The height step that moves the search window by at most `px` pixels anywhere: `px` over
/// the largest |∂q/∂h| of the image→image mapping on a 5×5 grid of the reference photo
/// (`width` × `height` px) at the lowest, middle and highest height of `heights` (the
/// parallax grows towards the camera, so the top of the range sets it). Seed 000 swept in 2 m
/// steps that were 4–9 px there: too coarse for the peak to be found and refined. None when
/// the mapping has no parallax (no base).
pub fn step_for_parallax(
    map: &Mapping,
    width: usize,
    height: usize,
    heights: [f64; 2],
    px: f64,
) -> Option<f64> {
    let mut rate = 0.0f64;
    let dh = ((heights[1] - heights[0]) * 1e-3).max(1e-3);
    for i in 0..5 {
        for j in 0..5 {
            let (x, y) = (
                width as f64 * i as f64 / 4.0,
                height as f64 * j as f64 / 4.0,
            );
            for k in 0..3 {
                let h = heights[0] + (heights[1] - heights[0]) * k as f64 / 2.0;
                let a = map.eval([x, y, h - dh]);
                let b = map.eval([x, y, h + dh]);
                rate = rate.max((b[0] - a[0]).hypot(b[1] - a[1]) / (2.0 * dh));
            }
        }
    }
    (rate.is_finite() && rate > 1e-9).then(|| px / rate)
}

/// Cells either side searched for the neighbours that bracket a pixel's height.
const BRACKET_REACH: usize = 4;
/// Steps the bracket is widened by on both sides.
const BRACKET_MARGIN: usize = 2;

/// Whether plane `plane` of cell (i, j) lies within the planes of its band neighbours'
/// pass-1 winners (at least 3 of them, within [`BRACKET_REACH`] cells), widened by
/// [`BRACKET_MARGIN`] steps, with every plane of that bracket seen for this cell.
fn bracketed(
    first: &[Option<Winner>],
    cols: usize,
    rows: usize,
    i: usize,
    j: usize,
    plane: usize,
    cell: &[f32],
) -> bool {
    let (mut lo, mut hi, mut n) = (usize::MAX, 0usize, 0);
    for jj in j.saturating_sub(BRACKET_REACH)..(j + BRACKET_REACH + 1).min(rows) {
        for ii in i.saturating_sub(BRACKET_REACH)..(i + BRACKET_REACH + 1).min(cols) {
            if let Some(w) = first[jj * cols + ii] {
                lo = lo.min(w.plane);
                hi = hi.max(w.plane);
                n += 1;
            }
        }
    }
    if n < 3 {
        return false;
    }
    let lo = lo.saturating_sub(BRACKET_MARGIN);
    let hi = (hi + BRACKET_MARGIN).min(cell.len() - 1);
    (lo..=hi).contains(&plane) && cell[lo..=hi].iter().all(|v| !v.is_nan())
}

/// The heights tried: h_min and every whole step up to h_max.
pub fn planes_of(p: &SweepParams) -> usize {
    let n = ((p.h_max - p.h_min) / p.h_step).floor();
    if n.is_finite() && n >= 0.0 {
        n as usize + 1
    } else {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// x′ = x + 0.5·h, y′ = y (half a pixel of parallax a metre, along the rows), fitted over
    /// samples spanning `extent` (x, y in px from row 10, h in m) as the pair's mapping
    /// functions are.
    fn half_a_pixel_a_metre(extent: [f64; 3]) -> Mapping {
        use crate::matching::mapping::pmf::{Normaliser, Polynomial, Term};
        let samples: Vec<([f64; 3], f64)> = (0..4)
            .flat_map(|i| {
                (0..3).map(move |k| {
                    let i = i as f64;
                    [
                        i * extent[0] / 3.0,
                        10.0 + i * extent[1] / 3.0,
                        k as f64 * extent[2] / 2.0,
                    ]
                })
            })
            .map(|v| (v, v[0] + 0.5 * v[2]))
            .collect();
        let norm = Normaliser::over(&samples.iter().map(|s| s.0).collect::<Vec<_>>());
        let terms = [Term(0, 0, 0), Term(1, 0, 0), Term(0, 0, 1)];
        let x = Polynomial::fit(&terms, &norm, &samples).unwrap();
        let ys: Vec<_> = samples.iter().map(|s| (s.0, s.0[1])).collect();
        let y = Polynomial::fit(&[Term(0, 0, 0), Term(0, 1, 0)], &norm, &ys).unwrap();
        Mapping { x, y }
    }

    /// A correlation peak ρ(h) = ρ0·(1 − k·(h − h0)²/2) sampled at steps: σ from the second
    /// difference equals the closed form √((1 − ρ0)/(n·ρ0·k)), whatever the step.
    #[test]
    fn sigma_from_the_peak_curvature_matches_the_closed_form() {
        let (rho0, k, n) = (0.9, 0.8, 81);
        let want = ((1.0 - rho0) / (n as f64 * rho0 * k)).sqrt();
        for step in [0.1, 0.5, 1.0] {
            let r = |h: f64| rho0 * (1.0 - 0.5 * k * h * h);
            let d2 = r(-step) - 2.0 * r(0.0) + r(step);
            let got = height_sigma(rho0, d2, step, n).unwrap();
            assert!(
                (got - want).abs() < 1e-12 * want.max(1.0),
                "{got} vs {want}"
            );
        }
        // A flat or inverted peak, or a NaN, has no σ.
        assert_eq!(height_sigma(0.9, 0.0, 1.0, 81), None);
        assert_eq!(height_sigma(0.9, 0.1, 1.0, 81), None);
        assert_eq!(height_sigma(f64::NAN, -0.1, 1.0, 81), None);
        assert_eq!(height_sigma(0.9, f64::NAN, 1.0, 81), None);
        assert_eq!(height_sigma(0.9, -0.1, 1.0, 0), None);
    }

    /// The right photo sees less than the left: where the true height's window lies beyond
    /// its edge, the sweep must find nothing rather than the best of the heights it can still
    /// score. Every height it gives is the true one (within two steps), and the columns whose
    /// match lies outside get none.
    #[test]
    fn no_height_is_invented_where_the_right_photo_does_not_see() {
        let (w, h) = (160usize, 40usize);
        // A texture with detail at every scale, the same every run.
        let tex = |x: f64, y: f64| -> f32 {
            ((x * 0.71).sin() * (y * 0.53).cos()
                + (x * 0.23 + y * 0.37).sin()
                + (x * 1.7 - y * 1.3).sin() * 0.5) as f32
        };
        let mut left = ImageF32::new(w, h);
        for r in 0..h {
            for c in 0..w {
                left.data[r * w + c] = tex(c as f64, r as f64);
            }
        }
        // x″ = x′ + 0.5·h: at the true height 40 m the right photo is the left moved 20 px,
        // and it is 40 px narrower.
        let (h0, wr) = (40.0, w - 40);
        let mut right = ImageF32::new(wr, h);
        for r in 0..h {
            for c in 0..wr {
                right.data[r * wr + c] = tex(c as f64 - 0.5 * h0, r as f64);
            }
        }
        let map = half_a_pixel_a_metre([150.0, 21.0, 100.0]);
        let p = SweepParams {
            h_min: 0.0,
            h_max: 100.0,
            h_step: 1.0,
            ..Default::default()
        };
        let hm = sweep(&left, &right, &map, &p);
        let (mut inside, mut outside_matched) = (0, 0);
        for j in 0..hm.rows {
            for i in 0..hm.cols {
                let v = hm.h[j * hm.cols + i];
                let [c, _] = hm.pixel(i, j);
                // The true match's window, 9 px wide, centred at c + 20.
                let sees = c + 0.5 * h0 + 4.5 < wr as f64;
                if v.is_finite() {
                    assert!(
                        (v as f64 - h0).abs() < 2.0,
                        "column {c}: {v} m, true {h0} m"
                    );
                    if sees {
                        inside += 1;
                    } else {
                        outside_matched += 1;
                    }
                }
            }
        }
        assert_eq!(
            outside_matched, 0,
            "heights invented beyond the right photo's edge"
        );
        assert!(inside > 1000, "{inside} matched where the right photo sees");
    }

    /// Coarse to fine against the sweep over every height, on a 256 × 256 pair over a slope
    /// (heights 100 … 177 m, half a pixel of parallax a metre, the search photo stretched by
    /// 15 %) swept over 0 … 400 m in 1 m steps: the guide engages, gives no height further than
    /// 5 m from the truth (no more than every height does), at least 85 % as many within 2 m
    /// (as many, here), and tries under 60 % of the candidates (53 %: the tiles along the
    /// search photo's edge, which the coarse level does not cover, try every height).
    #[test]
    fn the_coarse_guide_keeps_the_heights_and_cuts_the_work() {
        let (w, h) = (256usize, 256usize);
        // Random grey values every 2 px, bilinear between: texture without a period, which
        // the 15 % stretch of the slope keeps correlated over a window.
        let mut u = crate::test_rng::uniform(5);
        let n = 200usize;
        let g: Vec<f64> = (0..n * n).map(|_| 2.0 * u() - 1.0).collect();
        let tex = |x: f64, y: f64| -> f32 {
            let top = (n - 2) as f64;
            let (gx, gy) = ((x / 2.0).clamp(0.0, top), (y / 2.0).clamp(0.0, top));
            let (i, j) = (gx.floor() as usize, gy.floor() as usize);
            let (fx, fy) = (gx - i as f64, gy - j as f64);
            let at = |a: usize, b: usize| g[b * n + a];
            (at(i, j) * (1.0 - fx) * (1.0 - fy)
                + at(i + 1, j) * fx * (1.0 - fy)
                + at(i, j + 1) * (1.0 - fx) * fy
                + at(i + 1, j + 1) * fx * fy) as f32
        };
        let mut left = ImageF32::new(w, h);
        for r in 0..h {
            for c in 0..w {
                left.data[r * w + c] = tex(c as f64 + 0.5, r as f64 + 0.5);
            }
        }
        // The ground at column x (continuous) is 100 + 0.3·x m; x′ = x + 0.5·h.
        let height = |x: f64| 100.0 + 0.3 * x;
        let wr = 350usize;
        let mut right = ImageF32::new(wr, h);
        for r in 0..h {
            for c in 0..wr {
                let x = (c as f64 + 0.5 - 50.0) / 1.15;
                right.data[r * wr + c] = tex(x, r as f64 + 0.5);
            }
        }
        let map = half_a_pixel_a_metre([240.0, 180.0, 400.0]);
        let p = SweepParams {
            h_min: 0.0,
            h_max: 400.0,
            h_step: 1.0,
            ..Default::default()
        };
        let l = SweepLayout::new(w, h, &p);
        assert!(
            guide(&left, &right, &map, &p, &l).is_some(),
            "the guide engages"
        );
        let silent = crate::matching::progress::Silent;
        let run = |guided: bool| {
            let b = sweep_bands_guided(&left, &right, &map, &p, 0..l.bands(), &silent, guided);
            HeightMap::from_bands(l, vec![b]).unwrap()
        };
        // Within 2 m, beyond 5 m, candidates.
        let judge = |hm: &HeightMap| {
            let (mut near, mut far) = (0usize, 0usize);
            for j in 0..hm.rows {
                for i in 0..hm.cols {
                    let [c, _] = hm.pixel(i, j);
                    let v = hm.h[j * hm.cols + i] as f64;
                    if v.is_finite() {
                        let e = (v - height(c)).abs();
                        near += usize::from(e < 2.0);
                        far += usize::from(e > 5.0);
                    }
                }
            }
            (near, far, hm.candidates)
        };
        let (every, guided) = (judge(&run(false)), judge(&run(true)));
        eprintln!("every height: {every:?}; coarse to fine: {guided:?} (within 2 m, beyond 5 m, candidates)");
        assert!(
            guided.1 <= every.1,
            "blunders {} against {}",
            guided.1,
            every.1
        );
        assert!(
            guided.0 * 100 >= 85 * every.0,
            "{} within 2 m against {}",
            guided.0,
            every.0
        );
        assert!(
            guided.2 * 10 < every.2 * 6,
            "{} candidates against {}",
            guided.2,
            every.2
        );
        assert_eq!(every.2, (l.rows * l.cols * planes_of(&p)) as u64);
    }

    /// A tile over coarse heights searches them and two coarse steps around; a tile beyond
    /// the coarse map (no coarse cells: the photo's last rows, a map smaller than the layout)
    /// searches every height, and none reaches outside the planes.
    #[test]
    fn tiles_beyond_the_coarse_map_try_every_height() {
        let n = 100;
        let coarse = HeightMap {
            cols: 10,
            rows: 10,
            col0: 4,
            row0: 4,
            stride: 1,
            h: vec![100.0; n],
            corr: vec![0.9; n],
            sigma: vec![0.1; n],
            candidates: 0,
        };
        let g = Guide {
            coarse,
            f: 4,
            margin: 8.0,
            planes: 401,
            h_min: 0.0,
            h_step: 1.0,
        };
        let p = SweepParams {
            h_min: 0.0,
            h_max: 400.0,
            h_step: 1.0,
            ..Default::default()
        };
        let l = SweepLayout::new(300, 300, &p);
        assert_eq!(g.tiles(0, &l, 4)[0], (0, 64, 92, 17));
        for b in 0..l.bands() {
            for (i0, i1, first, count) in g.tiles(b, &l, 4) {
                assert!(i0 < i1 && i1 <= l.cols && count >= 1 && first + count <= 401);
            }
        }
        assert_eq!(
            *g.tiles(l.bands() - 1, &l, 4).last().unwrap(),
            (256, 292, 0, 401)
        );
    }
}
