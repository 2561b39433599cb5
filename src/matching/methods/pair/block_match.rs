//! Block matching's winners on a rectified pair, plane by plane. The disparity sweep of
//! [`crate::matching::plane_sweep::sweep_shifts`] keeps each cell's planes together (SGM needs them so,
//! for its volume), and so pays per cell for the window's columns, the plane range, the winner
//! and the right photo's winners. Here the planes are the outer loop: for one disparity the
//! column sums of Σl·w are moved down a row in one pass along the row, and the window sums,
//! correlations, the cells' winners and the right photo's winners in a second, on vector
//! lanes. The scores are the same correlations (summed in another order, so equal to a few
//! units in the last place) and the winners follow the same rules
//! ([`crate::matching::plane_sweep::winner::winner`] with [`crate::matching::plane_sweep::winner::Unseen::Skip`], the first of equal scores).
//!
//! Every plane's column sums and scores of a row must stay in a core's cache while the rows
//! pass. Wide photos with deep ranges (6000 px × 2048 disparities: 49 MB) are matched in
//! strips of columns ([`strip_cells`]), each strip down all the band's rows before the next:
//! 1.55 → 0.62 s on such a pair, 0.53 → 0.41 s on 2000 px × 1024.

use crate::matching::plane_sweep::winner::{stands_out, RowPicks};
use crate::matching::plane_sweep::{Prepared, RowStats};

/// What the winners need beyond the photos.
#[derive(Debug, Clone, Copy)]
pub struct BlockParams {
    /// Reference pixel c meets right pixel c − first − p on plane p (p < planes).
    pub first: i64,
    pub planes: usize,
    /// Half the window's side.
    pub k: usize,
    /// The uniqueness ratio (0: no test), on the cost 1 − NCC counted from `floor`.
    pub uniqueness: f32,
    pub floor: f32,
    /// Whether the right photo's winners are wanted (for the left-right check).
    pub right_winners: bool,
}

/// Takes each row's winners as they come: `row(j, picks, right)` for the j-th of the rows,
/// the picks of its cells and the right photo's winners (empty when not wanted).
pub trait RowSink {
    fn row(&mut self, j: usize, picks: &RowPicks, right: &[u32]);
}

impl<F: FnMut(usize, &RowPicks, &[u32])> RowSink for F {
    fn row(&mut self, j: usize, picks: &RowPicks, right: &[u32]) {
        self(j, picks, right)
    }
}

built_per_cpu! {
    /// The winners of `rows` (ascending; consecutive rows reuse the column sums) to `sink`,
    /// row by row in their order: the picks of cells c = k … wl − k − 1 of the left photo,
    /// and, with `right_winners`, the right photo's winner for each of its columns (u32::MAX
    /// where none). A row of one strip goes as soon as it is done (no band of picks is
    /// kept); rows of several strips when the last strip is. Built per CPU (see `simd`).
    pub fn block_match[S: RowSink](
        left: &Prepared,
        right: &Prepared,
        bp: &BlockParams,
        rows: &[usize],
        sink: &mut S,
    ) = band_body;
}

/// One plane's pass over a run of cells: each window's Σl·w from `W` consecutive column sums
/// `v` (W = 1: `v` holds the window sums), the correlation against the right window's mean·n
/// `rm` and inverse deviation `ri` (NaN: unseen, 0: flat) with the left's mean `ml` and
/// inverse deviation `il` (NaN where the left has nothing to match), into `out` (not clamped
/// to [−1, 1]: the picks are); the cells' winners `best`/`at` and, with `RB`, the right
/// photo's winners `rbest`/`rat` (the same run of columns, moved) keep it where it beats
/// them (see [`better`]). One loop, so that nothing but the scores and the winners goes
/// through memory.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn plane_pass<const W: usize, const RB: bool>(
    v: &[f32],
    ml: &[f32],
    il: &[f32],
    rm: &[f32],
    ri: &[f32],
    out: &mut [f32],
    best: &mut [f32],
    at: &mut [u32],
    rbest: &mut [f32],
    rat: &mut [u32],
    p: u32,
) {
    let n = out.len();
    let v = &v[..n + W - 1];
    let (ml, il, rm, ri, best, at) = (
        &ml[..n],
        &il[..n],
        &rm[..n],
        &ri[..n],
        &mut best[..n],
        &mut at[..n],
    );
    let (rbest, rat) = if RB {
        (&mut rbest[..n], &mut rat[..n])
    } else {
        (&mut rbest[..0], &mut rat[..0])
    };
    for i in 0..n {
        let mut h = 0.0f32;
        for d in 0..W {
            h += v[i + d];
        }
        // Σ(l − l̄)(w − w̄) = Σl·w − l̄·Σw; rounding may take it a few units in the last
        // place beyond ±1: the winner's scores are clamped when they are picked.
        let s = (h - ml[i] * rm[i]) * il[i] * ri[i];
        out[i] = s;
        let (b, a) = better(best[i], at[i], s, p);
        (best[i], at[i]) = (b, a);
        if RB {
            let (b, a) = better(rbest[i], rat[i], s, p);
            (rbest[i], rat[i]) = (b, a);
        }
    }
}

