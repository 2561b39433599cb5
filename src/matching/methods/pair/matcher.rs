//! Matching an epipolar-rectified pair (rows correspond): the plane sweep over whole-pixel
//! disparities d = x_left − x_right (Middlebury's and OpenCV's convention), the winner per
//! pixel, or per pixel after semi-global aggregation, a left-right consistency check, and the
//! sub-pixel disparity by a parabola (through the aggregated costs with SGM, the correlations
//! without) or by least-squares matching with its σ.

use crate::image::ImageF32;
use crate::matching::methods::pair::block_match::{block_match, BlockParams};
use crate::matching::methods::pair::sgm::{
    aggregate_halves, dequantise, quantise, SgmParams, Streamed,
};
use crate::matching::methods::sweep::height_sweep::{height_sigma_or_nan, HeightMap};
use crate::matching::methods::sweep::regions::{remove_wrong_heights, RegionParams};
pub use crate::matching::plane_sweep::refine::Subpixel;
use crate::matching::plane_sweep::refine::{refine, RefineFailure, Window, RHO_MAX};
use crate::matching::plane_sweep::winner::{
    parabola, unique, winner, Pick, RightBest, RowPicks, Unseen,
};
use crate::matching::plane_sweep::{sweep_shifts, CellSink, Cells, Planes, Prepared};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// What removes wrong matches after the winner is taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Filter {
    /// The winner per pixel, nothing more.
    None,
    /// Seed 000's region filter (§2.3) on the disparities.
    Regions,
    /// Semi-global aggregation along 5 or 8 paths before the winner (Hirschmüller 2008).
    Sgm,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PairParams {
    /// Disparities searched, whole pixels, both inclusive.
    pub d_min: i64,
    pub d_max: i64,
    /// Side of the correlation window, px (odd).
    pub window: usize,
    /// Lowest correlation accepted at the winning disparity.
    pub threshold: f64,
    pub filter: Filter,
    pub sgm: SgmParams,
    pub regions: RegionParams,
    /// Largest difference between the left's and the right's disparity, px; None: no check.
    pub lr_tolerance: Option<f64>,
    /// The uniqueness ratio u (0 … 1; 0: no test): every disparity beyond the winner's
    /// neighbours must cost at least 1/(1 − u) times the winner's cost.
    pub uniqueness: f64,
    pub subpixel: Subpixel,
}

impl Default for PairParams {
    fn default() -> Self {
        PairParams {
            d_min: 0,
            d_max: 63,
            window: 5,
            threshold: 0.3,
            filter: Filter::Sgm,
            sgm: SgmParams::default(),
            regions: RegionParams {
                search_distance: 2,
                height_threshold: 1.5,
                population_threshold: 50,
            },
            lr_tolerance: Some(1.0),
            uniqueness: 0.1,
            subpixel: Subpixel::Parabola,
        }
    }
}

/// What happened to the pixels, for the report.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PairStats {
    pub width: usize,
    pub height: usize,
    pub disparities: usize,
    /// Pixel-candidates scored (pixels × disparities).
    pub candidates: u64,
    /// Pixels whose window lies inside the left photo.
    pub pixels: usize,
    /// Pixels without a winner the right photo sees with seen neighbours on both sides.
    pub unseen: usize,
    /// Pixels with a flat window, or a winner with a flat neighbour.
    pub unscored: usize,
    /// Pixels whose best disparity was MIN or MAX (the match may lie beyond the range).
    pub at_range_end: usize,
    /// Pixels whose winner was not unique (another disparity nearly as good).
    pub ambiguous: usize,
    pub below_threshold: usize,
    pub left_right: usize,
    pub regions: usize,
    pub matched: usize,
    pub lsm_refined: usize,
    /// Why least squares failed, and how often (the parabola's value was kept).
    pub lsm_failures: BTreeMap<String, usize>,
    /// Seconds of the semi-global aggregation where it is a step of its own (8 paths; 0
    /// otherwise), of the σ's self-match ([`crate::matching::methods::pair::match_pair`]), and
    /// of the whole match, σ included.
    pub seconds_aggregate: f64,
    #[serde(default)]
    pub seconds_sigma: f64,
    pub seconds_total: f64,
}

