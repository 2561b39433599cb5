//! Semi-global aggregation (Hirschmüller 2008, eq. 13–14) of a plane sweep's scores: for
//! each path direction r, L_r(p, d) = C(p, d) + min(L_r(p − r, d), L_r(p − r, d ± 1) + P1,
//! min_i L_r(p − r, i) + P2) − min_k L_r(p − r, k), and S(p, d) = Σ_r L_r(p, d). The cost is
//! C = (1 − NCC)·COST_SCALE; a plane the search photo does not see, or could not score, costs
//! as much as an uncorrelated window, so it neither attracts nor repels the paths.
//!
//! Two ways, by the number of paths:
//! - **5 paths, streamed** ([`Streamed`]): the paths along the row both ways and the three that
//!   come from the row before (diagonal behind, straight, diagonal ahead), in one pass over
//!   the rows with nothing kept but the last row's path costs: OpenCV's StereoSGBM is such a
//!   single pass over 5 directions by default (its documentation), where Hirschmüller (2008,
//!   §2.3) asks for at least 8 for a good coverage. The photo is matched in two halves
//!   on two threads, the upper from the top edge down and the lower from the bottom edge up, so
//!   that every path starts at the photo's edge.
//! - **8 paths** ([`aggregate_halves`]): two sweeps over a whole volume of scores, the first
//!   carrying the paths that come from the left, above-left, above and above-right, the second
//!   the four opposite ones.

use serde::{Deserialize, Serialize};

/// Cost of a score: NCC 1 → 0, NCC 0 → COST_SCALE, NCC −1 → 2·COST_SCALE.
pub const COST_SCALE: f32 = 256.0;

/// The penalties, in cost units (COST_SCALE is an NCC of 0), and the paths.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SgmParams {
    /// For a change of one plane between neighbours (slanted surfaces).
    pub p1: u16,
    /// For a larger change (discontinuities).
    pub p2: u16,
    /// 5 (streamed, no volume kept) or 8 (two sweeps over the whole volume).
    pub paths: u8,
}

/// The path counts there are.
pub const PATHS: [u8; 2] = [5, 8];

impl Default for SgmParams {
    fn default() -> Self {
        // An NCC of 0.75 against 1.0 costs 64: a change of one plane is paid like that, a
        // jump like two uncorrelated windows (chosen on the benchmark's rendered pair, where
        // P1 from 16 to 64 and P2 from 96 to 768 moved bad-2 between 2 % and 3 %).
        SgmParams {
            p1: 64,
            p2: 512,
            paths: 5,
        }
    }
}

/// A score in 16 bits for the volume that aggregation keeps: NCC·16384 (a step of 6·10⁻⁵,
/// far below a window's noise), with codes for unseen (NaN) and unscored (−∞) planes. Half
/// the memory of f32, and read twice (the two sweeps) and once more for the winners.
pub const Q_ONE: i32 = 16384;
pub const Q_UNSEEN: i16 = i16::MIN;
pub const Q_UNSCORED: i16 = i16::MIN + 1;

/// The 16-bit code of a score (NCC within −1…1, NaN, or −∞).
#[inline]
pub fn quantise(s: f32) -> i16 {
    // Truncation of a positive number (no libm round), and selects, not branches, so that
    // it runs on vector lanes.
    let q = ((s.clamp(-1.0, 1.0) * Q_ONE as f32 + (Q_ONE as f32 + 0.5)) as i32 - Q_ONE) as i16;
    let q = if s == f32::NEG_INFINITY {
        Q_UNSCORED
    } else {
        q
    };
    if s.is_nan() {
        Q_UNSEEN
    } else {
        q
    }
}

/// The score a code stands for.
#[inline]
pub fn dequantise(q: i16) -> f32 {
    match q {
        Q_UNSEEN => f32::NAN,
        Q_UNSCORED => f32::NEG_INFINITY,
        _ => q as f32 / Q_ONE as f32,
    }
}

/// Cost of a code: round((1 − NCC)·COST_SCALE); unseen and unscored planes cost COST_SCALE.
#[inline]
fn cost(q: i16) -> u16 {
    const SHIFT: u32 = (Q_ONE / COST_SCALE as i32).trailing_zeros();
    let c = ((Q_ONE - q as i32 + (1 << (SHIFT - 1))) >> SHIFT) as u16;
    if q <= Q_UNSCORED {
        COST_SCALE as u16
    } else {
        c
    }
}