/// The best score and its plane after score `s` of plane `p` (above every plane before it)
/// meets the best `b` at plane `a`: s and p where s > b (NaN never is; of equal scores the
/// first plane stays), else b and a. Both are chosen between registers (a compare and two
/// blends on vector lanes); measured 2 % (AVX-512) to 12 % (AVX2) faster than taking the plane
/// as a max under a sign mask.
#[inline(always)]
fn better(b: f32, a: u32, s: f32, p: u32) -> (f32, u32) {
    let won = s > b;
    (if won { s } else { b }, if won { p } else { a })
}

/// Σ of `w` consecutive values of `v` from each of `out.len()` starts, by doubling: sums of 2,
/// 4, 8 … consecutive values, one pass each, taken by w's binary digits (log₂ w passes, not w).
fn box_sums(v: &[f32], w: usize, out: &mut [f32], lv: &mut Vec<f32>, next: &mut Vec<f32>) {
    let n = out.len();
    out.fill(0.0);
    // Level `size`: lv[i] = Σ v[i..i + size], for i < n + w − size.
    lv.clear();
    lv.extend_from_slice(&v[..n + w - 1]);
    let (mut off, mut size, mut rem) = (0, 1, w);
    loop {
        if rem & 1 == 1 {
            for (o, x) in out.iter_mut().zip(&lv[off..off + n]) {
                *o += x;
            }
            off += size;
        }
        rem >>= 1;
        if rem == 0 {
            break;
        }
        let m = lv.len() - size;
        next.resize(m, 0.0);
        for (o, (a, b)) in next.iter_mut().zip(lv.iter().zip(&lv[size..])) {
            *o = a + b;
        }
        std::mem::swap(lv, next);
        size *= 2;
    }
}

/// v += l·r (a row entering the window, the first rows of a band).
#[inline(always)]
fn add_row(v: &mut [f32], l: &[f32], r: &[f32]) {
    for ((v, l), r) in v.iter_mut().zip(l).zip(r) {
        *v += l * r;
    }
}

/// v += l_in·r_in − l_out·r_out (the window moves down one row).
#[inline(always)]
fn move_row(v: &mut [f32], li: &[f32], ri: &[f32], lo: &[f32], ro: &[f32]) {
    for ((((v, a), b), c), d) in v.iter_mut().zip(li).zip(ri).zip(lo).zip(ro) {
        *v += a * b - c * d;
    }
}

fn row(img: &Prepared, r: usize) -> &[f32] {
    let w = img.img.width;
    &img.img.data[r * w..(r + 1) * w]
}

/// Cells per strip: every plane's column sums and scores for a strip (8·np·(T + k) bytes)
/// within about 512 KiB, so that a core's cache holds them while a band's rows pass, but at
/// least 128 cells (the vector lanes and each plane's fixed costs). At 64 disparities a strip
/// is 1000 cells: most rows are one strip.
pub fn strip_cells(np: usize, k: usize) -> usize {
    ((512 << 10) / (8 * np.max(1))).saturating_sub(k).max(128)
}

/// Bytes a thread holds for a band of `rows` rows: each row's window statistics, picks and
/// right-photo winners, a strip's column sums and scores, and the row statistics' sums.
pub fn bytes_per_band(wl: usize, wr: usize, np: usize, k: usize, rows: usize) -> f64 {
    let cols = wl.saturating_sub(2 * k) as f64;
    let t = strip_cells(np, k) as f64;
    let (wl, wr, np) = (wl as f64, wr as f64, np as f64);
    rows as f64 * (8.0 * cols + 8.0 * wr + 21.0 * cols + 8.0 * wr)
        + 4.0 * np * (2.0 * t + 2.0 * k as f64)
        + 24.0 * (wl + wr)
}