/// Disparities on the left photo's pixels (NaN where no match), their correlation and σ (px).
#[derive(Debug, Clone, PartialEq)]
pub struct DisparityMap {
    pub width: usize,
    pub height: usize,
    pub d: Vec<f32>,
    pub corr: Vec<f32>,
    pub sigma: Vec<f32>,
    pub stats: PairStats,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PairError {
    #[error("the photos have {left} and {right} rows: a rectified pair has the same number of rows in both (rectify it first)")]
    Rows { left: usize, right: usize },
    #[error("--disparity {min} {max}: MIN must not exceed MAX, both within ±{MAX_ABS_DISPARITY} px, and at most {MAX_DISPARITIES} disparities searched")]
    Range { min: i64, max: i64 },
    #[error("--window {0}: odd, from 3 to 31 px")]
    Window(usize),
    #[error("the {which} photo ({w} × {h} px) is smaller than the window ({window} px){}", if *w >= 3 && *h >= 3 { ": give a smaller --window (3 at least)" } else { ": at least 3 × 3 px is needed" })]
    TooSmall {
        which: &'static str,
        w: usize,
        h: usize,
        window: usize,
    },
    #[error("--threshold {0}: a correlation from −1 to 1")]
    Threshold(f64),
    #[error("--uniqueness {0} %: from 0 (no test) to 99 %")]
    Uniqueness(f64),
    #[error("--paths {0}: 5 (streamed, the default) or 8 (the whole volume kept)")]
    Paths(u8),
    #[error("matching needs about {need_mib:.0} MiB; the limit is {limit_mib} MiB: crop the photos, narrow the disparities, {}or raise --max-memory", if *volume { "use --paths 5 or --filter none or regions (no cost volume kept), " } else { "" })]
    Memory {
        need_mib: f64,
        limit_mib: u64,
        /// The filter keeps a cost volume (SGM): the other filters need less.
        volume: bool,
    },
}

pub const MAX_DISPARITIES: i64 = 4096;
/// Largest |MIN| and |MAX|, px (far beyond any photo, far from overflow).
pub const MAX_ABS_DISPARITY: i64 = 1_000_000;
/// Most rows scored together (one rayon task).
const BAND: usize = 64;

/// Rows per band: at most [`BAND`], as many bands as an even number, all of one size but the
/// last, so that neither of two threads idles while the other finishes an extra band (596
/// rows in 64s are nine bands of 64 and one of 20: 320 rows on one thread and 276 on the
/// other; in ten bands of 60, 300 and 296). From the rows alone, never the threads: each band
/// starts its sums afresh, so its edges move the rounding, and the numbers must not depend
/// on the machine.
fn band_rows(rows: usize) -> usize {
    let bands = rows.div_ceil(BAND).div_ceil(2) * 2;
    let mut b = rows.div_ceil(bands.max(1)).max(1);
    // Rounding can leave an odd count (3969 rows in 63s are 63 bands): a row less per band
    // until the count is even (a few steps at most).
    while b > 1 && rows.div_ceil(b) % 2 == 1 && rows > b {
        b -= 1;
    }
    b
}

/// Whether matching keeps a volume of scores (SGM along 8 paths).
fn keeps_volume(p: &PairParams) -> bool {
    p.filter == Filter::Sgm && p.sgm.paths == 8
}

/// Whether matching streams the rows (SGM along 5 paths).
pub(super) fn streams(p: &PairParams) -> bool {
    p.filter == Filter::Sgm && p.sgm.paths == 5
}

/// Refuses `need` bytes above the limit, with what a match with `p` could do about it.
pub(super) fn within_memory(
    need: f64,
    max_memory_mb: u64,
    p: &PairParams,
) -> Result<(), PairError> {
    if need > max_memory_mb as f64 * 1048576.0 {
        return Err(PairError::Memory {
            need_mib: need / 1048576.0,
            limit_mib: max_memory_mb,
            volume: keeps_volume(p),
        });
    }
    Ok(())
}

/// Bytes that matching `left` against `right` holds at once: the photos (as read, and
/// prepared), the outputs and matches, each thread's running sums and picks, and for SGM the
/// whole score volume (16-bit codes) with, while it is aggregated, the two sweeps' sums.
pub fn bytes_needed(w: usize, h: usize, wr: usize, p: &PairParams) -> f64 {
    let np = (p.d_max as f64 - p.d_min as f64 + 1.0).max(0.0);
    let k = p.window / 2;
    let cols = w.saturating_sub(2 * k) as f64;
    let rows = h.saturating_sub(2 * k) as f64;
    // The photos as read and as prepared; the three outputs and the rows' matches (24 B).
    let images = 8.0 * (w * h + wr * h) as f64 + 36.0 * (w * h) as f64;
    let threads = rayon::current_num_threads() as f64;
    // A thread's work: with SGM, its column sums (f32 per column and plane), a band's picks
    // and right-photo winners, a row's scores, and the rows of sums; block matching's own.
    let bands = threads
        * match p.filter {
            Filter::Sgm if p.sgm.paths == 5 => {
                // The sweep's column sums, the row's scores and costs, the paths' rows.
                4.0 * np * w as f64
                    + 6.0 * np * cols
                    + crate::matching::methods::pair::sgm::streamed_bytes(cols, np)
                    + 40.0 * cols
                    + 64.0 * (w + wr) as f64
            }
            Filter::Sgm => {
                4.0 * np * (w as f64 + cols) + 40.0 * BAND as f64 * cols + 64.0 * (w + wr) as f64
            }
            _ => crate::matching::methods::pair::block_match::bytes_per_band(
                w,
                wr,
                np as usize,
                k,
                BAND,
            ),
        };
    let volume = match p.filter {
        Filter::Sgm if p.sgm.paths == 8 => {
            cols * rows * np * 2.0
                + crate::matching::methods::pair::sgm::bytes_needed(cols * rows, np, cols)
        }
        _ => 0.0,
    };
    images + bands + volume
}

pub(super) fn check(left: &ImageF32, right: &ImageF32, p: &PairParams) -> Result<(), PairError> {
    if left.height != right.height {
        return Err(PairError::Rows {
            left: left.height,
            right: right.height,
        });
    }
    let bounded = |d: i64| (-MAX_ABS_DISPARITY..=MAX_ABS_DISPARITY).contains(&d);
    if !(bounded(p.d_min) && bounded(p.d_max))
        || p.d_min > p.d_max
        || p.d_max - p.d_min >= MAX_DISPARITIES
    {
        return Err(PairError::Range {
            min: p.d_min,
            max: p.d_max,
        });
    }
    if p.window.is_multiple_of(2) || !(3..=31).contains(&p.window) {
        return Err(PairError::Window(p.window));
    }
    for (which, img) in [("left", left), ("right", right)] {
        if img.width < p.window || img.height < p.window {
            return Err(PairError::TooSmall {
                which,
                w: img.width,
                h: img.height,
                window: p.window,
            });
        }
    }
    if !(-1.0..=1.0).contains(&p.threshold) {
        return Err(PairError::Threshold(p.threshold));
    }
    if !(0.0..=0.99).contains(&p.uniqueness) {
        return Err(PairError::Uniqueness(p.uniqueness * 100.0));
    }
    if !crate::matching::methods::pair::sgm::PATHS.contains(&p.sgm.paths) {
        return Err(PairError::Paths(p.sgm.paths));
    }
    Ok(())
}

/// The sweep's sink that writes each cell's scores, as 16-bit codes, into a band's part of
/// the volume.
struct Codes<'a> {
    chunk: &'a mut [i16],
    cols: usize,
    np: usize,
}

impl CellSink for Codes<'_> {
    #[inline(always)]
    fn cell(&mut self, j: usize, i: usize, s: &[f32]) {
        let o = (j * self.cols + i) * self.np;
        for (d, &v) in self.chunk[o..o + self.np].iter_mut().zip(s) {
            *d = quantise(v);
        }
    }
}

