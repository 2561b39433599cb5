//! The plane sweep that both matchers share: the height sweep of seed 000 (§2.2), where the
//! planes are heights mapped into the search photo by the image→image polynomials, and
//! rectified pairs, where the planes are whole-pixel disparities (d = x_left − x_right, as in
//! Middlebury and OpenCV). For each plane the search photo is read once into the reference
//! photo's geometry (resampled bilinearly for heights, an index shift for disparities), and
//! every window's normalised cross-correlation comes from running sums of the five NCC sums
//! (Σl, Σl², Σw, Σw², Σl·w), so a candidate costs a few additions whatever the window size.
//!
//! A score is NaN when the window on that plane lies beyond the search photo or on its nodata
//! (the photo does not see it: see [`crate::matching::plane_sweep::winner::Unseen`] for what that does to the pixel), 0 when the
//! search window is flat (scored, uncorrelated), −∞ on every plane when the reference window
//! is flat or has nodata (nothing to match), else the NCC.

pub mod refine;
pub mod volume;
pub mod winner;

use crate::image::ImageF32;
use crate::matching::mapping::pmf::Mapping;

/// The planes swept.
#[derive(Debug, Clone, Copy)]
pub enum Planes<'a> {
    /// Rectified pair: reference pixel (c, r) on plane p meets search pixel (c − first − p, r).
    Shifts { first: i64, count: usize },
    /// Heights h0 + p·step, mapped by `map` (pixel coordinates with pixel c over [c, c + 1)).
    Heights {
        map: &'a Mapping,
        h0: f64,
        step: f64,
        count: usize,
    },
}

impl Planes<'_> {
    pub fn count(&self) -> usize {
        match *self {
            Planes::Shifts { count, .. } | Planes::Heights { count, .. } => count,
        }
    }

    /// Where the reference point (x, y) (continuous, pixel c over [c, c + 1)) lands in the
    /// search photo on plane `t` (continuous: a plane between two swept ones).
    pub fn locate(&self, x: f64, y: f64, t: f64) -> [f64; 2] {
        match *self {
            Planes::Shifts { first, .. } => [x - first as f64 - t, y],
            Planes::Heights { map, h0, step, .. } => map.eval([x, y, h0 + t * step]),
        }
    }
}

/// A photo ready for the sweep: grey values less their mean and divided by their standard
/// deviation (so that the running sums keep their precision in f32 whatever the photo's grey
/// scale, and "flat" means flat against the photo's own contrast), not-a-number pixels set to
/// 0 and flagged.
#[derive(Debug, Clone)]
pub struct Prepared {
    pub img: ImageF32,
    /// 1 where the photo had no value (NaN), else 0; empty where it has none.
    pub nodata: Vec<f32>,
}

impl Prepared {
    pub fn new(src: &ImageF32) -> Prepared {
        use rayon::prelude::*;
        const CHUNK: usize = 1 << 16;
        // Count, Σ(v − v0) and Σ(v − v0)² of the finite values in one pass, in f64 per chunk,
        // v0 the first finite value (so that a large mean against a small deviation does not
        // cancel).
        let v0 = src
            .data
            .iter()
            .copied()
            .find(|v| v.is_finite())
            .unwrap_or(0.0) as f64;
        let (n, s, ss) = src
            .data
            .par_chunks(CHUNK)
            .map(|c| {
                c.iter().filter(|v| v.is_finite()).fold(
                    (0usize, 0.0f64, 0.0f64),
                    |(n, s, ss), &v| {
                        let d = v as f64 - v0;
                        (n + 1, s + d, ss + d * d)
                    },
                )
            })
            .reduce(|| (0, 0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2));
        let (mean, sd) = if n > 0 {
            let m = s / n as f64;
            (v0 + m, (ss / n as f64 - m * m).max(0.0).sqrt())
        } else {
            (0.0, 0.0)
        };
        let scale = if sd > 0.0 && sd.is_finite() {
            1.0 / sd
        } else {
            1.0
        };
        let mut img = ImageF32 {
            width: src.width,
            height: src.height,
            data: Vec::with_capacity(src.data.len()),
        };
        img.data.par_extend(src.data.par_iter().map(|&v| {
            if v.is_finite() {
                ((v as f64 - mean) * scale) as f32
            } else {
                0.0
            }
        }));
        // Flags only where some pixel has no value: most photos have none.
        let nodata = if n < src.data.len() {
            src.data
                .par_iter()
                .map(|v| if v.is_finite() { 0.0 } else { 1.0 })
                .collect()
        } else {
            Vec::new()
        };
        Prepared { img, nodata }
    }
}

/// The reference pixels scored: columns `col0 + i·stride` (i < cols) of pixel rows `rows`.
#[derive(Debug, Clone)]
pub struct Cells {
    pub col0: usize,
    pub stride: usize,
    pub cols: usize,
    /// Pixel rows, each at least `k` from the photo's top and bottom: ascending, or (for the
    /// disparity sweep, [`sweep_shifts`]) descending.
    pub rows: Vec<usize>,
}