#[inline(always)]
fn band_body<S: RowSink>(
    left: &Prepared,
    right: &Prepared,
    bp: &BlockParams,
    rows: &[usize],
    sink: &mut S,
) {
    let (first, np, k) = (bp.first, bp.planes, bp.k);
    let (wl, wr, hr) = (left.img.width, right.img.width, right.img.height);
    let w = 2 * k + 1;
    let cols = wl.saturating_sub(2 * k);
    if cols == 0 || np == 0 {
        return;
    }
    let nr = rows.len();
    let want_unique = bp.uniqueness > 0.0;
    let rw = bp.right_winners;
    // Cells per strip. A row of one strip is done before the next row: its statistics, picks
    // and right-photo winners are kept for that row only (slot 0) and handed on at once. Rows
    // of several strips keep them for every row of the band (slot j) until the last strip.
    let t = strip_cells(np, k).min(cols);
    let single = t >= cols;
    let slots = if single { 1 } else { nr };
    let slot = |j: usize| if single { 0 } else { j };
    // The rows the right photo has (else nothing is seen), and each row's window statistics:
    // the left's mean and inverse deviation per cell (NaN: nothing to match), the right's
    // mean·n and inverse deviation per column (NaN: unseen, 0: flat).
    let seen: Vec<bool> = rows.iter().map(|&r| r >= k && r + k < hr).collect();
    let mut st = Stats {
        left: RowStats::new(wl),
        right: RowStats::new(wr),
        ml: vec![0.0f32; slots * cols],
        il: vec![0.0f32; slots * cols],
        rm: vec![0.0f32; slots * wr],
        ri: vec![0.0f32; slots * wr],
    };
    if !single {
        for (j, &r) in rows.iter().enumerate() {
            if seen[j] {
                st.fill(left, right, j, r, k);
            }
        }
    }
    let mut picks: Vec<RowPicks> = (0..slots)
        .map(|_| {
            let mut p = RowPicks::default();
            p.unseen(cols);
            p
        })
        .collect();
    let mut rbs = vec![u32::MAX; if rw { wr } else { 0 }];
    // The right photo's winners of every row, over all strips: for one right column the strips
    // come in ascending order of their planes, so the first of equal scores stays.
    let rn = if rw { slots * wr } else { 0 };
    let (mut rbest, mut rat) = (vec![f32::NEG_INFINITY; rn], vec![0u32; rn]);
    // A strip's column sums of Σl·w (plane p, strip column c at [p·sw + c]), its cells'
    // winners, every plane's scores of its row (plane p, cell i at [p·sc + i]; NaN: unseen)
    // for the winners' neighbours and the uniqueness test, and the highest beyond them (−∞
    // throughout without the test: every winner stands out).
    let (mut v, mut all) = (Vec::new(), Vec::new());
    let (mut best, mut at, mut other) = (Vec::new(), Vec::new(), Vec::new());
    // Window sums and their doubling levels for windows above 9.
    let (mut hsum, mut lv, mut lv2) = (vec![0.0f32; t], Vec::new(), Vec::new());
    for s0 in (0..cols).step_by(t) {
        // Cells s0 … s0 + sc − 1; their windows' left columns s0 … s0 + sw − 1.
        let sc = t.min(cols - s0);
        let sw = sc + 2 * k;
        v.clear();
        v.resize(np * sw, 0.0f32);
        all.clear();
        all.resize(np * sc, f32::NAN);
        best.resize(sc, f32::NEG_INFINITY);
        at.resize(sc, 0u32);
        other.clear();
        other.resize(sc, f32::NEG_INFINITY);
        let mut last: Option<usize> = None;
        for (j, &r) in rows.iter().enumerate() {
            let q = slot(j);
            if !seen[j] {
                last = None;
                if single {
                    picks[0].unseen(cols);
                    rbs.fill(u32::MAX);
                    sink.row(j, &picks[0], &rbs);
                }
                continue;
            }
            if single {
                st.fill(left, right, 0, r, k);
                if rw {
                    rbest.fill(f32::NEG_INFINITY);
                    rat.fill(0);
                }
            }
            let fresh = last.is_none_or(|q| q + 1 != r);
            if fresh {
                v.fill(0.0);
            }
            last = Some(r);
            best.fill(f32::NEG_INFINITY);
            at.fill(0);
            let (mlj, ilj) = (
                &st.ml[q * cols + s0..q * cols + s0 + sc],
                &st.il[q * cols + s0..q * cols + s0 + sc],
            );
            let (rmj, rij) = (&st.rm[q * wr..(q + 1) * wr], &st.ri[q * wr..(q + 1) * wr]);
            let (rbj, raj): (&mut [f32], &mut [u32]) = if rw {
                (
                    &mut rbest[q * wr..(q + 1) * wr],
                    &mut rat[q * wr..(q + 1) * wr],
                )
            } else {
                (&mut [], &mut [])
            };
            for p in 0..np {
                // Left column c meets right column c − s.
                let s = first + p as i64 - s0 as i64;
                let clamp = |x: i64, hi: usize| x.clamp(0, hi as i64) as usize;
                // The strip's column sums that meet the right photo: c in [s, s + wr).
                let (c0, c1) = (clamp(s, sw), clamp(s + wr as i64, sw));
                if c0 < c1 {
                    let x0 = (c0 as i64 - s) as usize;
                    let len = c1 - c0;
                    let vp = &mut v[p * sw + c0..p * sw + c1];
                    let (l0, l1) = (s0 + c0, s0 + c1);
                    if fresh {
                        for rr in r - k..=r + k {
                            add_row(vp, &row(left, rr)[l0..l1], &row(right, rr)[x0..x0 + len]);
                        }
                    } else {
                        let (r_in, r_out) = (r + k, r - k - 1);
                        move_row(
                            vp,
                            &row(left, r_in)[l0..l1],
                            &row(right, r_in)[x0..x0 + len],
                            &row(left, r_out)[l0..l1],
                            &row(right, r_out)[x0..x0 + len],
                        );
                    }
                }
                // The cells whose window the right photo holds: strip cell i (column
                // s0 + k + i) in [s, s + wr − 2k); right window centre x = i + k − s.
                let (i0, i1) = (clamp(s, sc), clamp(s + wr as i64 - 2 * k as i64, sc));
                let i1 = i1.max(i0);
                let out = &mut all[p * sc..(p + 1) * sc];
                out[..i0].fill(f32::NAN);
                out[i1..].fill(f32::NAN);
                if i0 == i1 {
                    continue;
                }
                let xs = (i0 as i64 + k as i64 - s) as usize;
                let x1 = xs + (i1 - i0);
                let vs = &v[p * sw + i0..p * sw + i1 + 2 * k];
                let (rbs_, rats) = if rw {
                    (&mut rbj[xs..x1], &mut raj[xs..x1])
                } else {
                    (&mut rbj[..0], &mut raj[..0])
                };
                let (ms, is, rms, ris) = (&mlj[i0..i1], &ilj[i0..i1], &rmj[xs..x1], &rij[xs..x1]);
                let (o, b, a) = (&mut out[i0..i1], &mut best[i0..i1], &mut at[i0..i1]);
                let pu = p as u32;
                macro_rules! pass {
                    ($w:expr, $vs:expr) => {
                        if rw {
                            plane_pass::<$w, true>($vs, ms, is, rms, ris, o, b, a, rbs_, rats, pu)
                        } else {
                            plane_pass::<$w, false>($vs, ms, is, rms, ris, o, b, a, rbs_, rats, pu)
                        }
                    };
                }
                match w {
                    3 => pass!(3, vs),
                    5 => pass!(5, vs),
                    7 => pass!(7, vs),
                    9 => pass!(9, vs),
                    _ => {
                        // Larger windows: the window sums by doubling (log₂ w passes, not w).
                        box_sums(vs, w, &mut hsum[..i1 - i0], &mut lv, &mut lv2);
                        pass!(1, &hsum[..i1 - i0])
                    }
                }
            }
            // The highest score beyond each winner's neighbours, for the uniqueness test.
            if want_unique {
                other.fill(f32::NEG_INFINITY);
                for p in 0..np {
                    others(&mut other, &all[p * sc..(p + 1) * sc], &at, p as u32);
                }
            }
            take_picks(&mut picks[q], s0, &best, &at, ilj, &all, &other, np, bp);
            if single {
                hand_on(
                    j,
                    &picks[0],
                    rw.then(|| (&rbest[..wr], &rat[..wr])),
                    &mut rbs,
                    sink,
                );
            }
        }
    }
    if !single {
        for (j, pk) in picks.iter().enumerate() {
            if seen[j] {
                hand_on(
                    j,
                    pk,
                    rw.then(|| (&rbest[j * wr..(j + 1) * wr], &rat[j * wr..(j + 1) * wr])),
                    &mut rbs,
                    sink,
                );
            } else {
                rbs.fill(u32::MAX);
                sink.row(j, pk, &rbs);
            }
        }
    }
}