built_per_cpu! {
    /// One row of SGM's picks: each cell's pick on the aggregated costs `sum` (cell i's
    /// planes from `i·stride`; the chosen score −S; unseen planes NaN, unscored cells −∞ throughout), its raw correlations from `raw`,
    /// and, with `lr`, the right photo's best plane for each right column x (u32::MAX where
    /// none), the best over the cells that meet x on the chosen scores. Built per CPU (see
    /// `simd`).
    #[allow(clippy::too_many_arguments)]
    fn pick_row[](
        raw: &[f32],
        sum: &[u16],
        place_sum: Option<&[u16]>,
        stride: usize,
        np: usize,
        col0: usize,
        first: i64,
        wr: usize,
        lr: bool,
        uniqueness: f32,
    ) -> (RowPicks, Vec<u32>) = pick_row_body;
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn pick_row_body(
    raw: &[f32],
    sum: &[u16],
    place_sum: Option<&[u16]>,
    stride: usize,
    np: usize,
    col0: usize,
    first: i64,
    wr: usize,
    lr: bool,
    uniqueness: f32,
) -> (RowPicks, Vec<u32>) {
    let cols = raw.len() / np.max(1);
    let mut cell = vec![0.0f32; np];
    let mut picks = RowPicks::default();
    let mut rb = RightBest::new(wr, np);
    for i in 0..cols {
        let (rc, s) = (
            &raw[i * np..(i + 1) * np],
            &sum[i * stride..i * stride + np],
        );
        if rc.iter().fold(true, |t, &q| t & (q == f32::NEG_INFINITY)) {
            cell.fill(f32::NEG_INFINITY);
        } else {
            for p in 0..np {
                let v = -(s[p] as f32);
                cell[p] = if rc[p].is_nan() { f32::NAN } else { v };
            }
        }
        let win = winner(&cell, Unseen::Skip);
        let mut pick = Pick::new(win, np, |p| rc[p]);
        // The sub-plane peak of the aggregated costs, as Hirschmüller (2008, §2.4) takes it:
        // smoother than the raw correlations' (on the benchmark pair, RMSE 0.17 against
        // 0.24 px for the pixels within 2 px), which give the σ only.
        pick.offset = win.and_then(|w| {
            aggregated_place(
                s,
                place_sum.map(|h| &h[i * stride..i * stride + np]),
                w.plane,
            )
        });
        // The chosen scores are −S: the cost is S, from one cost unit.
        pick.unique = win.is_none_or(|w| unique(&cell, w.plane, uniqueness, 1.0, |v| -v));
        picks.push(&pick);
        if !lr {
            continue;
        }
        // Right column x = col0 + i − first − p, inside the right photo for p_lo..=p_hi.
        let x0 = (col0 + i) as i64 - first;
        let p_lo = (x0 - (wr as i64 - 1)).max(0);
        let p_hi = x0.min(np as i64 - 1);
        if p_lo > p_hi {
            continue;
        }
        rb.offer(x0, &cell, p_lo as usize, p_hi as usize + 1);
    }
    let mut out = vec![u32::MAX; if lr { wr } else { 0 }];
    rb.write(&mut out);
    (picks, out)
}

/// The sub-plane place of the winner `at` on the aggregated costs `sum` (its cell's planes):
/// on the paths along the row, `along`, where they peak there (see `Streamed::row`), else on
/// the sum, as Hirschmüller (2008, §2.4) takes it; None at an end of the range or where
/// neither peaks.
#[inline(always)]
fn aggregated_place(sum: &[u16], along: Option<&[u16]>, at: usize) -> Option<f32> {
    if at == 0 || at + 1 >= sum.len() {
        return None;
    }
    let peak = |c: &[u16]| {
        let (off, den) = parabola(-(c[at - 1] as f64), -(c[at] as f64), -(c[at + 1] as f64));
        (den < 0.0).then_some(off as f32)
    };
    along.and_then(peak).or_else(|| peak(sum))
}

built_per_cpu! {
    /// The disparities alone of one row's cells (into `d`, from the row's first cell; NaN
    /// where none) from the scores `raw` and the aggregated costs `sum` (cell i's planes from
    /// `i·stride`), with no threshold, uniqueness or left-right check: what [`pick_row`] and
    /// [`finish_row`] give then, in a fraction of the time (the σ's self-match runs four
    /// times over the photo). Built per CPU (see `simd`).
    fn self_row[](raw: &[f32], sum: &[u16], along: &[u16], stride: usize, np: usize, first: i64, d: &mut [f32]) = self_row_body;
}

#[inline(always)]
fn self_row_body(
    raw: &[f32],
    sum: &[u16],
    along: &[u16],
    stride: usize,
    np: usize,
    first: i64,
    d: &mut [f32],
) {
    let cols = (raw.len() / np.max(1)).min(d.len());
    for (i, out) in d[..cols].iter_mut().enumerate() {
        let (rc, s) = (
            &raw[i * np..(i + 1) * np],
            &sum[i * stride..i * stride + np],
        );
        *out = f32::NAN;
        if rc.iter().fold(true, |t, &q| t & (q == f32::NEG_INFINITY)) {
            continue;
        }
        // The first of the lowest costs among the seen planes (winner's rule on −S).
        let mut at = usize::MAX;
        let mut best = u32::MAX;
        for p in 0..np {
            if !rc[p].is_nan() && (s[p] as u32) < best {
                best = s[p] as u32;
                at = p;
            }
        }
        // None; a neighbour unseen; at an end of the range.
        if at == usize::MAX
            || (at > 0 && rc[at - 1].is_nan())
            || (at + 1 < np && rc[at + 1].is_nan())
            || (np > 1 && (at == 0 || at == np - 1))
        {
            continue;
        }
        if at == 0 || at + 1 == np {
            // A single plane: no neighbours, no sub-plane place.
            *out = (first as f64 + at as f64) as f32;
            continue;
        }
        // As pick_row and finish_row: the aggregated costs' place, else the raw
        // correlations' (finite neighbours only, as a pick keeps them), else 0.
        let own = aggregated_place(s, Some(&along[i * stride..i * stride + np]), at);
        let finite = |v: f32| if v.is_finite() { v } else { f32::NAN };
        let (off, _) = place(
            finite(rc[at - 1]),
            rc[at] as f64,
            finite(rc[at + 1]),
            own.unwrap_or(f32::NAN),
        );
        *out = (first as f64 + at as f64 + off) as f32;
    }
}

/// One pixel row of the three outputs (disparity, correlation, σ), NaN where no match.
struct OutRow<'a> {
    d: &'a mut [f32],
    corr: &'a mut [f32],
    sigma: &'a mut [f32],
}

/// What every row's matching needs.
struct Ctx<'a> {
    left: &'a ImageF32,
    right: &'a ImageF32,
    p: &'a PairParams,
    planes: Planes<'a>,
    k: usize,
    np: usize,
    /// Correlations and σ wanted, not only disparities.
    full: bool,
}

/// The rows of the three outputs, each made NaN by the thread that takes it.
fn out_rows<'a>(
    d: &'a mut [f32],
    corr: &'a mut [f32],
    sigma: &'a mut [f32],
    w: usize,
) -> impl IndexedParallelIterator<Item = OutRow<'a>> {
    d.par_chunks_mut(w)
        .zip(corr.par_chunks_mut(w))
        .zip(sigma.par_chunks_mut(w))
        .map(|((d, corr), sigma)| {
            for v in [&mut *d, &mut *corr, &mut *sigma] {
                v.fill(f32::NAN);
            }
            OutRow { d, corr, sigma }
        })
}

