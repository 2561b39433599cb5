//! Block matching's winners on a rectified pair, plane by plane. The disparity sweep of
//! [`super::plane_sweep::sweep_shifts`] keeps each cell's planes together (SGM needs them so,
//! for its volume), and so pays per cell for the window's columns, the plane range, the winner
//! and the right photo's winners. Here the planes are the outer loop: for one disparity the
//! column sums of Σl·w are moved down a row in one pass along the row, and the window sums,
//! correlations, the cells' winners and the right photo's winners in a second, on vector
//! lanes. The scores are the same correlations (summed in another order, so equal to a few
//! units in the last place) and the winners follow the same rules
//! ([`super::winner::winner`] with [`super::winner::Unseen::Skip`], the first of equal scores).

use super::plane_sweep::{Prepared, RowStats};
use super::winner::{stands_out, RowPicks};

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
    /// The winners of `rows` (ascending; consecutive rows reuse the column sums), one row at
    /// a time to `sink` (so that no band of picks is kept): the picks of cells
    /// c = k … wl − k − 1 of the left photo, and, with `right_winners`, the right photo's
    /// winner for each of its columns (u32::MAX where none). Built per CPU (see `simd`).
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
    let n = (w * w) as f32;
    let mut picks = RowPicks::default();
    let mut rbs = vec![u32::MAX; if bp.right_winners { wr } else { 0 }];
    if cols == 0 || np == 0 {
        return;
    }
    let want_unique = bp.uniqueness > 0.0;
    // Column sums of Σl·w: plane p, left column c at [p·wl + c].
    let mut v = vec![0.0f32; np * wl];
    let (mut lst, mut rst) = (RowStats::new(wl), RowStats::new(wr));
    let (mut ml, mut il) = (vec![0.0f32; cols], vec![0.0f32; cols]);
    let (mut rm, mut ri) = (vec![0.0f32; wr], vec![0.0f32; wr]);
    let (mut best, mut at) = (vec![f32::NEG_INFINITY; cols], vec![0u32; cols]);
    // Every plane's scores of the row: plane p, cell i at [p·cols + i] (NaN: unseen), for
    // the winners' neighbours and the uniqueness test.
    let mut all = vec![f32::NAN; np * cols];
    // (−∞ throughout without the test: every winner stands out.)
    let mut other = vec![f32::NEG_INFINITY; cols];
    let (mut rbest, mut rat) = (vec![f32::NEG_INFINITY; wr], vec![0u32; wr]);
    let mut last: Option<usize> = None;
    // Window sums and their doubling levels for windows above 9.
    let (mut hsum, mut lv, mut lv2) = (vec![0.0f32; cols], Vec::new(), Vec::new());
    for (j, &r) in rows.iter().enumerate() {
        if r + k >= hr || r < k {
            // The right photo has no such rows: nothing is seen.
            picks.unseen(cols);
            rbs.fill(u32::MAX);
            sink.row(j, &picks, &rbs);
            last = None;
            continue;
        }
        let fresh = last.is_none_or(|q| q + 1 != r);
        if fresh {
            v.fill(0.0);
        }
        last = Some(r);
        lst.fill(left, r, k);
        rst.fill(right, r, k);
        for (i, (m, q)) in ml.iter_mut().zip(&mut il).enumerate() {
            let inv = lst.inv[k + i];
            *m = lst.mean[k + i];
            *q = if inv > 0.0 { inv } else { f32::NAN };
        }
        for (x, (m, q)) in rm.iter_mut().zip(&mut ri).enumerate() {
            *m = rst.mean[x] * n;
            *q = rst.inv[x];
        }
        best.fill(f32::NEG_INFINITY);
        at.fill(0);
        rbest.fill(f32::NEG_INFINITY);
        rat.fill(0);
        for p in 0..np {
            // Left column c meets right column c − s.
            let s = first + p as i64;
            let clamp = |x: i64, hi: usize| x.clamp(0, hi as i64) as usize;
            // The column sums that meet the right photo: c in [s, s + wr).
            let (c0, c1) = (clamp(s, wl), clamp(s + wr as i64, wl));
            if c0 < c1 {
                let x0 = (c0 as i64 - s) as usize;
                let len = c1 - c0;
                let vp = &mut v[p * wl + c0..p * wl + c1];
                if fresh {
                    for rr in r - k..=r + k {
                        add_row(vp, &row(left, rr)[c0..c1], &row(right, rr)[x0..x0 + len]);
                    }
                } else {
                    let (r_in, r_out) = (r + k, r - k - 1);
                    move_row(
                        vp,
                        &row(left, r_in)[c0..c1],
                        &row(right, r_in)[x0..x0 + len],
                        &row(left, r_out)[c0..c1],
                        &row(right, r_out)[x0..x0 + len],
                    );
                }
            }
            // The cells whose window the right photo holds: cell i (column k + i) in
            // [s, s + wr − 2k); right window centre x = i + k − s.
            let (i0, i1) = (clamp(s, cols), clamp(s + wr as i64 - 2 * k as i64, cols));
            let i1 = i1.max(i0);
            let out = &mut all[p * cols..(p + 1) * cols];
            out[..i0].fill(f32::NAN);
            out[i1..].fill(f32::NAN);
            if i0 == i1 {
                continue;
            }
            let xs = (i0 as i64 + k as i64 - s) as usize;
            let x1 = xs + (i1 - i0);
            let vs = &v[p * wl + i0..p * wl + i1 + 2 * k];
            let (rbs_, rats) = (&mut rbest[xs..x1], &mut rat[xs..x1]);
            let (ms, is, rms, ris) = (&ml[i0..i1], &il[i0..i1], &rm[xs..x1], &ri[xs..x1]);
            let (o, b, a) = (&mut out[i0..i1], &mut best[i0..i1], &mut at[i0..i1]);
            let pu = p as u32;
            macro_rules! pass {
                ($w:expr, $vs:expr) => {
                    if bp.right_winners {
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
                others(&mut other, &all[p * cols..(p + 1) * cols], &at, p as u32);
            }
        }
        take_picks(&mut picks, &best, &at, &il, &all, &other, np, bp);
        if bp.right_winners {
            for ((o, &a), &b) in rbs.iter_mut().zip(&rat).zip(&rbest) {
                *o = if b > f32::NEG_INFINITY { a } else { u32::MAX };
            }
        }
        sink.row(j, &picks, &rbs);
    }
}

/// A row's picks from its cells' best scores `best` at planes `at`, the left windows'
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
    best: &[f32],
    at: &[u32],
    il: &[f32],
    all: &[f32],
    other: &[f32],
    np: usize,
    bp: &BlockParams,
) {
    let cols = best.len();
    pk.clear();
    pk.plane.resize(cols, RowPicks::NONE);
    for v in [&mut pk.rho, &mut pk.below, &mut pk.above, &mut pk.offset] {
        v.resize(cols, f32::NAN);
    }
    pk.unique.resize(cols, true);
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
        pk.plane[i] = if has { pl as u32 } else { RowPicks::NONE };
        pk.rho[i] = if unscored {
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
        pk.below[i] = fin(lo);
        pk.above[i] = fin(hi);
        pk.unique[i] = !has || stands_out(b, other[i], bp.uniqueness, bp.floor, |v| 1.0 - v);
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
    use crate::matching::plane_sweep::{sweep_shifts, CellSink, Cells};
    use crate::matching::winner::{unique, winner, Pick, Unseen};

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
        for (seed, wl, wr, h) in [(1u64, 70usize, 60usize, 26usize), (2, 50, 50, 22)] {
            let (l, r) = pair(seed, wl, wr, h);
            let (lp, rp) = (Prepared::new(&l), Prepared::new(&r));
            for (k, first, np, u) in [
                (2usize, 0i64, 16usize, 0.1f32),
                (1, -5, 24, 0.0),
                (3, 4, 9, 0.3),
                (5, -20, 40, 0.1),
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