/// Scores of every plane for some cells: `v[(j·cols + i)·planes + p]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Scores {
    pub planes: usize,
    pub cols: usize,
    pub rows: usize,
    pub v: Vec<f32>,
    /// Disparities only: per row and right-photo column x, `[j·right width + x]`, the plane
    /// of the highest score among the cells that meet x (the right photo's own winner, for
    /// the left-right check), u32::MAX where none; empty for heights.
    pub right_best: Vec<u32>,
}

impl Scores {
    pub fn cell(&self, i: usize, j: usize) -> &[f32] {
        let o = (j * self.cols + i) * self.planes;
        &self.v[o..o + self.planes]
    }
}

/// Scores every plane for `cells` of `left` (windows of (2k + 1)², wholly inside `left`)
/// against `right`.
pub fn score(
    left: &Prepared,
    right: &Prepared,
    planes: &Planes,
    k: usize,
    cells: &Cells,
) -> Scores {
    let np = planes.count();
    let mut out = Scores {
        planes: np,
        cols: cells.cols,
        rows: cells.rows.len(),
        v: {
            let mut v =
                crate::matching::plane_sweep::volume::zeroed(cells.cols * cells.rows.len() * np);
            v.fill(f32::NEG_INFINITY);
            v
        },
        right_best: Vec::new(),
    };
    if np == 0 || cells.rows.is_empty() || cells.cols == 0 {
        return out;
    }
    match *planes {
        Planes::Shifts { first, .. } => {
            let wr = right.img.width;
            let mut rb = vec![u32::MAX; cells.rows.len() * wr];
            let (cols, v) = (cells.cols, &mut out.v);
            sweep_shifts(
                left,
                right,
                first,
                np,
                k,
                cells,
                &mut rb,
                &mut |j: usize, i: usize, s: &[f32]| {
                    let o = (j * cols + i) * np;
                    v[o..o + np].copy_from_slice(s);
                },
            );
            out.right_best = rb;
        }
        Planes::Heights { .. } => score_warped(left, right, planes, k, cells, &mut out),
    }
    out
}

/// Keeps Σ over the window's rows of per-row values (f32 vectors of `width·planes`), moving
/// the window down by adding the rows that enter and subtracting those that leave.
struct Running {
    top: usize,
    bottom: usize,
    empty: bool,
}

impl Running {
    /// The rows to subtract and to add to move the window to `top..=bottom` (of the same
    /// height), down the photo or up it; afresh where the two do not overlap.
    fn moves(
        &mut self,
        top: usize,
        bottom: usize,
    ) -> (std::ops::Range<usize>, std::ops::Range<usize>, bool) {
        let reset = self.empty || top > self.bottom || bottom < self.top;
        let r = if reset {
            (0..0, top..bottom + 1, true)
        } else if top >= self.top {
            (self.top..top, self.bottom + 1..bottom + 1, false)
        } else {
            (bottom + 1..self.bottom + 1, top..self.top, false)
        };
        self.top = top;
        self.bottom = bottom;
        self.empty = false;
        r
    }
}

/// Each window's mean and inverse deviation 1/√(Σ(v − v̄)²) along one row of a photo, for
/// the window centres x in `k..w − k`: `inv[x]` is NaN where the window has nodata or is
/// not wholly in the photo, 0 where it is flat, else positive; `mean[x]` is 0 where `inv[x]`
/// is NaN. From column sums; in separate arrays so that every step runs on vector lanes.
pub(super) struct RowStats {
    pub(super) mean: Vec<f32>,
    pub(super) inv: Vec<f32>,
    /// Column sums Σv, Σv², Σnodata over the window's rows, and the horizontal Σnodata.
    c0: Vec<f32>,
    c1: Vec<f32>,
    c2: Vec<f32>,
    s2: Vec<f32>,
}

impl RowStats {
    pub(super) fn new(w: usize) -> RowStats {
        let z = vec![0.0f32; w];
        RowStats {
            mean: z.clone(),
            inv: z.clone(),
            c0: z.clone(),
            c1: z.clone(),
            c2: z.clone(),
            s2: z,
        }
    }

    /// Whether the window at x has a reference to match: seen, and not flat.
    #[inline(always)]
    fn usable(&self, x: usize) -> Option<(f32, f32)> {
        let inv = self.inv[x];
        (inv > 0.0).then(|| (self.mean[x], inv))
    }

    #[inline(always)]
    pub(super) fn fill(&mut self, p: &Prepared, r: usize, k: usize) {
        self.fill_columns(p, r, k, 0, p.img.width);
    }