/// What became of a cell (see [`row_matches`]).
mod fate {
    pub const MATCH: u8 = 0;
    pub const UNSEEN: u8 = 1;
    pub const UNSCORED: u8 = 2;
    pub const RANGE_END: u8 = 3;
    pub const AMBIGUOUS: u8 = 4;
    pub const BELOW_THRESHOLD: u8 = 5;
    pub const LEFT_RIGHT: u8 = 6;
}

/// The rules a row's matches follow, and where they go.
#[derive(Clone, Copy)]
struct Rules {
    np: usize,
    /// Reference column of the first cell.
    col0: usize,
    first: i64,
    threshold: f64,
    /// The left-right tolerance, planes (None: no check).
    lr: Option<f64>,
    /// Pixels in a window (for σ).
    n: usize,
    /// Whether the correlation and σ are wanted (the σ's self-match wants disparities only).
    full: bool,
}

built_per_cpu! {
    /// Each cell's fate, and where it is a match its disparity, correlation and σ, into the
    /// row's outputs from column `rules.col0` (NaN elsewhere). Built per CPU (see `simd`).
    fn finish_row[](pk: &RowPicks, rb: &[u32], rules: &Rules, fates: &mut [u8], out: &mut OutRow) = finish_row_body;
}

/// In order: no plane (some plane unseen, or nothing to match); the best at an end of the
/// range (as a rule the flank of a match beyond it); not unique; below the correlation
/// threshold; the right photo's winner elsewhere (`rb[x]`, u32::MAX where none). A match's
/// place below the plane step is the chosen scores' own (aggregated costs) or the parabola of
/// the raw correlations, and its σ from their curvature, in planes (a step of 1). Without a
/// branch, so that the cells are taken on vector lanes.
#[inline(always)]
fn finish_row_body(pk: &RowPicks, rb: &[u32], rules: &Rules, fates: &mut [u8], out: &mut OutRow) {
    use fate::*;
    let n = pk.len();
    let Rules {
        np,
        col0,
        first,
        threshold,
        lr,
        n: nw,
        full,
    } = *rules;
    let (pl_, rho_, lo_, hi_, off_, un_) = (
        &pk.plane[..n],
        &pk.rho[..n],
        &pk.below[..n],
        &pk.above[..n],
        &pk.offset[..n],
        &pk.unique[..n],
    );
    let fates = &mut fates[..n];
    let (d, corr, sigma) = (
        &mut out.d[col0..col0 + n],
        &mut out.corr[col0..col0 + n],
        &mut out.sigma[col0..col0 + n],
    );
    for i in 0..n {
        let (pl, rho) = (pl_[i], rho_[i]);
        let none = pl == RowPicks::NONE;
        let end = np > 1 && (pl == 0 || pl as usize == np - 1);
        let low = (rho as f64) < threshold;
        let f = if none {
            if rho.is_nan() {
                UNSEEN
            } else {
                UNSCORED
            }
        } else if end {
            RANGE_END
        } else if !un_[i] {
            AMBIGUOUS
        } else if low {
            BELOW_THRESHOLD
        } else {
            MATCH
        };
        fates[i] = f;
        let rho = rho as f64;
        let (off, den) = place(lo_[i], rho, hi_[i], off_[i]);
        let t = first as f64 + pl as f64 + off;
        let sd = if full {
            let (top, curvature) = peak_top(lo_[i], rho, hi_[i], den);
            height_sigma_or_nan(top, curvature, 1.0, nw)
        } else {
            f64::NAN
        };
        let ok = f == MATCH;
        d[i] = if ok { t as f32 } else { f32::NAN };
        corr[i] = if ok { rho as f32 } else { f32::NAN };
        sigma[i] = if ok { sd as f32 } else { f32::NAN };
    }
    // The left-right check, last: a match whose right column's winner is elsewhere.
    let Some(tol) = lr else {
        return;
    };
    for i in 0..n {
        if fates[i] != MATCH {
            continue;
        }
        let pl = pl_[i];
        let xr = (col0 + i) as i64 - first - pl as i64;
        let ok = usize::try_from(xr)
            .ok()
            .and_then(|x| rb.get(x))
            .is_some_and(|&w| w != u32::MAX && (w as f64 - pl as f64).abs() <= tol);
        if !ok {
            fates[i] = LEFT_RIGHT;
            d[i] = f32::NAN;
            corr[i] = f32::NAN;
            sigma[i] = f32::NAN;
        }
    }
}

/// A match's place below the plane step: the chosen scores' own `own` (aggregated costs), or
/// the parabola through the raw correlations `lo`, `rho`, `hi`, or 0 where they are no peak;
/// and the parabola's second difference (for σ).
#[inline(always)]
fn place(lo: f32, rho: f64, hi: f32, own: f32) -> (f64, f64) {
    let (peak, den) = parabola(lo as f64, rho, hi as f64);
    let own = own as f64;
    let off = if !own.is_nan() {
        own
    } else if !peak.is_nan() {
        peak
    } else {
        0.0
    };
    (off, den)
}

/// The Gaussian through three correlations a pixel apart (a parabola through their
/// logarithms: the three-point Gaussian estimator, Willert & Gharib 1991, "Digital particle
/// image velocimetry", Exp. Fluids 10, eq. 7): its top and the logarithms' second difference
/// (negative); `None` unless the three are positive and peak.
fn gaussian(lo: f32, rho: f64, hi: f32) -> Option<(f64, f64)> {
    let (lo, hi) = (lo as f64, hi as f64);
    if !(lo > 0.0 && hi > 0.0 && rho > 0.0) {
        return None;
    }
    let (l0, l1, l2) = (lo.ln(), rho.ln(), hi.ln());
    let dl = l0 - 2.0 * l1 + l2;
    (dl < 0.0).then(|| ((l1 - (l2 - l0).powi(2) / (8.0 * dl)).exp().min(1.0), dl))
}

