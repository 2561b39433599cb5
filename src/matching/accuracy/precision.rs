//! How far to trust the matchers' standard deviations: an a-posteriori variance factor from
//! the redundancy of several pairs, as an adjustment scales its normal matrix's precision by
//! σ0. Where two pairs give a height for the same node, their difference has the variance
//! σ_a² + σ_b² if the standard deviations are right; the factor is what they must be
//! multiplied by for that to hold (robustly: from the median of the normalised squared
//! differences, which is 0.455 for a χ² of one degree of freedom).

use crate::matching::grid::ElevationGrid;
use crate::matching::point::MatchedPoint;
use serde::{Deserialize, Serialize};

/// The scale of the standard deviations, and the node comparisons it rests on.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct VarianceFactor {
    pub s0: f64,
    /// Node heights compared between two pairs.
    pub comparisons: usize,
}

/// The fewest comparisons a factor is estimated from.
pub const MIN_COMPARISONS: usize = 50;
/// The most it compares (nodes in order): the median is well known long before, and the work
/// stays bounded for a block of many pairs.
pub const MAX_COMPARISONS: usize = 1_000_000;

/// The variance factor from each pair's points on `grid`'s nodes; `None` with fewer than
/// [`MIN_COMPARISONS`] nodes seen by two pairs (a single pair has no redundancy). Pairs that
/// share a photo share its errors, which their difference cannot show: the factor is then a
/// lower bound. Memory grows with the nodes each pair fills, not with the grid.
pub fn variance_factor(grid: &ElevationGrid, pairs: &[&[MatchedPoint]]) -> Option<VarianceFactor> {
    // Per node: each pair's mean height and mean σ² there.
    let mut per_node: std::collections::BTreeMap<usize, Vec<(f64, f64)>> = Default::default();
    for pts in pairs {
        let mut acc: std::collections::BTreeMap<usize, (f64, u32, f64, u32)> = Default::default();
        for p in pts.iter() {
            let g = p.ground;
            let Some(i) = grid.node_index(g.x, g.y).filter(|_| g.z.is_finite()) else {
                continue;
            };
            let a = acc.entry(i).or_default();
            a.0 += g.z;
            a.1 += 1;
            if p.sigma_m.is_finite() {
                a.2 += (p.sigma_m as f64).powi(2);
                a.3 += 1;
            }
        }
        for (i, (sz, nz, ss, ns)) in acc {
            if ns > 0 {
                per_node
                    .entry(i)
                    .or_default()
                    .push((sz / nz as f64, ss / ns as f64));
            }
        }
    }
    let mut r = Vec::new();
    'nodes: for v in per_node.values() {
        for a in 0..v.len() {
            for b in a + 1..v.len() {
                let var = v[a].1 + v[b].1;
                let d = v[a].0 - v[b].0;
                if d.is_finite() && var.is_finite() && var > 0.0 {
                    r.push(d * d / var);
                    if r.len() >= MAX_COMPARISONS {
                        break 'nodes;
                    }
                }
            }
        }
    }
    if r.len() < MIN_COMPARISONS {
        return None;
    }
    r.sort_by(f64::total_cmp);
    let median = r[r.len() / 2];
    Some(VarianceFactor {
        s0: (median / 0.454_936).sqrt(),
        comparisons: r.len(),
    })
}

/// Standard deviations against true errors: how far the error bars can be trusted.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SigmaCheck {
    pub points: usize,
    pub rmse_m: f64,
    pub rms_sigma_m: f64,
    /// RMSE / RMS σ: 1 when the standard deviations are right, above 1 when too small.
    pub ratio: f64,
    /// Share of errors within 2σ, %: 95.4 for right normal errors.
    pub within_2_sigma_percent: f64,
}

/// Compares errors with their standard deviations (pairs with a non-finite member skipped).
pub fn check_sigma(pairs: impl IntoIterator<Item = (f64, f64)>) -> Option<SigmaCheck> {
    let (mut n, mut ee, mut ss, mut inside) = (0usize, 0.0, 0.0, 0usize);
    for (e, s) in pairs {
        if !(e.is_finite() && s.is_finite()) || s <= 0.0 {
            continue;
        }
        n += 1;
        ee += e * e;
        ss += s * s;
        inside += usize::from(e.abs() <= 2.0 * s);
    }
    (n > 0).then(|| {
        let (rmse, rms) = ((ee / n as f64).sqrt(), (ss / n as f64).sqrt());
        SigmaCheck {
            points: n,
            rmse_m: rmse,
            rms_sigma_m: rms,
            ratio: rmse / rms,
            within_2_sigma_percent: 100.0 * inside as f64 / n as f64,
        }
    })
}

/// `sigma` (one per node of `grid`) against the differences from `reference`, node by node.
pub fn sigma_vs_reference(
    grid: &ElevationGrid,
    sigma: &[f32],
    reference: &ElevationGrid,
) -> Option<SigmaCheck> {
    let d = grid.differences(|x, y| reference.interpolate(x, y));
    check_sigma(d.iter().zip(sigma).map(|(&e, &s)| (e as f64, s as f64)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coords::GroundM;

    /// Two pairs whose heights scatter with a known standard deviation 3 times the stated one:
    /// the factor comes out near 3.
    #[test]
    fn the_factor_is_the_ratio_of_true_to_stated_scatter() {
        let grid = ElevationGrid::covering([0.0, 0.0, 99.0, 99.0], 1.0, 64).unwrap();
        // A deterministic normal-ish sequence (sum of 12 uniforms − 6).
        let mut state = 12345u64;
        let mut gauss = || {
            let mut s = 0.0;
            for _ in 0..12 {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                s += (state >> 11) as f64 / (1u64 << 53) as f64;
            }
            s - 6.0
        };
        let (stated, truth) = (0.1f32, 0.3);
        let mut pairs = [Vec::new(), Vec::new()];
        for r in 0..100 {
            for c in 0..100 {
                for p in pairs.iter_mut() {
                    p.push(MatchedPoint {
                        ground: GroundM::new(c as f64, r as f64, 500.0 + truth * gauss()),
                        corr: 0.9,
                        sigma_m: stated,
                    });
                }
            }
        }
        let refs: Vec<&[MatchedPoint]> = pairs.iter().map(|p| p.as_slice()).collect();
        let f = variance_factor(&grid, &refs).unwrap();
        assert_eq!(f.comparisons, 10_000);
        assert!((f.s0 - 3.0).abs() < 0.15, "{f:?}");
        // One pair: nothing to compare.
        assert!(variance_factor(&grid, &refs[..1]).is_none());
    }
}