/// Cost of a score (an NCC, NaN unseen, −∞ unscored), as [`cost`] gives it for the score's
/// code: round((1 − NCC)·COST_SCALE), COST_SCALE where not scored. Selects, not branches, so
/// that a row's costs are taken on vector lanes.
#[inline(always)]
pub fn cost_of(s: f32) -> u16 {
    // An unscored or unseen plane as an NCC of 0; then within −1 … 1, so that the cost is
    // within 0.5 … 512.5 before it is cut to a whole number.
    let v = if s.is_finite() { s } else { 0.0 };
    let x = (1.0 - v.clamp(-1.0, 1.0)) * COST_SCALE + 0.5;
    // SAFETY: x is finite and within 0.5 … 512.5, which i32 holds: the conversion is exact
    // truncation, one instruction a lane (`as` would add the fix-ups for NaN and overflow,
    // a fifth of the aggregation's time).
    (unsafe { x.to_int_unchecked::<i32>() }) as u16
}

/// Lanes of a vector of u16 (AVX2): [`Streamed`] keeps each cell's planes padded to a
/// multiple, so that a step is whole vectors whatever the number of planes (a search of ±2
/// planes, as the σ's self-match has, would otherwise run one lane at a time).
const LANES: usize = 16;

/// The cost of a padding plane, and the path cost it keeps: never a path's minimum, never a
/// neighbour's way in (a saturating add leaves it where it is).
const PAD: u16 = u16::MAX;

/// Bytes [`Streamed`] holds for rows `cols` wide of `planes`: the path costs of the row before
/// and of this one (three paths), the row's costs and its sums, padded (see [`LANES`]).
pub fn streamed_bytes(cols: f64, planes: f64) -> f64 {
    let padded = (planes / LANES as f64).ceil() * LANES as f64;
    (6.0 * (padded + 2.0) + 2.0 * padded) * cols * 2.0 + 6.0 * cols * 2.0
}

/// Semi-global aggregation along five paths in one pass over the rows (see the module's
/// doc): give it each row's scores in the order of travel, and it gives back the row's S. It
/// keeps the three paths' costs of the row before and nothing else. Each cell's planes lie
/// [`Streamed::stride`] apart in the sums, the planes beyond the real ones padding; a path's
/// costs are kept with a padding plane either side as well (a slot of stride + 2), so that a
/// step reads the neighbours below and above as whole vectors, without a copy.
pub struct Streamed {
    np: usize,
    stride: usize,
    cols: usize,
    p: SgmParams,
    /// Path costs of the row before and of this one (diagonal behind, straight, diagonal
    /// ahead) in slots, and each cell's minimum over its planes.
    prev: [Vec<u16>; 3],
    cur: [Vec<u16>; 3],
    prev_min: [Vec<u16>; 3],
    cur_min: [Vec<u16>; 3],
    /// The path along the row: this cell's slot and the one before.
    along: Vec<u16>,
    along_prev: Vec<u16>,
    started: bool,
    cost: Vec<u16>,
    sum: Vec<u16>,
    /// The two paths along the row alone (see [`Streamed::row`]).
    along_sum: Vec<u16>,
}

impl Streamed {
    pub fn new(cols: usize, np: usize, p: &SgmParams) -> Streamed {
        let stride = np.div_ceil(LANES).max(1) * LANES;
        let slots = || vec![PAD; cols * (stride + 2)];
        let mins = || vec![0u16; cols];
        Streamed {
            np,
            stride,
            cols,
            p: *p,
            prev: [slots(), slots(), slots()],
            cur: [slots(), slots(), slots()],
            prev_min: [mins(), mins(), mins()],
            cur_min: [mins(), mins(), mins()],
            along: vec![PAD; stride + 2],
            along_prev: vec![PAD; stride + 2],
            started: false,
            cost: vec![PAD; cols * stride],
            sum: vec![PAD; cols * stride],
            along_sum: vec![PAD; cols * stride],
        }
    }

    /// How far apart the cells' planes lie in [`Streamed::row`]'s sums.
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// The sums S of the next row (cell i's plane p at `i·stride + p`) from its scores
    /// `scores[i·planes + p]` (an NCC, NaN unseen, −∞ unscored; columns left to right), and
    /// the sums of the two paths along the row alone. Those two come from both sides, so that
    /// their pull towards the neighbours' disparities cancels: the sub-plane place is taken
    /// on them (the three paths from the row before all come from one side, and on a surface
    /// that slopes down the photo they pull the place one way: on the benchmark pair's roof
    /// the sub-pixel RMSE was 0.27 px on S against 0.18 px with 8 paths).
    pub fn row(&mut self, scores: &[f32]) -> (&[u16], &[u16]) {
        stream_row(self, scores);
        (&self.sum, &self.along_sum)
    }
}