    /// [`RowStats::fill`] from the columns `x0 .. x1` alone (the windows centred within
    /// `x0 + k .. x1 − k`; the others are left as they were).
    #[inline(always)]
    pub(super) fn fill_columns(&mut self, p: &Prepared, r: usize, k: usize, x0: usize, x1: usize) {
        let w = p.img.width;
        let n = ((2 * k + 1) * (2 * k + 1)) as f32;
        let ww = x1 - x0;
        let (c0, c1, c2) = (
            &mut self.c0[x0..x1],
            &mut self.c1[x0..x1],
            &mut self.c2[x0..x1],
        );
        c0.fill(0.0);
        c1.fill(0.0);
        c2.fill(0.0);
        for rr in r - k..=r + k {
            let row = &p.img.data[rr * w + x0..rr * w + x1];
            for x in 0..ww {
                c0[x] += row[x];
                c1[x] += row[x] * row[x];
            }
            if let Some(nd) = p.nodata.get(rr * w + x0..rr * w + x1) {
                for x in 0..ww {
                    c2[x] += nd[x];
                }
            }
        }
        self.mean[x0..x1].fill(0.0);
        self.inv[x0..x1].fill(f32::NAN);
        if ww < 2 * k + 1 {
            return;
        }
        let m = ww - 2 * k;
        // Horizontal sums: Σv into mean, Σv² into inv, Σnodata into s2 (window centre k + x).
        let (s0, s1, s2) = (
            &mut self.mean[x0 + k..x0 + k + m],
            &mut self.inv[x0 + k..x0 + k + m],
            &mut self.s2[..m],
        );
        s1.fill(0.0);
        s2.fill(0.0);
        for d in 0..2 * k + 1 {
            let (a, b, c) = (&c0[d..d + m], &c1[d..d + m], &c2[d..d + m]);
            for x in 0..m {
                s0[x] += a[x];
                s1[x] += b[x];
                s2[x] += c[x];
            }
        }
        for x in 0..m {
            let (s, q, bad) = (s0[x], s1[x], s2[x]);
            let var = q - s * s / n;
            let flat = !(var > 1e-5 * q.max(1e-12) && var > 1e-9);
            let inv = if flat { 0.0 } else { 1.0 / var.sqrt() };
            s1[x] = if bad != 0.0 { f32::NAN } else { inv };
            s0[x] = if bad != 0.0 { 0.0 } else { s / n };
        }
    }
}

/// Cells between two re-summings of the running horizontal sums (f32 drift stays far below
/// the correlation's precision).
const RESUM: usize = 32;

/// Σ over the window's columns `c − k ..= c + k` of the per-column vectors `v` (`np` each),
/// into `acc`: summed afresh, or moved on from the previous cell one column to the left.
#[inline(always)]
fn window_columns(v: &[f32], np: usize, c: usize, k: usize, acc: &mut [f32], afresh: bool) {
    if afresh {
        acc.iter_mut().for_each(|a| *a = 0.0);
        for cc in c - k..=c + k {
            add_into(acc, &v[cc * np..(cc + 1) * np]);
        }
    } else {
        let (enter, leave) = (
            &v[(c + k) * np..(c + k + 1) * np],
            &v[(c - k - 1) * np..(c - k) * np],
        );
        for ((a, e), l) in acc.iter_mut().zip(enter).zip(leave) {
            *a += e - l;
        }
    }
}

/// Takes each cell's scores from the disparity sweep: `cell(j, i, scores)` for row j and
/// cell i of the [`Cells`], in row-major order. A sink whose `cell` is `#[inline(always)]` is
/// built into the sweep (on its vector lanes); a closure is called.
pub trait CellSink {
    fn cell(&mut self, j: usize, i: usize, scores: &[f32]);
}

impl<F: FnMut(usize, usize, &[f32])> CellSink for F {
    #[inline(always)]
    fn cell(&mut self, j: usize, i: usize, scores: &[f32]) {
        self(j, i, scores)
    }
}

/// The planes p_lo..=p_hi of reference column c that meet the right photo (`wr` wide) by
/// column x = c − first − p (0 ≤ x ≤ wr − 1), and the reversed index wr − 1 − x of plane
/// p_lo; None where none does.
#[inline(always)]
fn span_in_right(c: usize, first: i64, wr: usize, np: usize) -> Option<(usize, usize, usize)> {
    let x0 = c as i64 - first;
    let p_lo = (x0 - (wr as i64 - 1)).max(0);
    let p_hi = x0.min(np as i64 - 1);
    if p_lo > p_hi {
        return None;
    }
    // In i64 first: wr − 1 − x0 is negative where x0 lies beyond the right photo.
    let i0 = (wr as i64 - 1 - x0 + p_lo) as usize;
    Some((p_lo as usize, p_hi as usize, i0))
}