/// The top of the correlation peak through `lo`, `rho`, `hi` and its curvature there
/// (negative), for the noise's share of σ; `den` is the three's second difference.
/// - The top is the decorrelation the noise leaves: at the winning whole disparity ρ is lower
///   by the sub-pixel phase as well, which the estimator's own error ([`crate::matching::methods::pair::matcher::sigma`])
///   already holds.
/// - The second difference of three samples a pixel apart falls short of a narrow peak's
///   curvature (for a Gaussian peak of width 1 px, by a fifth).
///
/// Both from the Gaussian through the three where it exists (its top, and top × the
/// logarithms' second difference, the larger curvature of the two taken); else the
/// parabola's vertex and `den` (ρ where the three are no peak).
fn peak_top(lo: f32, rho: f64, hi: f32, den: f64) -> (f64, f64) {
    if let Some((top, dl)) = gaussian(lo, rho, hi) {
        return (top, (top * dl).min(den));
    }
    let (off, _) = parabola(lo as f64, rho, hi as f64);
    let top = if off.is_finite() {
        (rho - 0.5 * den * off * off).min(1.0)
    } else {
        rho
    };
    (top, den)
}

/// The matches of pixel row `r` from its cells' picks and the right photo's winners
/// (`rb[x]`, u32::MAX where none), written into `out` (NaN where none, the row's first and
/// last k pixels included); what happened to the rest. With least squares, each match is
/// refined from the place [`finish_row`] gave it.
fn row_matches(x: &Ctx, r: usize, picks: &RowPicks, rb: &[u32], mut out: OutRow) -> PairStats {
    let (p, k) = (x.p, x.k);
    let rules = Rules {
        np: x.np,
        col0: k,
        first: p.d_min,
        threshold: p.threshold,
        lr: p.lr_tolerance,
        n: p.window * p.window,
        full: x.full,
    };
    let mut fates = vec![0u8; picks.len()];
    finish_row(picks, rb, &rules, &mut fates, &mut out);
    let mut st = PairStats::default();
    let mut count = [0usize; 7];
    for &f in &fates {
        count[f as usize] += 1;
    }
    st.unseen = count[fate::UNSEEN as usize];
    st.unscored = count[fate::UNSCORED as usize];
    st.at_range_end = count[fate::RANGE_END as usize];
    st.ambiguous = count[fate::AMBIGUOUS as usize];
    st.below_threshold = count[fate::BELOW_THRESHOLD as usize];
    st.left_right = count[fate::LEFT_RIGHT as usize];
    if p.subpixel == Subpixel::Lsm {
        for (i, _) in fates.iter().enumerate().filter(|(_, &f)| f == fate::MATCH) {
            let c = k + i;
            let (xc, yc) = (c as f64 + 0.5, r as f64 + 0.5);
            let locate = |u: f64, v: f64, t: f64| x.planes.locate(xc + u, yc + v, t);
            let pl = picks.plane[i] as f64;
            let t0 = pl
                + place(
                    picks.below[i],
                    picks.rho[i] as f64,
                    picks.above[i],
                    picks.offset[i],
                )
                .0;
            match refine(x.left, Window { c, r, k }, x.right, &locate, t0, 1.0) {
                Ok(f) => {
                    out.d[c] = (p.d_min as f64 + f.t) as f32;
                    // The residuals of neighbouring pixels are not independent (the photos'
                    // blur, the bilinear resampling): σ_t² for n_eff observations, not n.
                    out.sigma[c] = (f.sigma_t * f.dependence.sqrt()) as f32;
                    st.lsm_refined += 1;
                }
                // No disparity where least squares does not converge (as in the sweep): the
                // parabola's place left there would carry least squares' estimator σ.
                Err(e) => {
                    out.d[c] = f32::NAN;
                    out.sigma[c] = f32::NAN;
                    *st.lsm_failures.entry(failure_name(e)).or_default() += 1
                }
            }
        }
    }
    st
}

impl PairStats {
    /// Adds another part's counts.
    fn add(mut self, o: PairStats) -> PairStats {
        self.unseen += o.unseen;
        self.unscored += o.unscored;
        self.at_range_end += o.at_range_end;
        self.ambiguous += o.ambiguous;
        self.below_threshold += o.below_threshold;
        self.left_right += o.left_right;
        self.lsm_refined += o.lsm_refined;
        for (k, v) in o.lsm_failures {
            *self.lsm_failures.entry(k).or_default() += v;
        }
        self
    }
}

/// Matches a rectified pair, with the σ of the noise alone ([`crate::matching::methods::pair::matcher::match_pair`] adds the
/// estimator's own error).
pub fn match_pair_alone(
    left: &ImageF32,
    right: &ImageF32,
    p: &PairParams,
    max_memory_mb: u64,
    progress: &dyn crate::matching::progress::Progress,
) -> Result<DisparityMap, PairError> {
    match_with(left, right, p, max_memory_mb, progress, true, None)
}

/// The disparities alone (the correlation and σ NaN): what the σ's self-match needs. With
/// `rows = Some((j, step))` and SGM's 5 streamed paths, only every `step`-th row from the j-th
/// with a full window is matched, the paths from the row before stepping `step` rows (the
/// sub-plane place comes from the paths along the row, which see the row alone); the rest
/// NaN.
pub(super) fn disparities_alone(
    left: &ImageF32,
    right: &ImageF32,
    p: &PairParams,
    max_memory_mb: u64,
    rows: Option<(usize, usize)>,
) -> Result<DisparityMap, PairError> {
    match_with(
        left,
        right,
        p,
        max_memory_mb,
        &crate::matching::progress::Silent,
        false,
        rows.filter(|_| streams(p)),
    )
}

