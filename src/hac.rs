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
    covariance(h, psi, h, psi, inside, n, lag, dof)
}

/// The cross term of two series observed at the same pixels (two photos' residuals against
/// one template, whose own noise they share): Σᵢ Σⱼ aᵢ bⱼ C_ab(i − j), C_ab the
/// cross-covariance of `psi_a` and `psi_b` at lags up to `lag`, Bartlett-weighted, times
/// `dof`. With a = b it is [`variance`]; the sum over both orders of two series is the
/// covariance their estimates share (negative where it cancels).
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
) -> [f64; K] {
    let l = lag.min(n.saturating_sub(1)) as i64;
    let n_i = n as i64;
    let mut total = [0.0; K];
    // Most windows lie wholly inside: then no pixel need be asked (the same sums).
    let all = inside.iter().all(|&b| b);
    for dy in -l..=l {
        for dx in -l..=l {
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

#[cfg(test)]
mod tests {
    /// White residuals: only lag 0 counts on average, so the variance tends to Σ hᵢ² σ²
    /// (the normal matrix's own answer); with the same residual in pairs of neighbours
    /// (correlation at lag 1 in x) it is larger.
    #[test]
    fn white_residuals_give_the_classical_variance_and_correlated_ones_more() {
        let n = 16;
        let mut state = 12345u64;
        let mut r = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
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
