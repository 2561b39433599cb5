//! The variance of a least-squares estimate without assuming white residuals (the
//! Newey–West estimator, Bartlett-tapered): every observation's influence on the estimate
//! against the residuals' own autocovariance. Resampling, a template a little unlike the
//! picture, or terrain within a patch leave residuals correlated over a few pixels; the
//! normal matrix alone then reads them as independent and is too sure of itself.

/// Σᵢ Σⱼ hᵢ hⱼ C(i − j) for each of the `K` estimates' influences `h` over an n×n window
/// (row-major, `inside` marking the pixels used), C the autocovariance of `psi` at lags up to
/// `lag` in each direction with Bartlett weights, times `dof` (n / (n − u)).
pub fn variance<const K: usize>(
    h: [&[f64]; K],
    psi: &[f64],
    inside: &[bool],
    n: usize,
    lag: usize,
    dof: f64,
) -> [f64; K] {
    // A series against itself: lag −d takes the products of lag d, in the same order (each
    // pair the other way round), so half the lags give them all.
    let s = Series { h, psi };
    Lags::new(s, s, inside, n, lag, true).total(false, dof)
}

/// The cross term of two series observed at the same pixels (two photos' residuals against
/// one template, whose own noise they share): Σᵢ Σⱼ aᵢ bⱼ C_ab(i − j), C_ab the
/// cross-covariance of `psi_a` and `psi_b` at lags up to `lag`, Bartlett-weighted, times
/// `dof`; and the same of b with a. Both from one pass over the lags: C_ba at lag −d is C_ab
/// at d, the same products in the same order, so each is the number a pass of its own would
/// give, to the bit. With a = b it is [`variance`]; the sum over both orders of two series is
/// the covariance their estimates share (negative where it cancels).
#[allow(clippy::too_many_arguments)]
pub fn covariance<const K: usize>(
    h_a: [&[f64]; K],
    psi_a: &[f64],
    h_b: [&[f64]; K],
    psi_b: &[f64],
    inside: &[bool],
    n: usize,
    lag: usize,
    dof: f64,
) -> ([f64; K], [f64; K]) {
    let (a, b) = (Series { h: h_a, psi: psi_a }, Series { h: h_b, psi: psi_b });
    let t = Lags::new(a, b, inside, n, lag, false);
    (t.total(false, dof), t.total(true, dof))
}

/// One series over the window: the estimates' influences and the residuals.
#[derive(Clone, Copy)]
struct Series<'a, const K: usize> {
    h: [&'a [f64]; K],
    psi: &'a [f64],
}

/// Per lag (dy, dx), row-major from (−l, −l): Σ ψ_a·ψ_b over the pairs, their number, and
/// Σ h_a·h_b for each estimate.
struct Lags<const K: usize> {
    l: i64,
    sums: Vec<(f64, usize, [f64; K])>,
}

impl<const K: usize> Lags<K> {
    /// `mirror`: the two series are one, so the second half of the lags is the first's.
    fn new(
        a: Series<'_, K>,
        b: Series<'_, K>,
        inside: &[bool],
        n: usize,
        lag: usize,
        mirror: bool,
    ) -> Lags<K> {
        let (h_a, psi_a, h_b, psi_b) = (a.h, a.psi, b.h, b.psi);
        let l = lag.min(n.saturating_sub(1)) as i64;
        let n_i = n as i64;
        let side = (2 * l + 1) as usize;
        let mut sums = vec![(0.0, 0usize, [0.0; K]); side * side];
        // Most windows lie wholly inside: then no pixel need be asked (the same sums).
        let all = inside.iter().all(|&b| b);
        for dy in -l..=l {
            for dx in -l..=l {
                let at = ((dy + l) as usize) * side + (dx + l) as usize;
                if mirror && (dy, dx) > (0, 0) {
                    sums[at] = sums[side * side - 1 - at];
                    continue;
                }
                let (mut cov, mut pairs, mut hh) = (0.0, 0usize, [0.0; K]);
                for y in 0.max(-dy)..n_i.min(n_i - dy) {
                    for x in 0.max(-dx)..n_i.min(n_i - dx) {
                        let i = (y * n_i + x) as usize;
                        let j = ((y + dy) * n_i + x + dx) as usize;
                        if all || (inside[i] && inside[j]) {
                            cov += psi_a[i] * psi_b[j];
                            pairs += 1;
                            for a in 0..K {
                                hh[a] += h_a[a][i] * h_b[a][j];
                            }
                        }
                    }
                }
                sums[at] = (cov, pairs, hh);
            }
        }
        Lags { l, sums }
    }

