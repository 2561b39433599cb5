//! Seed 001's feature route to a coarse DEM (3.2): along a pair of conjugate (epipolar)
//! lines, the edges of the intensity profiles (zero crossings of the second derivative after
//! a gradient filter, c), each with a property list (position, polarity, amplitude, contrast
//! across it and width of its slope, d), matched as strings: each feature's cheapest partner
//! by a weighted cost of the properties (e), kept only when the choice is mutual, left to
//! right and right to left (f), and the pairs then kept in order along the line (a string
//! does not cross itself). A property list tolerates what defeats correlation: a long base
//! that changes the texture's look, weak texture with a few strong edges, a gain between the
//! photos.

use serde::{Deserialize, Serialize};

/// An edge along a profile and its properties.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Edge {
    /// Position along the line, px (sub-pixel: the gradient's peak by a parabola through
    /// three samples).
    pub at: f64,
    /// +1 rising, −1 falling.
    pub polarity: i8,
    /// The smoothed gradient at the peak, grey values per px.
    pub amplitude: f64,
    /// Grey values from one side of the edge to the other (±2σ of the smoothing).
    pub contrast: f64,
    /// Width of the gradient's peak at half its height, px.
    pub width: f64,
}

/// How edges are found.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EdgeParams {
    /// σ of the Gaussian smoothing before the gradient, px.
    pub sigma_px: f64,
    /// Edges weaker than this (smoothed gradient, grey values per px) are noise.
    pub min_amplitude: f64,
}

/// Gaussian smoothing of `p` with σ `s` px (edges repeated).
fn smooth(p: &[f64], s: f64) -> Vec<f64> {
    let r = (3.0 * s).ceil().max(1.0) as isize;
    let k: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * s * s)).exp())
        .collect();
    let sum: f64 = k.iter().sum();
    let n = p.len() as isize;
    (0..n)
        .map(|i| {
            (-r..=r)
                .map(|j| p[(i + j).clamp(0, n - 1) as usize] * k[(j + r) as usize])
                .sum::<f64>()
                / sum
        })
        .collect()
}

/// The edges of profile `p`: the peaks of |gradient| of the smoothed profile (zero crossings
/// of its second derivative) above the amplitude threshold.
pub fn edges(p: &[f64], e: &EdgeParams) -> Vec<Edge> {
    // (σ beyond 50 px smooths any profile flat; its kernel would be needlessly long.)
    if p.len() < 5 || !(e.sigma_px.is_finite() && e.sigma_px > 0.0 && e.sigma_px <= 50.0) {
        return Vec::new();
    }
    let s = smooth(p, e.sigma_px);
    let n = s.len();
    let g: Vec<f64> = (0..n)
        .map(|i| 0.5 * (s[(i + 1).min(n - 1)] - s[i.saturating_sub(1)]))
        .collect();
    let reach = (2.0 * e.sigma_px).ceil() as usize;
    let mut out = Vec::new();
    for i in 1..n - 1 {
        let (a, b, c) = (g[i - 1].abs(), g[i].abs(), g[i + 1].abs());
        if !(b >= a && b > c && b >= e.min_amplitude) {
            continue;
        }
        // The same sign across the peak (not a crossing of zero).
        if g[i - 1] * g[i] < 0.0 || g[i + 1] * g[i] < 0.0 {
            continue;
        }
        let den = a - 2.0 * b + c;
        let off = if den.abs() > 1e-12 {
            (0.5 * (a - c) / den).clamp(-0.5, 0.5)
        } else {
            0.0
        };
        // Half-height width of the gradient's peak.
        let half = 0.5 * b;
        let mut lo = i;
        while lo > 0 && g[lo - 1].abs() > half && g[lo - 1] * g[i] > 0.0 {
            lo -= 1;
        }
        let mut hi = i;
        while hi + 1 < n && g[hi + 1].abs() > half && g[hi + 1] * g[i] > 0.0 {
            hi += 1;
        }
        let before = s[i.saturating_sub(reach)];
        let after = s[(i + reach).min(n - 1)];
        out.push(Edge {
            at: i as f64 + off,
            polarity: if g[i] > 0.0 { 1 } else { -1 },
            amplitude: b,
            contrast: (after - before).abs(),
            width: (hi - lo + 1) as f64,
        });
    }
    out
}