built_per_cpu! {
    /// Disparities: the search window of plane p is the right photo's window moved by a whole
    /// pixel, so Σw and 1/√var(w) are the right photo's own, per column; only Σl·w is summed per
    /// plane, and a score is two multiplications. Each cell's scores go to `sink.cell(j, i, scores)`
    /// as soon as they are known (so that a caller who wants only the winner keeps no volume);
    /// `right_best[j·wr + x]` gets the right photo's winner for column x of row j (u32::MAX where
    /// none); an empty `right_best` asks for none (a quarter of the work per cell). Built per CPU
    /// (see `simd`).
    #[allow(clippy::too_many_arguments)]
    pub fn sweep_shifts[F: CellSink](
        left: &Prepared,
        right: &Prepared,
        first: i64,
        np: usize,
        k: usize,
        cells: &Cells,
        right_best: &mut [u32],
        sink: &mut F,
    ) = shifts_body;
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn shifts_body<F: CellSink>(
    left: &Prepared,
    right: &Prepared,
    first: i64,
    np: usize,
    k: usize,
    cells: &Cells,
    right_best: &mut [u32],
    sink: &mut F,
) {
    let (wl, wr) = (left.img.width, right.img.width);
    let n = ((2 * k + 1) * (2 * k + 1)) as f32;
    let right_h = right.img.height;
    let mut vlw = vec![0.0f32; wl * np];
    let mut run = Running {
        top: 0,
        bottom: 0,
        empty: true,
    };
    let mut rrow = vec![0.0f32; wr];
    let mut rrow_in = vec![0.0f32; wr];
    let (mut lst, mut rst) = (RowStats::new(wl), RowStats::new(wr));
    // Right window mean·n and inverse deviation per column, reversed (index wr − 1 − x) so
    // that the planes of one reference column read them ascending; NaN where unseen.
    let mut r_mean = vec![0.0f32; wr];
    let mut r_inv = vec![f32::NAN; wr];
    let mut acc = vec![0.0f32; np];
    let mut dst = vec![0.0f32; np];
    // The right photo's winners, in the same reversed order.
    let mut rb = crate::matching::plane_sweep::winner::RightBest::new(wr, np);
    for (j, &r) in cells.rows.iter().enumerate() {
        let (sub, add, reset) = run.moves(r - k, r + k);
        if reset {
            vlw.iter_mut().for_each(|v| *v = 0.0);
        }
        // A window moving by whole rows: each row that leaves paired with one that enters,
        // so that the sums are read and written once for both.
        let paired = !reset && sub.len() == add.len() && sub.end <= right_h && add.end <= right_h;
        if paired {
            for (rs, ra) in sub.clone().zip(add.clone()) {
                rrow.copy_from_slice(&right.img.data[rs * wr..(rs + 1) * wr]);
                rrow.reverse();
                rrow_in.copy_from_slice(&right.img.data[ra * wr..(ra + 1) * wr]);
                rrow_in.reverse();
                let lrow_out = &left.img.data[rs * wl..(rs + 1) * wl];
                let lrow_in = &left.img.data[ra * wl..(ra + 1) * wl];
                for c in 0..wl {
                    let (lo, li) = (-lrow_out[c], lrow_in[c]);
                    let Some((p_lo, p_hi, i0)) = span_in_right(c, first, wr, np) else {
                        continue;
                    };
                    let d = &mut vlw[c * np + p_lo..c * np + p_hi + 1];
                    let so = &rrow[i0..i0 + d.len()];
                    let si = &rrow_in[i0..i0 + d.len()];
                    for ((d, so), si) in d.iter_mut().zip(so).zip(si) {
                        *d += lo * so + li * si;
                    }
                }
            }
        }
        let (sub, add) = if paired { (0..0, 0..0) } else { (sub, add) };
        for (rows, sign) in [(sub, -1.0f32), (add, 1.0f32)] {
            for rr in rows {
                if rr >= right_h {
                    continue;
                }
                rrow.copy_from_slice(&right.img.data[rr * wr..(rr + 1) * wr]);
                rrow.reverse();
                let lrow = &left.img.data[rr * wl..(rr + 1) * wl];
                for c in 0..wl {
                    let l = sign * lrow[c];
                    let Some((p_lo, p_hi, i0)) = span_in_right(c, first, wr, np) else {
                        continue;
                    };
                    let d = &mut vlw[c * np + p_lo..c * np + p_hi + 1];
                    let s = &rrow[i0..i0 + d.len()];
                    for (d, s) in d.iter_mut().zip(s) {
                        *d += l * s;
                    }
                }
            }
        }
        let want_rb = !right_best.is_empty();
        if want_rb {
            right_best[j * wr..(j + 1) * wr].fill(u32::MAX);
        }
        if r + k >= right_h {
            // The right photo has no such rows: nothing is seen.
            dst.iter_mut().for_each(|v| *v = f32::NAN);
            for i in 0..cells.cols {
                sink.cell(j, i, &dst);
            }
            continue;
        }
        lst.fill(left, r, k);
        rst.fill(right, r, k);
        // A flat right window (inverse deviation 0) scores 0: scored, uncorrelated; an
        // unseen one NaN.
        for (x, (m, v)) in rst.mean.iter().zip(&rst.inv).enumerate() {
            r_mean[wr - 1 - x] = m * n;
            r_inv[wr - 1 - x] = *v;
        }
        rb.clear();
        for i in 0..cells.cols {
            let c = cells.col0 + i * cells.stride;
            let afresh = cells.stride != 1 || i % RESUM == 0;
            window_columns(&vlw, np, c, k, &mut acc, afresh);
            let Some((ml, inv_l)) = lst.usable(c) else {
                // No reference: every plane −∞.
                dst.iter_mut().for_each(|v| *v = f32::NEG_INFINITY);
                sink.cell(j, i, &dst);
                continue;
            };
            // Seen planes: k ≤ x ≤ wr − 1 − k with x = c − first − p.
            let x0 = c as i64 - first;
            let p_lo = (x0 - (wr as i64 - 1 - k as i64)).clamp(0, np as i64) as usize;
            let p_hi = (x0 - k as i64 + 1).clamp(p_lo as i64, np as i64) as usize;
            dst[..p_lo].iter_mut().for_each(|v| *v = f32::NAN);
            dst[p_hi..].iter_mut().for_each(|v| *v = f32::NAN);
            if p_lo < p_hi {
                // The reversed index of plane p_lo (in i64 first: wr − 1 − x0 may be negative).
                let s0 = (wr as i64 - 1 - x0 + p_lo as i64) as usize;
                let s1 = s0 + (p_hi - p_lo);
                let (rm, ri) = (&r_mean[s0..s1], &r_inv[s0..s1]);
                // Σ(l − l̄)(w − w̄) = Σl·w − l̄·Σw.
                for (((d, a), m), v) in dst[p_lo..p_hi]
                    .iter_mut()
                    .zip(&acc[p_lo..p_hi])
                    .zip(rm)
                    .zip(ri)
                {
                    *d = ((a - ml * m) * inv_l * v).clamp(-1.0, 1.0);
                }
                if !want_rb {
                    sink.cell(j, i, &dst);
                    continue;
                }
                rb.offer(x0, &dst, p_lo, p_hi);
            }
            sink.cell(j, i, &dst);
        }
        if want_rb {
            rb.write(&mut right_best[j * wr..(j + 1) * wr]);
        }
    }
}

built_per_cpu! {
    /// Heights: the search photo is resampled once per plane over the rows' span, then the
    /// four search sums (Σw, Σw², Σl·w and the count of samples it does not see) run down and
    /// across. Built per CPU (see `simd`).
    fn score_warped[](
        left: &Prepared,
        right: &Prepared,
        planes: &Planes,
        k: usize,
        cells: &Cells,
        out: &mut Scores,
    ) = warped_body;
}

#[inline(always)]
fn warped_body(
    left: &Prepared,
    right: &Prepared,
    planes: &Planes,
    k: usize,
    cells: &Cells,
    out: &mut Scores,
) {
    let Planes::Heights { map, .. } = *planes else {
        return;
    };
    let np = planes.count();
    let wl = left.img.width;
    let n = ((2 * k + 1) * (2 * k + 1)) as f32;
    if cells.cols == 0 || cells.rows.is_empty() {
        return;
    }
    let (top, bottom) = (cells.rows[0] - k, cells.rows[cells.rows.len() - 1] + k);
    let span = bottom - top + 1;
    // The columns the cells' windows reach (a tile of a coarse-to-fine sweep is a small part
    // of the photo's width: warping and summing all of it cost nineteen times the tile's work
    // on a 1 200 px photo).
    let cx0 = cells.col0 - k;
    let cx1 = (cells.col0 + (cells.cols - 1) * cells.stride + k + 1).min(wl);
    let ww = cx1 - cx0;
    // The mapping as a polynomial in the normalised height for each reference pixel:
    // q(u) = Σ a_e·uᵉ, so a plane costs a Horner per coordinate, not the full polynomial.
    let (top_x, top_y) = (map.x.top_exponents(), map.y.top_exponents());
    let order = top_x[2].max(top_y[2]) as usize;
    let height = |p: usize| match *planes {
        Planes::Heights { h0, step, .. } => h0 + p as f64 * step,
        Planes::Shifts { .. } => 0.0,
    };
    let normalised = |n: &crate::matching::mapping::pmf::Normaliser| -> Vec<f64> {
        (0..np)
            .map(|p| (height(p) - n.centre[2]) / n.scale[2])
            .collect()
    };
    let (us, uy) = (normalised(&map.x.norm), normalised(&map.y.norm));
    // Warped values and their "unseen" flags, row-major over the span, planes innermost;
    // this thread's buffers of its last band, each element written below (so not cleared).
    let (mut wv, mut wn) = WARPED.with(|b| std::mem::take(&mut *b.borrow_mut()));
    for v in [&mut wv, &mut wn] {
        if v.capacity() < span * ww * np {
            *v = crate::matching::plane_sweep::volume::zeroed(span * ww * np);
        }
        v.resize(span * ww * np, 0.0);
    }
    let (rw, rh) = (right.img.width as f64, right.img.height as f64);
    let any_nodata = !right.nodata.is_empty();
    let mut ax = vec![0.0f64; order + 1];
    let mut ay = vec![0.0f64; order + 1];
    // Where each plane lands, for one reference pixel: Horner's steps run across the planes
    // (in each lane the operations of one plane's Horner, so the same bits).
    let (mut qxs, mut qys) = (vec![0.0f64; np], vec![0.0f64; np]);
    for rr in 0..span {
        let y = (top + rr) as f64 + 0.5;
        for c in cx0..cx1 {
            let x = c as f64 + 0.5;
            collapse(&map.x, top_x, x, y, &mut ax);
            collapse(&map.y, top_y, x, y, &mut ay);
            horner_across(&ax, &us, &mut qxs);
            horner_across(&ay, &uy, &mut qys);
            let o = (rr * ww + c - cx0) * np;
            for p in 0..np {
                let (qx, qy) = (qxs[p], qys[p]);
                // Bilinear, pixel centres at +0.5; the sample must have its four pixels.
                // A millionth of a pixel beyond the outermost centres is on them: a fitted
                // mapping lands there, not exactly on them.
                let (u, v) = (qx - 0.5, qy - 0.5);
                if !(u >= -1e-6 && v >= -1e-6 && u <= rw - 1.0 + 1e-6 && v <= rh - 1.0 + 1e-6) {
                    (wv[o + p], wn[o + p]) = (0.0, 1.0);
                    continue;
                }
                let (u, v) = (u.clamp(0.0, rw - 1.0), v.clamp(0.0, rh - 1.0));
                let (i, jj) = (
                    (u as usize).min(right.img.width.saturating_sub(2)),
                    (v as usize).min(right.img.height.saturating_sub(2)),
                );
                let (fx, fy) = ((u - i as f64) as f32, (v - jj as f64) as f32);
                let base = jj * right.img.width + i;
                let d = &right.img.data;
                let nd = &right.nodata;
                let rwid = right.img.width;
                if any_nodata
                    && nd[base] + nd[base + 1] + nd[base + rwid] + nd[base + rwid + 1] > 0.0
                {
                    (wv[o + p], wn[o + p]) = (0.0, 1.0);
                    continue;
                }
                let a = d[base] + fx * (d[base + 1] - d[base]);
                let b = d[base + rwid] + fx * (d[base + rwid + 1] - d[base + rwid]);
                (wv[o + p], wn[o + p]) = (a + fy * (b - a), 0.0);
            }
        }
    }
    let mut vw = vec![0.0f32; ww * np];
    let mut vw2 = vec![0.0f32; ww * np];
    let mut vlw = vec![0.0f32; ww * np];
    let mut vn = vec![0.0f32; ww * np];
    let mut run = Running {
        top: 0,
        bottom: 0,
        empty: true,
    };
    let mut lst = RowStats::new(wl);
    let (mut a_w, mut a_w2, mut a_lw, mut a_n) = (
        vec![0.0f32; np],
        vec![0.0f32; np],
        vec![0.0f32; np],
        vec![0.0f32; np],
    );
    for (j, &r) in cells.rows.iter().enumerate() {
        let (sub, add, reset) = run.moves(r - k, r + k);
        if reset {
            for v in [&mut vw, &mut vw2, &mut vlw, &mut vn] {
                v.iter_mut().for_each(|x| *x = 0.0);
            }
        }
        for (rows, sign) in [(sub, -1.0f32), (add, 1.0f32)] {
            for rr in rows {
                let lrow = &left.img.data[rr * wl + cx0..rr * wl + cx1];
                let o = (rr - top) * ww * np;
                for c in 0..ww {
                    let l = lrow[c];
                    let src = &wv[o + c * np..o + (c + 1) * np];
                    let srcn = &wn[o + c * np..o + (c + 1) * np];
                    let s = c * np..(c + 1) * np;
                    for (((w, w2), lw), v) in vw[s.clone()]
                        .iter_mut()
                        .zip(&mut vw2[s.clone()])
                        .zip(&mut vlw[s.clone()])
                        .zip(src)
                    {
                        *w += sign * v;
                        *w2 += sign * v * v;
                        *lw += sign * l * v;
                    }
                    for (d, m) in vn[s].iter_mut().zip(srcn) {
                        *d += sign * m;
                    }
                }
            }
        }
        lst.fill_columns(left, r, k, cx0, cx1);
        for i in 0..cells.cols {
            let c = cells.col0 + i * cells.stride;
            let afresh = cells.stride != 1 || i % RESUM == 0;
            window_columns(&vw, np, c - cx0, k, &mut a_w, afresh);
            window_columns(&vw2, np, c - cx0, k, &mut a_w2, afresh);
            window_columns(&vlw, np, c - cx0, k, &mut a_lw, afresh);
            window_columns(&vn, np, c - cx0, k, &mut a_n, afresh);
            let Some((ml, inv_l)) = lst.usable(c) else {
                continue; // no reference: every plane stays −∞
            };
            let o = (j * cells.cols + i) * np;
            let inv_n = 1.0 / n;
            // Without branches, so that it runs on vector lanes: a flat search window scores
            // 0 (uncorrelated), an unseen one NaN.
            for ((((d, &w), &w2), &lw), &un) in out.v[o..o + np]
                .iter_mut()
                .zip(&a_w)
                .zip(&a_w2)
                .zip(&a_lw)
                .zip(&a_n)
            {
                let var_w = w2 - w * w * inv_n;
                // Σ(l − l̄)(w − w̄) = Σl·w − l̄·Σw.
                let cov = lw - ml * w;
                let flat = var_w <= 1e-5 * w2.max(1e-12) || var_w <= 1e-9;
                let v = if flat {
                    0.0
                } else {
                    cov * inv_l / var_w.sqrt()
                };
                *d = if un > 0.5 {
                    f32::NAN
                } else {
                    v.clamp(-1.0, 1.0)
                };
            }
        }
    }
    WARPED.with(|b| *b.borrow_mut() = (wv, wn));
}

thread_local! {
    /// [`score_warped`]'s warped band, kept for the thread's next band: clearing a fresh one
    /// took a tenth of a sweep.
    static WARPED: std::cell::RefCell<(Vec<f32>, Vec<f32>)> = const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

#[inline(always)]
fn add_into(a: &mut [f32], b: &[f32]) {
    for (x, y) in a.iter_mut().zip(b) {
        *x += y;
    }
}

/// The coefficients of `poly` at (x, y) as a polynomial in its normalised third variable.
fn collapse(
    poly: &crate::matching::mapping::pmf::Polynomial,
    top: [u8; 3],
    x: f64,
    y: f64,
    a: &mut [f64],
) {
    use crate::matching::mapping::pmf::{powers, MOST_POWERS};
    a.iter_mut().for_each(|v| *v = 0.0);
    let u = poly.norm.apply([x, y, poly.norm.centre[2]]);
    if top[0] as usize >= MOST_POWERS || top[1] as usize >= MOST_POWERS {
        for (t, c) in poly.terms.iter().zip(&poly.coef) {
            a[t.2 as usize] += c * u[0].powi(t.0 as i32) * u[1].powi(t.1 as i32);
        }
        return;
    }
    // Each power once (`top`: the polynomial's highest exponents, found once a band).
    let (p0, p1) = (powers(u[0], top[0]), powers(u[1], top[1]));
    for (t, c) in poly.terms.iter().zip(&poly.coef) {
        a[t.2 as usize] += c * p0[t.0 as usize] * p1[t.1 as usize];
    }
}

/// The polynomial with coefficients `a` (lowest first) at every `u` into `q` by Horner's
/// rule, a coefficient at a time over all of them.
#[inline(always)]
fn horner_across(a: &[f64], u: &[f64], q: &mut [f64]) {
    q.iter_mut().for_each(|v| *v = 0.0);
    for c in a.iter().rev() {
        for (v, &u) in q.iter_mut().zip(u) {
            *v = *v * u + c;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tex(x: f64, y: f64) -> f32 {
        ((x * 0.71).sin() * (y * 0.53).cos()
            + (x * 0.23 + y * 0.37).sin()
            + (x * 1.7 - y * 1.3).sin() * 0.5) as f32
            * 40.0
            + 100.0
    }

    /// A photo is brought to mean 0 and deviation 1 (computed here in two plain passes), also
    /// when its mean is far larger than its deviation; nodata is flagged only where there is
    /// some.
    #[test]
    fn prepared_has_unit_deviation_and_flags_only_nodata() {
        for (offset, nan) in [(0.0f32, false), (30000.0, false), (30000.0, true)] {
            let mut img = ImageF32::new(300, 7);
            for (i, v) in img.data.iter_mut().enumerate() {
                *v = offset + ((i * 7919) % 13) as f32 * 0.25;
            }
            if nan {
                img.data[5] = f32::NAN;
            }
            let p = Prepared::new(&img);
            let fin: Vec<f64> = img
                .data
                .iter()
                .filter(|v| v.is_finite())
                .map(|&v| v as f64)
                .collect();
            let m = fin.iter().sum::<f64>() / fin.len() as f64;
            let sd = (fin.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / fin.len() as f64).sqrt();
            for (a, b) in img.data.iter().zip(&p.img.data) {
                let want = if a.is_finite() {
                    ((*a as f64 - m) / sd) as f32
                } else {
                    0.0
                };
                assert!((b - want).abs() < 1e-5, "{offset}: {b} vs {want}");
            }
            assert_eq!(p.nodata.is_empty(), !nan);
            if nan {
                assert_eq!(p.nodata.iter().filter(|&&v| v == 1.0).count(), 1);
                assert_eq!(p.nodata[5], 1.0);
            }
        }
    }

    /// The running sums give the NCC that a direct computation over each window gives, for
    /// every plane, cell and stride; a window beyond the right photo is NaN.
    #[test]
    fn running_sums_equal_the_direct_correlation() {
        let (w, h) = (60usize, 30usize);
        let mut left = ImageF32::new(w, h);
        let mut right = ImageF32::new(w - 7, h);
        for r in 0..h {
            for c in 0..w {
                left.data[r * w + c] = tex(c as f64, r as f64);
            }
            for c in 0..w - 7 {
                right.data[r * (w - 7) + c] = tex(c as f64 * 1.1 + 3.0, r as f64) + (c % 3) as f32;
            }
        }
        let (lp, rp) = (Prepared::new(&left), Prepared::new(&right));
        let k = 3;
        for stride in [1, 2] {
            let cells = Cells {
                col0: k,
                stride,
                cols: (w - 2 * k).div_ceil(stride),
                rows: (k..h - k).step_by(stride).collect(),
            };
            let planes = Planes::Shifts {
                first: -2,
                count: 12,
            };
            let s = score(&lp, &rp, &planes, k, &cells);
            for (j, &r) in cells.rows.iter().enumerate() {
                for i in 0..cells.cols {
                    let c = cells.col0 + i * stride;
                    for p in 0..12 {
                        let x = c as i64 + 2 - p as i64;
                        let got = s.cell(i, j)[p];
                        if x < k as i64 || x + k as i64 >= (w - 7) as i64 {
                            assert!(got.is_nan(), "({c},{r}) plane {p}: {got}");
                            continue;
                        }
                        let (mut a, mut b) = (Vec::new(), Vec::new());
                        for rr in r - k..=r + k {
                            for d in -(k as i64)..=k as i64 {
                                a.push(left.at((c as i64 + d) as usize, rr) as f64);
                                b.push(right.at((x + d) as usize, rr) as f64);
                            }
                        }
                        let want = crate::correlation::ncc(&a, &b) as f32;
                        assert!(
                            (got - want).abs() < 2e-4,
                            "({c},{r}) plane {p}: {got} vs {want}"
                        );
                    }
                }
            }
        }
    }

    /// Heights mapped by a polynomial that is a pure shift (x″ = x′ − 2 − h) score what the
    /// disparities score: the resampling lands on pixel centres, the sums are the same.
    #[test]
    fn warped_heights_agree_with_shifts() {
        use crate::matching::mapping::pmf::{Normaliser, Polynomial, Term};
        let (w, h) = (50usize, 24usize);
        let mut left = ImageF32::new(w, h);
        let mut right = ImageF32::new(w, h);
        for r in 0..h {
            for c in 0..w {
                left.data[r * w + c] = tex(c as f64, r as f64);
                right.data[r * w + c] = tex(c as f64 + 5.0, r as f64 * 0.9);
            }
        }
        let samples: Vec<([f64; 3], f64)> = (0..4)
            .flat_map(|i| {
                (0..3).map(move |q| [i as f64 * 15.0, 3.0 + i as f64 * 5.0, q as f64 * 4.0])
            })
            .map(|v| (v, v[0] - 2.0 - v[2]))
            .collect();
        let norm = Normaliser::over(&samples.iter().map(|s| s.0).collect::<Vec<_>>());
        let x = Polynomial::fit(
            &[Term(0, 0, 0), Term(1, 0, 0), Term(0, 0, 1)],
            &norm,
            &samples,
        )
        .unwrap();
        let ys: Vec<_> = samples.iter().map(|s| (s.0, s.0[1])).collect();
        let y = Polynomial::fit(&[Term(0, 0, 0), Term(0, 1, 0)], &norm, &ys).unwrap();
        let map = Mapping { x, y };
        let (lp, rp) = (Prepared::new(&left), Prepared::new(&right));
        let k = 4;
        let cells = Cells {
            col0: k,
            stride: 1,
            cols: w - 2 * k,
            rows: (k..h - k).collect(),
        };
        let a = score(&lp, &rp, &Planes::Shifts { first: 2, count: 9 }, k, &cells);
        let b = score(
            &lp,
            &rp,
            &Planes::Heights {
                map: &map,
                h0: 0.0,
                step: 1.0,
                count: 9,
            },
            k,
            &cells,
        );
        let (mut compared, mut skipped) = (0, 0);
        for (x, y) in a.v.iter().zip(&b.v) {
            if x.is_nan() != y.is_nan() {
                skipped += 1;
            }
            if x.is_nan() || y.is_nan() {
                continue;
            }
            assert!((x - y).abs() < 1e-3, "{x} vs {y}");
            compared += 1;
        }
        assert!(
            compared > 2000 && skipped == 0,
            "{compared} compared, {skipped} unseen by one only"
        );
    }
}