    /// The Bartlett-weighted sum over the lags in their order, times `dof`; `reversed`: of
    /// the series the other way round (lag d read at −d).
    fn total(&self, reversed: bool, dof: f64) -> [f64; K] {
        let l = self.l;
        let side = (2 * l + 1) as usize;
        let mut total = [0.0; K];
        for dy in -l..=l {
            for dx in -l..=l {
                let at = ((dy + l) as usize) * side + (dx + l) as usize;
                let (cov, pairs, hh) = self.sums[if reversed { side * side - 1 - at } else { at }];
                if pairs > 0 {
                    let bartlett = (1.0 - dx.abs() as f64 / (l + 1) as f64)
                        * (1.0 - dy.abs() as f64 / (l + 1) as f64);
                    for a in 0..K {
                        total[a] += bartlett * hh[a] * cov / pairs as f64;
                    }
                }
            }
        }
        total.map(|t| t * dof)
    }
}

#[cfg(test)]
mod tests {
    /// Uniform numbers in [−½, ½) from `seed`.
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut u = crate::test_rng::uniform(seed);
        move || u() - 0.5
    }

    /// The mirrored lags give each number a direct pass over every lag gives, to the bit: a
    /// series against itself, and two series both ways round, with pixels left out.
    #[test]
    fn mirrored_lags_are_the_direct_sums_to_the_bit() {
        let n = 11;
        let mut r = uniform(99);
        let mut series = || -> Vec<f64> { (0..n * n).map(|_| r()).collect() };
        let (pa, pb, ha, hb) = (series(), series(), series(), series());
        for inside in [
            vec![true; n * n],
            (0..n * n).map(|i| i % 7 != 3 && i / n != 4).collect(),
        ] {
            for lag in [0, 1, 3] {
                let direct = |h_a: &[f64], p_a: &[f64], h_b: &[f64], p_b: &[f64]| {
                    let l = lag as i64;
                    let mut total = 0.0;
                    for dy in -l..=l {
                        for dx in -l..=l {
                            let (mut cov, mut pairs, mut hh) = (0.0, 0usize, 0.0);
                            for y in 0.max(-dy)..(n as i64).min(n as i64 - dy) {
                                for x in 0.max(-dx)..(n as i64).min(n as i64 - dx) {
                                    let i = (y * n as i64 + x) as usize;
                                    let j = ((y + dy) * n as i64 + x + dx) as usize;
                                    if inside[i] && inside[j] {
                                        cov += p_a[i] * p_b[j];
                                        pairs += 1;
                                        hh += h_a[i] * h_b[j];
                                    }
                                }
                            }
                            if pairs > 0 {
                                let w = (1.0 - dx.abs() as f64 / (l + 1) as f64)
                                    * (1.0 - dy.abs() as f64 / (l + 1) as f64);
                                total += w * hh * cov / pairs as f64;
                            }
                        }
                    }
                    total * 1.3
                };
                let [v] = super::variance([&ha], &pa, &inside, n, lag, 1.3);
                assert_eq!(v.to_bits(), direct(&ha, &pa, &ha, &pa).to_bits());
                let ([ab], [ba]) = super::covariance([&ha], &pa, [&hb], &pb, &inside, n, lag, 1.3);
                assert_eq!(ab.to_bits(), direct(&ha, &pa, &hb, &pb).to_bits());
                assert_eq!(ba.to_bits(), direct(&hb, &pb, &ha, &pa).to_bits());
                let ([self_ab], _) =
                    super::covariance([&ha], &pa, [&ha], &pa, &inside, n, lag, 1.3);
                assert_eq!(self_ab.to_bits(), v.to_bits());
            }
        }
    }

    /// White residuals: only lag 0 counts on average, so the variance tends to Σ hᵢ² σ²
    /// (the normal matrix's own answer); with the same residual in pairs of neighbours
    /// (correlation at lag 1 in x) it is larger.
    #[test]
    fn white_residuals_give_the_classical_variance_and_correlated_ones_more() {
        let n = 16;
        let mut r = uniform(12345);
        let psi: Vec<f64> = (0..n * n).map(|_| r()).collect();
        let h = vec![1.0; n * n];
        let inside = vec![true; n * n];
        let s2 = psi.iter().map(|v| v * v).sum::<f64>() / (n * n) as f64;
        let [white] = super::variance([&h], &psi, &inside, n, 0, 1.0);
        assert!((white - (n * n) as f64 * s2).abs() < 1e-9 * white);
        let [lagged] = super::variance([&h], &psi, &inside, n, 3, 1.0);
        assert!((lagged / white - 1.0).abs() < 0.5, "{lagged} vs {white}");
        let pairs: Vec<f64> = (0..n * n).map(|i| psi[i - i % 2]).collect();
        let [w2] = super::variance([&h], &pairs, &inside, n, 0, 1.0);
        let [c2] = super::variance([&h], &pairs, &inside, n, 3, 1.0);
        assert!(c2 > 1.4 * w2, "{c2} vs {w2}");
    }
}