built_per_cpu! {
    /// One row of [`Streamed`]: the costs, the paths along the row forward and the three
    /// from the row before, then the path along the row backward. Built per CPU (see `simd`).
    fn stream_row[](s: &mut Streamed, scores: &[f32]) = stream_row_body;
}

/// One step of a path on padded planes: the slot `out` (this cell's path costs between a
/// padding plane either side) from the predecessor's slot `prev` (`m` the minimum of its
/// costs) and this cell's costs `c`; returns the minimum of the costs written.
#[inline(always)]
fn padded_step(c: &[u16], prev: Option<(&[u16], u16)>, p1: u16, p2: u16, out: &mut [u16]) -> u16 {
    let n = c.len();
    let out = &mut out[1..n + 1];
    let Some((prev, m)) = prev else {
        out.copy_from_slice(c);
        return c.iter().fold(u16::MAX, |a, &b| a.min(b));
    };
    let jump = m.saturating_add(p2);
    let mut low = u16::MAX;
    for ((((o, &cc), &here), &below), &above) in out
        .iter_mut()
        .zip(c)
        .zip(&prev[1..n + 1])
        .zip(&prev[..n])
        .zip(&prev[2..n + 2])
    {
        let v = here
            .min(below.saturating_add(p1))
            .min(above.saturating_add(p1))
            .min(jump);
        let x = cc.saturating_add(v - m);
        *o = x;
        low = low.min(x);
    }
    low
}

#[inline(always)]
fn stream_row_body(s: &mut Streamed, scores: &[f32]) {
    let (np, st, cols) = (s.np, s.stride, s.cols);
    let g = st + 2;
    let (p1, p2) = (s.p.p1, s.p.p2);
    if np == 0 || scores.len() != cols * np {
        return;
    }
    for i in 0..cols {
        for (c, &v) in s.cost[i * st..i * st + np]
            .iter_mut()
            .zip(&scores[i * np..(i + 1) * np])
        {
            *c = cost_of(v);
        }
    }
    let mut along_min = 0u16;
    for i in 0..cols {
        let cc = &s.cost[i * st..(i + 1) * st];
        along_min = padded_step(
            cc,
            (i > 0).then_some((&s.along_prev[..], along_min)),
            p1,
            p2,
            &mut s.along,
        );
        std::mem::swap(&mut s.along, &mut s.along_prev);
        let dst = &mut s.sum[i * st..(i + 1) * st];
        dst.copy_from_slice(&s.along_prev[1..st + 1]);
        s.along_sum[i * st..(i + 1) * st].copy_from_slice(&s.along_prev[1..st + 1]);
        // From the row before: diagonal behind, straight, diagonal ahead.
        for (k, di) in [-1i64, 0, 1].into_iter().enumerate() {
            let pi = i as i64 + di;
            let prev = (s.started && pi >= 0 && (pi as usize) < cols).then(|| {
                let pi = pi as usize;
                (&s.prev[k][pi * g..(pi + 1) * g], s.prev_min[k][pi])
            });
            let out = &mut s.cur[k][i * g..(i + 1) * g];
            s.cur_min[k][i] = padded_step(cc, prev, p1, p2, out);
            for (d, v) in dst.iter_mut().zip(&out[1..st + 1]) {
                *d = d.saturating_add(*v);
            }
        }
    }
    // Along the row backward.
    for i in (0..cols).rev() {
        let cc = &s.cost[i * st..(i + 1) * st];
        along_min = padded_step(
            cc,
            (i + 1 < cols).then_some((&s.along_prev[..], along_min)),
            p1,
            p2,
            &mut s.along,
        );
        std::mem::swap(&mut s.along, &mut s.along_prev);
        for ((d, h), v) in s.sum[i * st..(i + 1) * st]
            .iter_mut()
            .zip(&mut s.along_sum[i * st..(i + 1) * st])
            .zip(&s.along_prev[1..st + 1])
        {
            *d = d.saturating_add(*v);
            *h = h.saturating_add(*v);
        }
    }
    std::mem::swap(&mut s.prev, &mut s.cur);
    std::mem::swap(&mut s.prev_min, &mut s.cur_min);
    s.started = true;
}