/// Weights of the properties in the cost (seed 001 3.2 e: by their reliability; these are
/// relative differences, so a gain between the photos costs nothing in the ratios' logs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CostWeights {
    pub amplitude: f64,
    pub contrast: f64,
    pub width: f64,
    /// Of the disparity's distance from the expected one, per px.
    pub disparity: f64,
}

impl Default for CostWeights {
    fn default() -> Self {
        CostWeights {
            amplitude: 1.0,
            contrast: 1.0,
            width: 0.5,
            disparity: 0.0,
        }
    }
}

/// One matched pair: indices into the left and right edges, and the cost.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pair {
    pub left: usize,
    pub right: usize,
    pub cost: f64,
}

/// Where a left edge's partner may lie: `right.at − left.at` within `range`, and the
/// disparity expected there (from a coarser level or the heights' middle), px.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Window {
    pub range: [f64; 2],
    pub expected: f64,
}

/// The cost of taking right edge `r` for left edge `l`: infinite across polarities or
/// outside the window.
pub fn cost(l: &Edge, r: &Edge, window: &Window, w: &CostWeights) -> f64 {
    let d = r.at - l.at;
    if l.polarity != r.polarity || d < window.range[0] || d > window.range[1] {
        return f64::INFINITY;
    }
    // Differences of logs: relative, so a feature twice as strong costs the same at any
    // grey level (a gain between the photos is taken out before, by `match_strings`).
    let lr = |a: f64, b: f64| (a.max(1e-9) / b.max(1e-9)).ln().abs();
    w.amplitude * lr(l.amplitude, r.amplitude)
        + w.contrast * lr(l.contrast, r.contrast)
        + w.width * lr(l.width, r.width)
        + w.disparity * (d - window.expected).abs()
}