/// Each row's window statistics (slot q of `ml`, `il`: the left's mean and inverse deviation
/// per cell, NaN: nothing to match; of `rm`, `ri`: the right's mean·n and inverse deviation per
/// column, NaN: unseen, 0: flat).
struct Stats {
    left: RowStats,
    right: RowStats,
    ml: Vec<f32>,
    il: Vec<f32>,
    rm: Vec<f32>,
    ri: Vec<f32>,
}

impl Stats {
    /// Row r's statistics into slot q.
    #[inline(always)]
    fn fill(&mut self, left: &Prepared, right: &Prepared, q: usize, r: usize, k: usize) {
        let (wl, wr) = (left.img.width, right.img.width);
        let cols = wl - 2 * k;
        let n = ((2 * k + 1) * (2 * k + 1)) as f32;
        self.left.fill(left, r, k);
        self.right.fill(right, r, k);
        let (l, rs) = (&self.left, &self.right);
        let (mj, ij) = (
            &mut self.ml[q * cols..(q + 1) * cols],
            &mut self.il[q * cols..(q + 1) * cols],
        );
        for (i, (m, v)) in mj.iter_mut().zip(ij).enumerate() {
            let inv = l.inv[k + i];
            *m = l.mean[k + i];
            *v = if inv > 0.0 { inv } else { f32::NAN };
        }
        let (mj, ij) = (
            &mut self.rm[q * wr..(q + 1) * wr],
            &mut self.ri[q * wr..(q + 1) * wr],
        );
        for (x, (m, v)) in mj.iter_mut().zip(ij).enumerate() {
            *m = rs.mean[x] * n;
            *v = rs.inv[x];
        }
    }
}