/// Bytes [`aggregate`] needs for a volume of `cells` × `planes` (rows `cols` wide), beside the
/// codes it reads: the two sweeps' sums (u16 each), and 7 rows of path costs.
pub fn bytes_needed(cells: f64, planes: f64, cols: f64) -> f64 {
    cells * planes * 4.0 + 7.0 * cols * planes * 2.0
}

/// One step of a path: `out` from the predecessor's path costs `prev` and this cell's costs.
#[inline(always)]
fn step(c: &[u16], prev: Option<&[u16]>, p1: u16, p2: u16, out: &mut [u16]) {
    let Some(prev) = prev else {
        out.copy_from_slice(c);
        return;
    };
    let n = c.len();
    // A fold, not Iterator::min, so that it runs on vector lanes.
    let m = prev.iter().fold(u16::MAX, |a, &b| a.min(b));
    let jump = m.saturating_add(p2);
    if n == 1 {
        out[0] = c[0].saturating_add(prev[0].min(jump) - m);
        return;
    }
    out[0] = c[0].saturating_add(prev[0].min(prev[1].saturating_add(p1)).min(jump) - m);
    out[n - 1] =
        c[n - 1].saturating_add(prev[n - 1].min(prev[n - 2].saturating_add(p1)).min(jump) - m);
    // The middle without branches, so that it runs on vector lanes.
    for ((((o, &cc), &here), &below), &above) in out[1..n - 1]
        .iter_mut()
        .zip(&c[1..n - 1])
        .zip(&prev[1..n - 1])
        .zip(&prev[..n - 2])
        .zip(&prev[2..])
    {
        let v = here
            .min(below.saturating_add(p1))
            .min(above.saturating_add(p1))
            .min(jump);
        *o = cc.saturating_add(v - m);
    }
}

/// One of the two sweeps: the four paths that come from behind it, summed.
#[inline(always)]
fn sweep(q: &[i16], cols: usize, rows: usize, np: usize, p: &SgmParams, forward: bool) -> Vec<u16> {
    let mut sum: Vec<u16> = crate::matching::plane_sweep::volume::zeroed(q.len());
    let mut cc = vec![0u16; np];
    let at = |i: usize, j: usize| (j * cols + i) * np;
    // Path costs of the previous row for the three paths that come from it (indexed by the
    // position along the sweep's travel), and of the previous cell for the path along the row.
    let mut prev_rows = vec![vec![0u16; cols * np]; 3];
    let mut cur_rows = vec![vec![0u16; cols * np]; 3];
    let mut along_prev = vec![0u16; np];
    let mut along = vec![0u16; np];
    for jj in 0..rows {
        let j = if forward { jj } else { rows - 1 - jj };
        for ii in 0..cols {
            let i = if forward { ii } else { cols - 1 - ii };
            let o = at(i, j);
            for (c, &v) in cc.iter_mut().zip(&q[o..o + np]) {
                *c = cost(v);
            }
            let cc = &cc[..];
            let dst = &mut sum[o..o + np];
            step(
                cc,
                (ii > 0).then_some(&along_prev[..]),
                p.p1,
                p.p2,
                &mut along,
            );
            std::mem::swap(&mut along, &mut along_prev);
            dst.copy_from_slice(&along_prev);
            // From the previous row: diagonal behind, straight, diagonal ahead.
            for (k, di) in [-1i64, 0, 1].into_iter().enumerate() {
                let pi = ii as i64 + di;
                let prev = (jj > 0 && pi >= 0 && (pi as usize) < cols)
                    .then(|| &prev_rows[k][pi as usize * np..(pi as usize + 1) * np]);
                let out = &mut cur_rows[k][ii * np..(ii + 1) * np];
                step(cc, prev, p.p1, p.p2, out);
                for (d, v) in dst.iter_mut().zip(out.iter()) {
                    *d = d.saturating_add(*v);
                }
            }
        }
        std::mem::swap(&mut prev_rows, &mut cur_rows);
    }
    sum
}

/// The aggregated costs S (lower is better) of a volume of score codes ([`quantise`])
/// `[(j·cols + i)·planes + p]`, in the same order.
pub fn aggregate(q: &[i16], cols: usize, rows: usize, np: usize, p: &SgmParams) -> Vec<u16> {
    let (mut a, b) = aggregate_halves(q, cols, rows, np, p);
    for (x, y) in a.iter_mut().zip(&b) {
        *x = x.saturating_add(*y);
    }
    a
}