fn match_with(
    left: &ImageF32,
    right: &ImageF32,
    p: &PairParams,
    max_memory_mb: u64,
    progress: &dyn crate::matching::progress::Progress,
    full: bool,
    subset: Option<(usize, usize)>,
) -> Result<DisparityMap, PairError> {
    check(left, right, p)?;
    within_memory(
        bytes_needed(left.width, left.height, right.width, p),
        max_memory_mb,
        p,
    )?;
    let t0 = std::time::Instant::now();
    let (w, h) = (left.width, left.height);
    let k = p.window / 2;
    let np = (p.d_max - p.d_min + 1) as usize;
    let first = p.d_min;
    let (lp, rp) = rayon::join(|| Prepared::new(left), || Prepared::new(right));
    let cols = w - 2 * k;
    let rows: Vec<usize> = match subset {
        Some((j, step)) => (k + j % step.max(1)..h - k).step_by(step.max(1)).collect(),
        None => (k..h - k).collect(),
    };
    let band = band_rows(rows.len());
    let bands: Vec<&[usize]> = rows.chunks(band).collect();
    let x = Ctx {
        left,
        right,
        p,
        planes: Planes::Shifts { first, count: np },
        k,
        np,
        full,
    };
    let wr = right.width;
    let cells_of = |b: &[usize]| Cells {
        col0: k,
        stride: 1,
        cols,
        rows: b.to_vec(),
    };
    let row_len = cols * np;
    let mut seconds_aggregate = 0.0;
    // The outputs, zeroed lazily by the system and made NaN by the rows' own threads; rows
    // k…h − k are the matched ones (the first k and last k have no full window).
    let (mut d, mut corr, mut sigma) = (
        vec![0.0f32; w * h],
        vec![0.0f32; w * h],
        vec![0.0f32; w * h],
    );
    let (dm, cm, sm) = (
        &mut d[k * w..(h - k) * w],
        &mut corr[k * w..(h - k) * w],
        &mut sigma[k * w..(h - k) * w],
    );
    let counts: PairStats = match p.filter {
        Filter::Sgm if streams(p) => {
            progress.begin("match (rows)", rows.len() as u64);
            let st = match_streamed(&x, &lp, &rp, &rows, (dm, cm, sm), progress);
            progress.end();
            st
        }
        Filter::Sgm => {
            // The whole volume, in 16-bit codes, each band written in place.
            progress.begin("score (rows)", rows.len() as u64);
            let mut vol: Vec<i16> =
                crate::matching::plane_sweep::volume::zeroed(row_len * rows.len());
            vol.par_chunks_mut(band * row_len)
                .zip(bands.par_iter())
                .for_each(|(chunk, b)| {
                    // The right photo's winners come from the aggregated costs, not here.
                    let mut codes = Codes { chunk, cols, np };
                    sweep_shifts(&lp, &rp, first, np, k, &cells_of(b), &mut [], &mut codes);
                    progress.advance(b.len() as u64);
                });
            progress.end();
            let ta = std::time::Instant::now();
            let (fwd, bwd) = aggregate_halves(&vol, cols, rows.len(), np, &p.sgm);
            seconds_aggregate = ta.elapsed().as_secs_f64();
            progress.begin("winners (rows)", rows.len() as u64);
            let st = out_rows(dm, cm, sm, w)
                .zip(rows.par_iter())
                .enumerate()
                .map_init(
                    || (vec![0.0f32; row_len], vec![0u16; row_len]),
                    |(raw, sum), (j, (out, &r))| {
                        let row = j * row_len..(j + 1) * row_len;
                        for (v, &q) in raw.iter_mut().zip(&vol[row.clone()]) {
                            *v = dequantise(q);
                        }
                        for ((v, &a), &b) in sum.iter_mut().zip(&fwd[row.clone()]).zip(&bwd[row]) {
                            *v = a.saturating_add(b);
                        }
                        let (picks, rb) = pick_row(
                            raw,
                            sum,
                            None,
                            np,
                            np,
                            k,
                            first,
                            wr,
                            p.lr_tolerance.is_some(),
                            p.uniqueness as f32,
                        );
                        let m = row_matches(&x, r, &picks, &rb, out);
                        progress.advance(1);
                        m
                    },
                )
                .reduce(PairStats::default, PairStats::add);
            progress.end();
            st
        }
        _ => {
            // Each band's winners taken as its scores come: no volume is kept. The right
            // photo's winners only for the left-right check; the correlations' cost 1 − NCC
            // counted from 1 − RHO_MAX.
            let bm = BlockParams {
                first,
                planes: np,
                k,
                uniqueness: p.uniqueness as f32,
                floor: (1.0 - RHO_MAX) as f32,
                right_winners: p.lr_tolerance.is_some(),
            };
            progress.begin("match (rows)", rows.len() as u64);
            // The output rows in the same bands as the rows.
            let st = bands
                .par_iter()
                .zip(out_rows(dm, cm, sm, w).chunks(band))
                .map(|(b, outs)| {
                    // Each row's matches as its winners come.
                    let mut outs = outs.into_iter();
                    let mut st = PairStats::default();
                    block_match(
                        &lp,
                        &rp,
                        &bm,
                        b,
                        &mut |jb: usize, pk: &RowPicks, rb: &[u32]| {
                            if let Some(out) = outs.next() {
                                st = std::mem::take(&mut st)
                                    .add(row_matches(&x, b[jb], pk, rb, out));
                            }
                        },
                    );
                    progress.advance(b.len() as u64);
                    st
                })
                .reduce(PairStats::default, PairStats::add);
            progress.end();
            st
        }
    };
    // The rows without a full window.
    for v in [&mut d, &mut corr, &mut sigma] {
        v[..k * w].fill(f32::NAN);
        v[(h - k) * w..].fill(f32::NAN);
    }
    let stats = PairStats {
        width: w,
        height: h,
        disparities: np,
        candidates: (cols * rows.len() * np) as u64,
        pixels: cols * rows.len(),
        ..Default::default()
    };
    let mut stats = stats.add(counts);
    if p.filter == Filter::Regions {
        let mut hm = HeightMap {
            cols: w,
            rows: h,
            col0: 0,
            row0: 0,
            stride: 1,
            h: d,
            corr: corr.clone(),
            sigma: sigma.clone(),
            candidates: 0,
        };
        let before = hm.matched();
        remove_wrong_heights(&mut hm, &p.regions);
        stats.regions = before - hm.matched();
        d = hm.h;
        for ((dv, c), s) in d.iter().zip(corr.iter_mut()).zip(sigma.iter_mut()) {
            if dv.is_nan() {
                *c = f32::NAN;
                *s = f32::NAN;
            }
        }
    }
    stats.matched = d.iter().filter(|v| v.is_finite()).count();
    stats.seconds_aggregate = seconds_aggregate;
    stats.seconds_total = t0.elapsed().as_secs_f64();
    Ok(DisparityMap {
        width: w,
        height: h,
        d,
        corr,
        sigma,
        stats,
    })
}