/// Row j's picks to the sink, with its right-photo winners (best scores and their planes,
/// where wanted) into `rbs`.
#[inline(always)]
fn hand_on<S: RowSink>(
    j: usize,
    pk: &RowPicks,
    right: Option<(&[f32], &[u32])>,
    rbs: &mut [u32],
    sink: &mut S,
) {
    if let Some((b, a)) = right {
        for ((o, &a), &b) in rbs.iter_mut().zip(a).zip(b) {
            *o = if b > f32::NEG_INFINITY { a } else { u32::MAX };
        }
    }
    sink.row(j, pk, rbs);
}

/// A row's picks of cells `off` … `off + best.len() − 1` from their best scores `best` at
/// planes `at`, the left windows'
/// inverse deviations `il` (NaN: nothing to match), every plane's scores `all` (plane p,
/// cell i at [p·cols + i]) and the highest score beyond each winner's neighbours `other`.
/// A winner beside a plane the right photo does not see gets no plane (the peak may be the
/// flank of a match there); the scores are clamped to [−1, 1] (rounding takes them a few
/// units in the last place beyond) and a flat right window's −0 (by the sign of the rest)
/// is made +0. Without a branch, so that the cells are taken on vector lanes; each
/// neighbour is read at a plane inside the range and replaced by +∞ beyond its ends.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn take_picks(
    pk: &mut RowPicks,
    off: usize,
    best: &[f32],
    at: &[u32],
    il: &[f32],
    all: &[f32],
    other: &[f32],
    np: usize,
    bp: &BlockParams,
) {
    let cols = best.len();
    let cells = off..off + cols;
    let (plane, rho) = (&mut pk.plane[cells.clone()], &mut pk.rho[cells.clone()]);
    let (below, above) = (&mut pk.below[cells.clone()], &mut pk.above[cells.clone()]);
    let (offset, uniq) = (&mut pk.offset[cells.clone()], &mut pk.unique[cells]);
    offset.fill(f32::NAN);
    let (at, il, other) = (&at[..cols], &il[..cols], &other[..cols]);
    let last = np.saturating_sub(1);
    let clean = |v: f32| v.clamp(-1.0, 1.0) + 0.0;
    for i in 0..cols {
        let (b, pl) = (best[i], at[i] as usize);
        let lo = all[pl.saturating_sub(1) * cols + i];
        let lo = if pl >= 1 { lo } else { f32::INFINITY };
        let hi = all[(pl + 1).min(last) * cols + i];
        let hi = if pl < last { hi } else { f32::INFINITY };
        let unscored = il[i].is_nan();
        let seen = b > f32::NEG_INFINITY && !lo.is_nan() && !hi.is_nan();
        let has = !unscored && seen;
        plane[i] = if has { pl as u32 } else { RowPicks::NONE };
        rho[i] = if unscored {
            f32::NEG_INFINITY
        } else if seen {
            clean(b)
        } else {
            f32::NAN
        };
        let fin = |v: f32| {
            if has && v.is_finite() {
                clean(v)
            } else {
                f32::NAN
            }
        };
        below[i] = fin(lo);
        above[i] = fin(hi);
        uniq[i] = !has || stands_out(b, other[i], bp.uniqueness, bp.floor, |v| 1.0 - v);
    }
}