/// Seed 001's mutual string matching of the edges of one line pair (each list in order
/// along the line): every left edge's cheapest right edge within its `window` (of its
/// position) and every right edge's cheapest left edge; a pair is kept when each is the
/// other's choice (3.2 f), and then only pairs in order along the line (the costlier of two
/// crossing pairs goes). The right edges' amplitudes and contrasts are first scaled by the
/// median ratio over all candidate pairs (a gain between the photos). The candidates are
/// found by bisection, so the work grows with the candidates, not with the product of the
/// lists.
pub fn match_strings(
    left: &[Edge],
    right: &[Edge],
    window: &dyn Fn(f64) -> Window,
    w: &CostWeights,
) -> Vec<Pair> {
    // Candidate pairs: each left edge's window over the right edges (sorted by position).
    let mut candidates: Vec<(usize, usize, Window)> = Vec::new();
    for (i, l) in left.iter().enumerate() {
        let win = window(l.at);
        if !(win.range[0].is_finite() && win.range[1].is_finite()) {
            continue;
        }
        let lo = right.partition_point(|r| r.at < l.at + win.range[0]);
        let hi = right.partition_point(|r| r.at <= l.at + win.range[1]);
        for (j, r) in right.iter().enumerate().take(hi).skip(lo) {
            if r.polarity == l.polarity {
                candidates.push((i, j, win));
            }
        }
    }
    // The photos' relative gain: the median contrast ratio over the candidates.
    let mut ratios: Vec<f64> = candidates
        .iter()
        .map(|&(i, j, _)| (right[j].contrast.max(1e-9) / left[i].contrast.max(1e-9)).ln())
        .collect();
    let gain = if ratios.is_empty() {
        return Vec::new();
    } else {
        let mid = ratios.len() / 2;
        ratios.select_nth_unstable_by(mid, f64::total_cmp).1.exp()
    };
    let scaled = |r: &Edge| Edge {
        amplitude: r.amplitude / gain,
        contrast: r.contrast / gain,
        ..*r
    };
    let mut best_right: Vec<Option<(usize, f64)>> = vec![None; left.len()];
    let mut best_left: Vec<Option<(usize, f64)>> = vec![None; right.len()];
    for &(i, j, win) in &candidates {
        let c = cost(&left[i], &scaled(&right[j]), &win, w);
        if !c.is_finite() {
            continue;
        }
        if best_right[i].is_none_or(|(_, b)| c < b) {
            best_right[i] = Some((j, c));
        }
        if best_left[j].is_none_or(|(_, b)| c < b) {
            best_left[j] = Some((i, c));
        }
    }
    let mut pairs: Vec<Pair> = best_right
        .iter()
        .enumerate()
        .filter_map(|(i, b)| {
            let (j, c) = (*b)?;
            (best_left[j].map(|(k, _)| k) == Some(i)).then_some(Pair {
                left: i,
                right: j,
                cost: c,
            })
        })
        .collect();
    // Order along the line: drop the costlier of any two crossing pairs, cheapest first.
    // The kept pairs are in order, so a new one crosses one of them exactly when it is out
    // of order with its neighbours along the left line.
    pairs.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    let mut kept: std::collections::BTreeMap<usize, Pair> = Default::default();
    for p in pairs {
        let before = kept.range(..p.left).next_back().map(|(_, k)| k.right);
        let after = kept.range(p.left + 1..).next().map(|(_, k)| k.right);
        if before.is_none_or(|r| r < p.right) && after.is_none_or(|r| r > p.right) {
            kept.insert(p.left, p);
        }
    }
    kept.into_values().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic line pair: piecewise-constant grey levels (steps of random height, 5-25
    /// px apart, slightly blurred), the right profile the left one displaced by a disparity
    /// that varies along the line (5 + 2·sin(x/40) px; 0-10 px allowed, so neighbouring
    /// edges of one polarity compete), with a gain of 1.3, an offset of 20 and noise. The
    /// edges match mutually and in order; every pair's disparity is the true one within
    /// 0.3 px; at least 80 % of the edges are matched.
    #[test]
    fn edges_of_a_shifted_profile_pair_match_as_strings() {
        let n = 600;
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut rnd = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        // Steps at irregular places (8-30 px apart), levels 40-200.
        let mut steps = Vec::new();
        let mut x = 10.0;
        while x < n as f64 - 10.0 {
            steps.push((x, 40.0 + 160.0 * rnd()));
            x += 5.0 + 20.0 * rnd();
        }
        let scene = |x: f64| {
            // Each step a smooth ramp of about 1.5 px.
            let mut v = 100.0;
            for &(at, level) in &steps {
                let t = 1.0 / (1.0 + (-(x - at) / 0.6).exp());
                v += t * (level - v);
            }
            v
        };
        let disparity = |x: f64| 5.0 + 2.0 * (x / 40.0).sin();
        let left: Vec<f64> = (0..n).map(|i| scene(i as f64)).collect();
        // The right photo sees at x + d the point the left sees at x: right(x') = scene(x)
        // with x' = x + d(x); inverted by a fixed point.
        let right: Vec<f64> = (0..n)
            .map(|i| {
                let xr = i as f64;
                let mut x = xr - 5.0;
                for _ in 0..20 {
                    x = xr - disparity(x);
                }
                20.0 + 1.3 * scene(x) + 1.5 * (rnd() - 0.5)
            })
            .collect();
        let p = EdgeParams {
            sigma_px: 1.0,
            min_amplitude: 3.0,
        };
        let (le, re) = (edges(&left, &p), edges(&right, &p));
        assert!(
            le.len() >= steps.len() / 2,
            "{} edges of {} steps",
            le.len(),
            steps.len()
        );
        let window = |_: f64| Window {
            range: [0.0, 10.0],
            expected: 5.0,
        };
        let pairs = match_strings(&le, &re, &window, &CostWeights::default());
        let mut worst: f64 = 0.0;
        for w in pairs.windows(2) {
            assert!(w[0].left < w[1].left && w[0].right < w[1].right);
        }
        for pr in &pairs {
            let (l, r) = (&le[pr.left], &re[pr.right]);
            worst = worst.max((r.at - l.at - disparity(l.at)).abs());
        }
        eprintln!(
            "{} steps, {} + {} edges, {} pairs, worst {worst:.3} px",
            steps.len(),
            le.len(),
            re.len(),
            pairs.len()
        );
        assert!(worst < 0.3, "a pair off by {worst:.2} px");
        assert!(
            pairs.len() * 10 >= le.len() * 8,
            "{} of {} edges matched",
            pairs.len(),
            le.len()
        );
    }

    /// The ordering step against a brute force: on random edge lists with wide windows
    /// (many candidates, many crossings), the kept pairs are those the plain rule keeps
    /// (cheapest first, a pair dropped if it crosses or shares a right edge with any kept one
    /// in any order), and they are in order along both lines.
    #[test]
    fn the_ordering_step_keeps_what_the_brute_force_keeps() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut rnd = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..50 {
            let mut mk = |n: usize| -> Vec<Edge> {
                let mut at = 0.0;
                (0..n)
                    .map(|_| {
                        at += 1.0 + 6.0 * rnd();
                        Edge {
                            at,
                            polarity: if rnd() < 0.5 { 1 } else { -1 },
                            amplitude: 5.0 + 20.0 * rnd(),
                            contrast: 10.0 + 40.0 * rnd(),
                            width: 1.0 + 3.0 * rnd(),
                        }
                    })
                    .collect()
            };
            let (l, r) = (mk(40), mk(40));
            let window = |_: f64| Window {
                range: [-30.0, 30.0],
                expected: 0.0,
            };
            let w = CostWeights::default();
            let got = match_strings(&l, &r, &window, &w);
            for p in got.windows(2) {
                assert!(p[0].left < p[1].left && p[0].right < p[1].right);
            }
            // Brute force over the same mutual pairs: rebuild them from the costs.
            let gain = {
                let mut v: Vec<f64> = Vec::new();
                for a in &l {
                    for b in &r {
                        let d = b.at - a.at;
                        if a.polarity == b.polarity && (-30.0..=30.0).contains(&d) {
                            v.push((b.contrast / a.contrast).ln());
                        }
                    }
                }
                let m = v.len() / 2;
                v.select_nth_unstable_by(m, f64::total_cmp).1.exp()
            };
            let c = |i: usize, j: usize| {
                let s = Edge {
                    amplitude: r[j].amplitude / gain,
                    contrast: r[j].contrast / gain,
                    ..r[j]
                };
                cost(&l[i], &s, &window(0.0), &w)
            };
            let best =
                |n: usize, m: usize, f: &dyn Fn(usize, usize) -> f64| -> Vec<Option<usize>> {
                    (0..n)
                        .map(|i| {
                            (0..m)
                                .filter(|&j| f(i, j).is_finite())
                                .min_by(|&a, &b| f(i, a).total_cmp(&f(i, b)))
                        })
                        .collect()
                };
            let br = best(l.len(), r.len(), &|i, j| c(i, j));
            let bl = best(r.len(), l.len(), &|j, i| c(i, j));
            let mut mutual: Vec<(usize, usize, f64)> = br
                .iter()
                .enumerate()
                .filter_map(|(i, j)| {
                    let j = (*j)?;
                    (bl[j] == Some(i)).then(|| (i, j, c(i, j)))
                })
                .collect();
            mutual.sort_by(|a, b| a.2.total_cmp(&b.2));
            let mut kept: Vec<(usize, usize)> = Vec::new();
            for (i, j, _) in mutual {
                if !kept.iter().any(|&(a, b)| (a < i) != (b < j) || b == j) {
                    kept.push((i, j));
                }
            }
            kept.sort();
            let got: Vec<(usize, usize)> = got.iter().map(|p| (p.left, p.right)).collect();
            assert_eq!(got, kept);
        }
    }
}