/// The two sweeps' sums, S = forward + backward, apart (so that a caller who reads S once
/// adds them as it reads, without another pass over the volume). The sweeps run in parallel;
/// each is built per CPU (see `simd`).
pub fn aggregate_halves(
    q: &[i16],
    cols: usize,
    rows: usize,
    np: usize,
    p: &SgmParams,
) -> (Vec<u16>, Vec<u16>) {
    if np == 0 || cols == 0 || rows == 0 || q.len() != cols * rows * np {
        return (vec![0; q.len()], vec![0; q.len()]);
    }
    rayon::join(
        || sweep_dispatch(q, cols, rows, np, p, true),
        || sweep_dispatch(q, cols, rows, np, p, false),
    )
}

built_per_cpu! {
    fn sweep_dispatch[](
        q: &[i16],
        cols: usize,
        rows: usize,
        np: usize,
        p: &SgmParams,
        forward: bool,
    ) -> Vec<u16> = sweep;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A row of cells whose costs favour plane 2 except one cell that favours plane 6 weakly:
    /// aggregation carries the neighbours' plane into it; a cell that favours plane 6 strongly
    /// keeps it (a discontinuity is paid once, P2).
    #[test]
    fn smooths_weak_outliers_and_keeps_strong_evidence() {
        let (cols, rows, np) = (9usize, 5usize, 8usize);
        let mut v = vec![0.0f32; cols * rows * np];
        for j in 0..rows {
            for i in 0..cols {
                for p in 0..np {
                    let want = if i == 4 && j == 2 { 6 } else { 2 };
                    v[(j * cols + i) * np + p] = if p == want {
                        if want == 6 {
                            0.6
                        } else {
                            0.95
                        }
                    } else if p == 2 {
                        0.5
                    } else {
                        0.1
                    };
                }
            }
        }
        let codes = |v: &[f32]| v.iter().map(|&x| quantise(x)).collect::<Vec<i16>>();
        // Penalties below the evidence's cost difference (384 − 3 for the strong cell).
        let pen = SgmParams {
            p1: 24,
            p2: 128,
            paths: 8,
        };
        let sum = aggregate(&codes(&v), cols, rows, np, &pen);
        let best = |i: usize, j: usize| {
            let o = (j * cols + i) * np;
            (0..np).min_by_key(|&p| sum[o + p]).unwrap()
        };
        assert_eq!(best(4, 2), 2, "the weak outlier follows its neighbours");
        assert_eq!(best(0, 0), 2);
        // Strong evidence: plane 6 at 0.99 and plane 2 at −0.5 in the middle cell.
        let mut v2 = v;
        let o = (2 * cols + 4) * np;
        v2[o + 6] = 0.99;
        v2[o + 2] = -0.5;
        let sum2 = aggregate(&codes(&v2), cols, rows, np, &pen);
        let b = (0..np).min_by_key(|&p| sum2[o + p]).unwrap();
        assert_eq!(b, 6, "strong evidence survives");
    }

    /// The 16-bit codes keep a score to 1/32768 and keep NaN and −∞ apart from every score.
    #[test]
    fn codes_keep_scores() {
        for i in -1000..=1000 {
            let s = i as f32 / 1000.0;
            let back = dequantise(quantise(s));
            assert!(
                (back - s).abs() <= 0.5 / Q_ONE as f32 + 1e-7,
                "{s} → {back}"
            );
        }
        assert!(dequantise(quantise(f32::NAN)).is_nan());
        assert_eq!(dequantise(quantise(f32::NEG_INFINITY)), f32::NEG_INFINITY);
        assert_eq!(dequantise(quantise(7.0)), 1.0);
        assert_eq!(dequantise(quantise(-7.0)), -1.0);
    }

    /// Random scores with unseen (NaN) and unscored (−∞) planes among them.
    fn random_scores(n: usize, mut seed: u64) -> Vec<f32> {
        (0..n)
            .map(|_| {
                seed = seed
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                match seed >> 60 {
                    0 => f32::NAN,
                    1 => f32::NEG_INFINITY,
                    _ => ((seed >> 33) as f64 / (1u64 << 31) as f64 * 2.0 - 1.0) as f32,
                }
            })
            .collect()
    }

    /// The plain recurrence of one path (dx, dy) over a whole volume of costs `c`, in u32.
    fn one_path(
        c: &[u32],
        cols: usize,
        rows: usize,
        np: usize,
        p: &SgmParams,
        dx: i64,
        dy: i64,
    ) -> Vec<u32> {
        let mut l = vec![0u32; c.len()];
        let js: Vec<i64> = if dy >= 0 {
            (0..rows as i64).collect()
        } else {
            (0..rows as i64).rev().collect()
        };
        let is: Vec<i64> = if dx >= 0 {
            (0..cols as i64).collect()
        } else {
            (0..cols as i64).rev().collect()
        };
        for &j in &js {
            for &i in &is {
                let o = ((j as usize) * cols + i as usize) * np;
                let (pi, pj) = (i - dx, j - dy);
                if pi < 0 || pj < 0 || pi >= cols as i64 || pj >= rows as i64 {
                    l[o..o + np].copy_from_slice(&c[o..o + np]);
                    continue;
                }
                let q = ((pj as usize) * cols + pi as usize) * np;
                let m = *l[q..q + np].iter().min().unwrap();
                for d in 0..np {
                    let mut best = l[q + d];
                    if d > 0 {
                        best = best.min(l[q + d - 1] + p.p1 as u32);
                    }
                    if d + 1 < np {
                        best = best.min(l[q + d + 1] + p.p1 as u32);
                    }
                    best = best.min(m + p.p2 as u32);
                    l[o + d] = c[o + d] + best - m;
                }
            }
        }
        l
    }

    /// The plain costs: round((1 − NCC)·256), COST_SCALE where not scored.
    fn plain_costs(v: &[f32]) -> Vec<u32> {
        v.iter()
            .map(|&s| {
                if s.is_finite() {
                    ((1.0 - s as f64) * COST_SCALE as f64).round() as u32
                } else {
                    COST_SCALE as u32
                }
            })
            .collect()
    }

    /// The streamed aggregation equals the plain recurrences of its five paths (along the
    /// row both ways, and from the row before: above-left, above, above-right) run on their
    /// own over a whole volume, for plane counts below, at and above a vector's lanes.
    #[test]
    fn streamed_equals_five_separate_paths() {
        for (np, seed) in [(5usize, 3u64), (16, 5), (21, 9), (1, 11)] {
            let (cols, rows) = (9usize, 7usize);
            let v = random_scores(cols * rows * np, seed);
            let p = SgmParams::default();
            let c = plain_costs(&v);
            let mut want = vec![0u32; c.len()];
            for (dx, dy) in [(1i64, 0i64), (-1, 0), (1, 1), (0, 1), (-1, 1)] {
                for (w, x) in want
                    .iter_mut()
                    .zip(one_path(&c, cols, rows, np, &p, dx, dy))
                {
                    *w += x;
                }
            }
            let mut s = Streamed::new(cols, np, &p);
            let st = s.stride();
            assert!(st >= np && st.is_multiple_of(LANES));
            for j in 0..rows {
                let sum = s.row(&v[j * cols * np..(j + 1) * cols * np]).0.to_vec();
                for i in 0..cols {
                    for d in 0..np {
                        let w = want[(j * cols + i) * np + d].min(u16::MAX as u32) as u16;
                        assert_eq!(sum[i * st + d], w, "np {np}: row {j}, cell {i}, plane {d}");
                    }
                }
            }
        }
    }

    /// The two-sweep aggregation equals a plain one that runs each of the 8 paths on its
    /// own over a full volume, on random scores with unseen and flat planes among them.
    #[test]
    fn equals_eight_separate_paths() {
        let (cols, rows, np) = (7usize, 6usize, 5usize);
        let v = random_scores(cols * rows * np, 7);
        let q: Vec<i16> = v.iter().map(|&x| quantise(x)).collect();
        let p = SgmParams::default();
        let got = aggregate(&q, cols, rows, np, &p);
        // The costs the plain way, of the scores the codes stand for.
        let c = plain_costs(&q.iter().map(|&x| dequantise(x)).collect::<Vec<f32>>());
        let mut want = vec![0u32; c.len()];
        for (dx, dy) in [
            (1i64, 0i64),
            (-1, 0),
            (0, 1),
            (0, -1),
            (1, 1),
            (-1, -1),
            (1, -1),
            (-1, 1),
        ] {
            for (w, x) in want
                .iter_mut()
                .zip(one_path(&c, cols, rows, np, &p, dx, dy))
            {
                *w += x;
            }
        }
        let want: Vec<u16> = want
            .iter()
            .map(|&x| x.min(u16::MAX as u32) as u16)
            .collect();
        assert_eq!(got, want);
    }
}