/// The highest of plane `p`'s scores `s` (NaN left out) into `other` where p is not the
/// cell's winner `at` or beside it.
#[inline(always)]
fn others(other: &mut [f32], s: &[f32], at: &[u32], p: u32) {
    for ((o, &s), &a) in other.iter_mut().zip(s).zip(at) {
        let near = p.wrapping_sub(a).wrapping_add(1) <= 2;
        // A max (NaN left out), not a choice (see `better`).
        *o = o.max(if near { f32::NEG_INFINITY } else { s });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::ImageF32;
    use crate::matching::plane_sweep::winner::{unique, winner, Pick, Unseen};
    use crate::matching::plane_sweep::{sweep_shifts, CellSink, Cells};

    /// The cell-major sweep's picks, as the pair matcher took them before this module.
    struct Picks {
        np: usize,
        u: f32,
        floor: f32,
        v: Vec<Pick>,
        scores: Vec<Vec<f32>>,
    }

    impl CellSink for Picks {
        fn cell(&mut self, _: usize, _: usize, s: &[f32]) {
            let win = winner(s, Unseen::Skip);
            let mut pick = Pick::new(win, self.np, |p| s[p]);
            pick.unique = win.is_none_or(|w| unique(s, w.plane, self.u, self.floor, |v| 1.0 - v));
            self.v.push(pick);
            self.scores.push(s.to_vec());
        }
    }

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A textured pair with a flat patch, nodata in both photos, a right photo narrower than
    /// the left, and disparities that run beyond both photos' edges.
    fn pair(seed: u64, wl: usize, wr: usize, h: usize) -> (ImageF32, ImageF32) {
        let mut s = seed;
        let mut tex = vec![0.0f32; (wl + 40) * h];
        for v in tex.iter_mut() {
            *v = (lcg(&mut s) * 200.0) as f32;
        }
        let mut left = ImageF32::new(wl, h);
        let mut right = ImageF32::new(wr, h);
        for r in 0..h {
            for c in 0..wl {
                left.data[r * wl + c] = tex[r * (wl + 40) + c + 10];
            }
            for c in 0..wr {
                // Disparity 6 on the left half, 11 on the right half, with noise.
                let d = if c < wr / 2 { 6 } else { 11 };
                right.data[r * wr + c] =
                    tex[r * (wl + 40) + c + 10 + d] + (lcg(&mut s) * 8.0) as f32;
            }
        }
        for r in 8..13 {
            for c in 20..30 {
                left.data[r * wl + c] = 50.0; // flat
            }
        }
        left.data[3 * wl + 40] = f32::NAN;
        right.data[15 * wr + 17] = f32::NAN;
        (left, right)
    }

    /// The plane-by-plane winners are the cell-major sweep's: the same plane, correlation,
    /// neighbours, unseen flags and uniqueness, and the same right-photo winners, over
    /// window sizes (const and general), disparity ranges that reach beyond both photos,
    /// rows that start a band afresh and rows that move on.
    #[test]
    fn same_winners_as_the_cell_major_sweep() {
        let mut compared = 0;
        // The last photos with 700 disparities are matched in strips (of 128 cells: four of
        // them), whose right-photo winners meet across the strips.
        assert!(strip_cells(700, 2) < 416);
        for (seed, wl, wr, h) in [
            (1u64, 70usize, 60usize, 26usize),
            (2, 50, 50, 22),
            (3, 420, 380, 18),
        ] {
            let (l, r) = pair(seed, wl, wr, h);
            let (lp, rp) = (Prepared::new(&l), Prepared::new(&r));
            for (k, first, np, u) in [
                (2usize, 0i64, 16usize, 0.1f32),
                (1, -5, 24, 0.0),
                (3, 4, 9, 0.3),
                (5, -20, 40, 0.1),
                (2, -300, 700, 0.1),
            ] {
                let rows: Vec<usize> = (k..h - k).filter(|&r| r != k + 4).collect();
                let bpar = BlockParams {
                    first,
                    planes: np,
                    k,
                    uniqueness: u,
                    floor: 1e-3,
                    right_winners: true,
                };
                let (mut got, mut got_rb) = (Vec::new(), Vec::new());
                block_match(
                    &lp,
                    &rp,
                    &bpar,
                    &rows,
                    &mut |_: usize, p: &RowPicks, r: &[u32]| {
                        got.extend((0..p.len()).map(|i| p.get(i)));
                        got_rb.extend_from_slice(r);
                    },
                );
                let cols = wl - 2 * k;
                let cells = Cells {
                    col0: k,
                    stride: 1,
                    cols,
                    rows: rows.clone(),
                };
                let mut want = Picks {
                    np,
                    u,
                    floor: 1e-3,
                    v: Vec::new(),
                    scores: Vec::new(),
                };
                let mut want_rb = vec![u32::MAX; rows.len() * wr];
                sweep_shifts(&lp, &rp, first, np, k, &cells, &mut want_rb, &mut want);
                assert_eq!(got.len(), want.v.len());
                for (n, (g, w)) in got.iter().zip(&want.v).enumerate() {
                    let s = &want.scores[n];
                    let at = format!("k {k} first {first} cell {n}: {g:?} vs {w:?}");
                    // Equal up to the summing order: a different plane only on a near tie.
                    let us = |p: Option<u32>| p.map(|p| p as usize);
                    match (us(g.plane), us(w.plane)) {
                        (Some(a), Some(b)) if a != b => {
                            assert!((s[a] - s[b]).abs() < 1e-5, "{at}");
                            continue;
                        }
                        _ => assert_eq!(g.plane, w.plane, "{at}"),
                    }
                    assert_eq!(g.unseen, w.unseen, "{at}");
                    if let Some(p) = us(g.plane) {
                        assert!((g.rho - w.rho).abs() < 1e-5, "{at}");
                        for (a, b) in [(g.below, w.below), (g.above, w.above)] {
                            assert_eq!(a.is_some(), b.is_some(), "{at}");
                            assert!((a.unwrap_or(0.0) - b.unwrap_or(0.0)).abs() < 1e-5, "{at}");
                        }
                        if g.unique != w.unique {
                            // Only where the test is a near tie.
                            let o = s
                                .iter()
                                .enumerate()
                                .filter(|(q, v)| q.abs_diff(p) > 1 && !v.is_nan())
                                .map(|(_, v)| *v)
                                .fold(f32::NEG_INFINITY, f32::max);
                            let lhs = (1.0 - o + 1e-3) * (1.0 - u);
                            assert!((lhs - (1.0 - s[p] + 1e-3)).abs() < 1e-5, "{at}");
                        }
                        compared += 1;
                    }
                }
                // The score of right column x on plane q: the cell at x + first + q.
                let score_at = |j: usize, x: usize, q: u32| {
                    let i = x as i64 + first + q as i64 - k as i64;
                    want.scores[j * cols + i as usize][q as usize]
                };
                for (n, (&g, &w)) in got_rb.iter().zip(&want_rb).enumerate() {
                    let at = format!("k {k} first {first} right {n}: {g} vs {w}");
                    assert_eq!(g == u32::MAX, w == u32::MAX, "{at}");
                    if g != w {
                        // Only a near tie between two cells' scores.
                        let (j, x) = (n / wr, n % wr);
                        assert!((score_at(j, x, g) - score_at(j, x, w)).abs() < 1e-5, "{at}");
                    }
                }
            }
        }
        assert!(compared > 3000, "{compared} winners compared");
    }
}