/// The rows of SGM's five streamed paths (see [`crate::matching::methods::pair::sgm`]): the
/// upper half of `rows` (ascending; consecutive, or every other row) from the top down on
/// one thread, the lower half from the bottom up on the other, each row's scores aggregated,
/// picked and matched as soon as the sweep gives them, into `out` (the three outputs' rows
/// from pixel row k on). Nothing the size of the photo is kept but the outputs.
fn match_streamed(
    x: &Ctx,
    lp: &Prepared,
    rp: &Prepared,
    rows: &[usize],
    out: (&mut [f32], &mut [f32], &mut [f32]),
    progress: &dyn crate::matching::progress::Progress,
) -> PairStats {
    let (w, k) = (x.left.width, x.k);
    let mid = rows.len() / 2;
    let (upper, lower) = rows.split_at(mid);
    // The outputs from pixel row k; the lower half's from its first row.
    let split = lower.first().map_or(0, |&r| r - k);
    let (d, corr, sigma) = out;
    let (d0, d1) = d.split_at_mut(split * w);
    let (c0, c1) = corr.split_at_mut(split * w);
    let (s0, s1) = sigma.split_at_mut(split * w);
    let down: Vec<usize> = upper.to_vec();
    let up: Vec<usize> = lower.iter().rev().copied().collect();
    let (a, b) = rayon::join(
        || stream_half(x, lp, rp, &down, k, (d0, c0, s0), progress),
        || stream_half(x, lp, rp, &up, k + split, (d1, c1, s1), progress),
    );
    a.add(b)
}

/// One half of [`match_streamed`]: `travel` the rows in the order of travel, `out` the
/// outputs' rows from pixel row `row0` down (every row of the half, matched or not).
fn stream_half(
    x: &Ctx,
    lp: &Prepared,
    rp: &Prepared,
    travel: &[usize],
    row0: usize,
    out: (&mut [f32], &mut [f32], &mut [f32]),
    progress: &dyn crate::matching::progress::Progress,
) -> PairStats {
    // Rows left out (a self-match over every other row) have no match.
    for v in [&mut *out.0, &mut *out.1, &mut *out.2] {
        v.fill(f32::NAN);
    }
    if travel.is_empty() {
        return PairStats::default();
    }
    let (k, np) = (x.k, x.np);
    let cols = x.left.width - 2 * k;
    let mut sink = StreamRows {
        x,
        agg: Streamed::new(cols, np, &x.p.sgm),
        raw: vec![0.0; cols * np],
        cols,
        np,
        rows: Vec::new(),
        row0,
        quick: !x.full
            && x.p.subpixel == Subpixel::Parabola
            && x.p.lr_tolerance.is_none()
            && x.p.uniqueness <= 0.0
            && x.p.threshold <= -1.0,
        out,
        stats: PairStats::default(),
        progress,
    };
    // In bands, each summed afresh (the running sums' f32 rounding stays that of a band).
    for band in travel.chunks(BAND) {
        sink.rows = band.to_vec();
        let cells = Cells {
            col0: k,
            stride: 1,
            cols,
            rows: band.to_vec(),
        };
        sweep_shifts(lp, rp, x.p.d_min, np, k, &cells, &mut [], &mut sink);
    }
    sink.stats
}

/// The sweep's sink for [`stream_half`]: a row's scores as they come, and the row
/// aggregated, picked and matched when its last cell is in.
struct StreamRows<'a, 'o> {
    x: &'a Ctx<'a>,
    agg: Streamed,
    raw: Vec<f32>,
    cols: usize,
    np: usize,
    /// The pixel rows of the band swept.
    rows: Vec<usize>,
    /// The pixel row of the outputs' first row.
    row0: usize,
    /// Disparities alone with no check that would take one away (the σ's self-match):
    /// [`self_row`] gives them, not [`pick_row`] and [`row_matches`].
    quick: bool,
    out: (&'o mut [f32], &'o mut [f32], &'o mut [f32]),
    stats: PairStats,
    progress: &'a dyn crate::matching::progress::Progress,
}

impl StreamRows<'_, '_> {
    fn finish(&mut self, r: usize) {
        let p = self.x.p;
        let stride = self.agg.stride();
        let (sum, along) = self.agg.row(&self.raw);
        let w = self.x.left.width;
        let o = (r - self.row0) * w..(r - self.row0 + 1) * w;
        if self.quick {
            // The σ's self-match: the disparities alone, as the general way gives them.
            let d = &mut self.out.0[o][self.x.k..];
            self_row(&self.raw, sum, along, stride, self.np, p.d_min, d);
            self.progress.advance(1);
            return;
        }
        let (picks, rb) = pick_row(
            &self.raw,
            sum,
            Some(along),
            stride,
            self.np,
            self.x.k,
            p.d_min,
            self.x.right.width,
            p.lr_tolerance.is_some(),
            p.uniqueness as f32,
        );
        let out = OutRow {
            d: &mut self.out.0[o.clone()],
            corr: &mut self.out.1[o.clone()],
            sigma: &mut self.out.2[o],
        };
        let st = row_matches(self.x, r, &picks, &rb, out);
        self.stats = std::mem::take(&mut self.stats).add(st);
        self.progress.advance(1);
    }
}

impl CellSink for StreamRows<'_, '_> {
    #[inline(always)]
    fn cell(&mut self, j: usize, i: usize, s: &[f32]) {
        let np = self.np;
        self.raw[i * np..(i + 1) * np].copy_from_slice(s);
        if i + 1 == self.cols {
            self.finish(self.rows[j]);
        }
    }
}

fn failure_name(e: RefineFailure) -> String {
    format!("{e:?}").to_lowercase()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three samples of a Gaussian peak c(t) = a·exp(−(t − t0)²/2s²): the curvature at its top
    /// is −a/s² exactly, where the second difference falls short; a peak with a correlation
    /// at or below 0 beside it keeps the second difference.
    #[test]
    fn a_gaussian_peak_s_curvature_at_its_top() {
        for (a, s, t0) in [(0.95, 1.0, 0.0), (0.9, 0.8, 0.3), (0.99, 1.6, -0.4)] {
            let c = |t: f64| a * (-(t - t0) * (t - t0) / (2.0 * s * s)).exp();
            let (lo, rho, hi) = (c(-1.0) as f32, c(0.0), c(1.0) as f32);
            let den = lo as f64 - 2.0 * rho + hi as f64;
            let (top, k) = peak_top(lo, rho, hi, den);
            assert!(
                (k + a / (s * s)).abs() < 1e-5 * a / (s * s),
                "{k} vs {}",
                -a / (s * s)
            );
            assert!(k < den, "the second difference {den} falls short of {k}");
            assert!((top - a).abs() < 1e-5, "top {top} for {a}");
        }
        assert_eq!(peak_top(-0.1, 0.9, 0.2, -1.6).1, -1.6);
    }

    /// A textured pair: the right photo the left shifted by `d` px (smooth lattice noise).
    fn textured_pair(w: usize, h: usize, d: f64) -> (ImageF32, ImageF32) {
        let f = |x: f64, y: f64| {
            100.0
                + 30.0 * (x * 0.31 + y * 0.17).sin()
                + 20.0 * (x * 0.13 - y * 0.41).cos()
                + 12.0 * (x * 0.71 + y * 0.53).sin() * (y * 0.23).cos()
        };
        let mut l = ImageF32::new(w, h);
        let mut r = ImageF32::new(w, h);
        for y in 0..h {
            for x in 0..w {
                l.data[y * w + x] = f(x as f64, y as f64) as f32;
                r.data[y * w + x] = f(x as f64 + d, y as f64) as f32;
            }
        }
        (l, r)
    }

    /// The σ's self-match takes the disparities the quick way ([`self_row`]): they are the
    /// general way's, to the bit, on every row it matches, with SGM's 5 streamed paths.
    #[test]
    fn the_quick_disparities_are_the_general_ones() {
        let (l, r) = textured_pair(60, 40, 1.3);
        let p = PairParams {
            d_min: -2,
            d_max: 2,
            threshold: -1.0,
            lr_tolerance: None,
            uniqueness: 0.0,
            ..PairParams::default()
        };
        let full = match_pair_alone(&l, &r, &p, 4096, &crate::matching::progress::Silent).unwrap();
        let quick = disparities_alone(&l, &r, &p, 4096, None).unwrap();
        // Every fourth row: the place on the paths along the row is the row's own, so those
        // rows' disparities are the same wherever the rows before were taken from.
        let quarter = disparities_alone(&l, &r, &p, 4096, Some((2, 4))).unwrap();
        let k = p.window / 2;
        let (mut same, mut n) = (0, 0);
        for y in (k + 2..40 - k).step_by(4) {
            for x in 0..60 {
                let (a, b) = (quick.d[y * 60 + x], quarter.d[y * 60 + x]);
                if a.is_finite() {
                    n += 1;
                    same += usize::from((a - b).abs() < 1e-3);
                }
            }
        }
        assert!(n > 300 && same * 100 >= n * 95, "{same} of {n} the same");
        assert!(full.stats.matched > 1000, "{:?}", full.stats);
        for (a, b) in full.d.iter().zip(&quick.d) {
            assert!(
                a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                "{a} vs {b}"
            );
        }
        // Every other row: those rows matched, the rest NaN.
        let half = disparities_alone(&l, &r, &p, 4096, Some((1, 2))).unwrap();
        let k = p.window / 2;
        for y in k..40 - k {
            let row = &half.d[y * 60..(y + 1) * 60];
            let matched = row.iter().filter(|v| v.is_finite()).count();
            if (y - k) % 2 == 1 {
                assert!(matched > 40, "row {y}: {matched}");
            } else {
                assert_eq!(matched, 0, "row {y}");
            }
        }
    }

    /// Matching down the photo and up it (the streamed halves) finds the shift of a
    /// fronto-parallel pair everywhere, with 5 paths and with 8.
    #[test]
    fn both_halves_find_the_shift() {
        let (l, r) = textured_pair(80, 61, 3.25);
        for paths in [5u8, 8] {
            let mut p = PairParams {
                d_min: 0,
                d_max: 8,
                ..PairParams::default()
            };
            p.sgm.paths = paths;
            let m = match_pair_alone(&l, &r, &p, 4096, &crate::matching::progress::Silent).unwrap();
            let k = p.window / 2;
            let mut n = 0;
            // Each half's mean: the parabola's pixel locking moves both alike.
            let mut halves = [(0.0f64, 0usize); 2];
            for y in k..61 - k {
                for x in 12..80 - k {
                    let v = m.d[y * 80 + x];
                    if v.is_finite() {
                        assert!((v - 3.25).abs() < 0.5, "{paths} paths, ({x}, {y}): {v}");
                        n += 1;
                        let hf = &mut halves[usize::from(y >= 30)];
                        hf.0 += v as f64;
                        hf.1 += 1;
                    }
                }
            }
            assert!(n > 50 * 50, "{paths} paths: {n} matched");
            let mean = |h: (f64, usize)| h.0 / h.1 as f64;
            assert!(
                (mean(halves[0]) - mean(halves[1])).abs() < 0.05,
                "{paths} paths: {halves:?}"
            );
        }
    }

    /// Bands never above BAND rows, every row in one, and an even number of them wherever
    /// there are rows enough (so that neither of two threads has an extra band to do).
    #[test]
    fn bands_share_the_rows_evenly() {
        for rows in 0..4000 {
            let b = band_rows(rows);
            assert!((1..=BAND).contains(&b), "{rows} rows: {b}");
            let n = rows.div_ceil(b);
            assert!(n * b >= rows);
            if rows >= 2 * BAND {
                assert_eq!(n % 2, 0, "{rows} rows: {n} bands of {b}");
            }
        }
        // 596 rows (the benchmark pair's): 10 bands of 60, not 9 of 64 and 20.
        assert_eq!(band_rows(596), 60);
    }

    /// The errors say what to do: a smaller window where one fits, the filters without a
    /// cost volume only where the volume is kept.
    #[test]
    fn errors_suggest_what_would_help() {
        let small = ImageF32::new(8, 8);
        let mut p = PairParams {
            d_min: 0,
            d_max: 3,
            window: 9,
            ..PairParams::default()
        };
        let e = match_pair_alone(&small, &small, &p, 4096, &crate::matching::progress::Silent)
            .unwrap_err();
        assert!(e.to_string().contains("smaller --window"), "{e}");
        let tiny = ImageF32::new(2, 8);
        p.window = 3;
        let e = match_pair_alone(&tiny, &tiny, &p, 4096, &crate::matching::progress::Silent)
            .unwrap_err();
        assert!(e.to_string().contains("at least 3 × 3"), "{e}");
        let big = ImageF32::new(2000, 2000);
        p.d_max = 255;
        for (filter, paths, hint) in [
            (Filter::Sgm, 8, true),
            (Filter::Sgm, 5, false),
            (Filter::None, 5, false),
            (Filter::Regions, 5, false),
        ] {
            p.filter = filter;
            p.sgm.paths = paths;
            let e = match_pair_alone(&big, &big, &p, 16, &crate::matching::progress::Silent)
                .unwrap_err();
            let e = e.to_string();
            assert!(e.contains("--max-memory"), "{e}");
            assert_eq!(e.contains("--filter none"), hint, "{filter:?}: {e}");
        }
    }
}
