//! The CCD's stripe noise (seed 002, "Test data", a and b), estimated from the image itself and
//! removed without any smoothing:
//! - a grey-level shift between the two video fields, i.e. between odd and even rows;
//! - a periodic column pattern (on the seed's camera: 3-pixel stripes, darker every 12 pixels),
//!   whose period, phase and profile are found by folding the column profile, not assumed.
//!
//! Both are offsets per row parity and per column phase, so removing them moves no edge.
//! Every statistic is a median, so that scene edges (a cross arm spans hundreds of rows) do not
//! bias it.

use super::ImageF32;
use serde::Serialize;

/// Half-width of the horizontal high-pass that separates the column pattern from the scene.
const HIGHPASS_HALF: usize = 24;
/// Smallest half-width of that high-pass, at the image's borders: a window of 13 px spans a
/// whole period of the seed's 12-px pattern on the first pass, before the pattern is known.
const HIGHPASS_MIN_HALF: usize = 6;
/// Periods searched for the column pattern, pixels.
const PERIODS: std::ops::RangeInclusive<usize> = 2..=32;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StripeEstimate {
    /// Grey-level shift of the odd rows against the even rows, DN.
    pub field_offset: f32,
    /// Period of the column pattern, pixels; `None` when no significant pattern was found.
    pub column_period: Option<usize>,
    /// The pattern's offset per column phase (`col % period`), DN, median zero.
    pub column_profile: Vec<f32>,
    /// The darkest column phase.
    pub column_darkest_phase: Option<usize>,
    /// Peak-to-peak of the profile, DN.
    pub column_amplitude: f32,
    /// Fraction of the column profile's variance the pattern explains.
    pub column_explained: f32,
}

fn median(v: &mut [f32]) -> f32 {
    if v.is_empty() {
        return f32::NAN;
    }
    let n = v.len();
    let (_, m, _) = v.select_nth_unstable_by(n / 2, f32::total_cmp);
    *m
}

/// Odd-row shift: the median over the image of each odd-row pixel minus the mean of its two
/// even neighbours.
fn field_offset(img: &ImageF32, keep: &dyn Fn(usize, usize) -> bool) -> f32 {
    let (w, h) = (img.width, img.height);
    let mut d = Vec::with_capacity(w * h / 2);
    for r in (1..h.saturating_sub(1)).step_by(2) {
        let (up, mid, down) = (img.row(r - 1), img.row(r), img.row(r + 1));
        for c in 0..w {
            if keep(c, r - 1) && keep(c, r) && keep(c, r + 1) {
                d.push(mid[c] - 0.5 * (up[c] + down[c]));
            }
        }
    }
    if d.is_empty() {
        0.0
    } else {
        median(&mut d)
    }
}

/// Per column, the median over rows of the pixel minus its horizontal neighbourhood mean; NaN
/// for the outermost columns, where not even a window of [`HIGHPASS_MIN_HALF`] fits. The
/// window is symmetric (so a scene's linear ramp cancels) and shrinks toward the borders:
/// a crop of a few dozen pixels around a mark (71 px) then still gives most of its columns,
/// several periods of a 12-px pattern, instead of the 23 a fixed 49-px window leaves. The
/// neighbourhood mean is taken with the pattern estimated so far (`known`, per column)
/// removed, so the window needs no particular length to be free of the pattern.
fn column_profile(
    img: &ImageF32,
    field: f32,
    known: &[f32],
    keep: &dyn Fn(usize, usize) -> bool,
) -> Vec<f32> {
    let (w, h) = (img.width, img.height);
    let mut per_col: Vec<Vec<f32>> = vec![Vec::with_capacity(h); w];
    let mut prefix = vec![0.0f64; w + 1];
    let mut count = vec![0usize; w + 1];
    for r in 0..h {
        let row = img.row(r);
        let off = if r % 2 == 1 { field } else { 0.0 };
        for c in 0..w {
            let k = keep(c, r);
            prefix[c + 1] = prefix[c]
                + if k {
                    (row[c] - off - known[c]) as f64
                } else {
                    0.0
                };
            count[c + 1] = count[c] + k as usize;
        }
        for c in 0..w {
            let half = HIGHPASS_HALF.min(c).min(w - 1 - c);
            if half < HIGHPASS_MIN_HALF || !keep(c, r) {
                continue;
            }
            let n = count[c + half + 1] - count[c - half];
            if n < HIGHPASS_MIN_HALF + 1 {
                continue;
            }
            let mean = (prefix[c + half + 1] - prefix[c - half]) / n as f64;
            per_col[c].push((row[c] - off) - mean as f32);
        }
    }
    let mut p: Vec<f32> = per_col.iter_mut().map(|v| median(v)).collect();
    let mut finite: Vec<f32> = p.iter().copied().filter(|v| !v.is_nan()).collect();
    let m = median(&mut finite);
    p.iter_mut().for_each(|v| *v -= m);
    p
}

/// Folds `p` with period `period`: the median per phase (NaN columns skipped).
fn fold(p: &[f32], period: usize) -> Vec<f32> {
    (0..period)
        .map(|k| {
            let mut v: Vec<f32> = p
                .iter()
                .skip(k)
                .step_by(period)
                .copied()
                .filter(|v| !v.is_nan())
                .collect();
            let m = median(&mut v);
            if m.is_nan() {
                0.0
            } else {
                m
            }
        })
        .collect()
}

/// (fraction of the profile's variance the folded pattern explains, residual variance)
fn fit(p: &[f32], f: &[f32]) -> (f64, f64, usize) {
    let (mut total, mut resid, mut n) = (0.0, 0.0, 0);
    for (c, &v) in p.iter().enumerate().filter(|(_, v)| !v.is_nan()) {
        total += (v as f64).powi(2);
        resid += ((v - f[c % f.len()]) as f64).powi(2);
        n += 1;
    }
    let e = if total > 0.0 {
        1.0 - resid / total
    } else {
        0.0
    };
    (e, resid / n.max(1) as f64, n)
}

/// The period that explains most of the column profile; of a period and its multiples (which
/// explain as much), the shortest that explains nearly all the best does.
fn best_period(p: &[f32]) -> Option<usize> {
    let used = p.iter().filter(|v| !v.is_nan()).count();
    let cands: Vec<(usize, f64)> = PERIODS
        .filter(|&q| q * 4 <= used)
        .map(|q| (q, fit(p, &fold(p, q)).0))
        .collect();
    let &(best_q, best_e) = cands.iter().max_by(|a, b| a.1.total_cmp(&b.1))?;
    cands
        .iter()
        .filter(|&&(q, e)| best_q % q == 0 && e >= 0.95 * best_e)
        .min_by_key(|&&(q, _)| q)
        .map(|&(q, _)| q)
}

/// Estimates the field shift and the column pattern of `img` (best on an average of many
/// frames, where the random noise is low).
pub fn estimate_stripes(img: &ImageF32) -> StripeEstimate {
    estimate_stripes_where(img, &|_, _| true)
}

/// [`estimate_stripes`] from the pixels `keep(col, row)` only: on a crop around a mark, its
/// background, the mark left out. The mark's own pixels would otherwise bias the medians
/// (a cross's bar fills half of its columns' rows), and a crop has no others to spare. The
/// stripes are offsets of the sensor's rows and columns (seed 002), so the background
/// determines them where the mark lies too.
pub fn estimate_stripes_where(
    img: &ImageF32,
    keep: &dyn Fn(usize, usize) -> bool,
) -> StripeEstimate {
    let field = field_offset(img, keep);
    let w = img.width;
    let none = StripeEstimate {
        field_offset: field,
        column_period: None,
        column_profile: vec![],
        column_darkest_phase: None,
        column_amplitude: 0.0,
        column_explained: 0.0,
    };
    // Each pass takes the neighbourhood means with the previous estimate removed; the
    // pattern's leak into the window mean shrinks geometrically.
    let mut known = vec![0.0f32; w];
    let mut found = None;
    for _ in 0..3 {
        let p = column_profile(img, field, &known, keep);
        let Some(q) = best_period(&p) else {
            return none;
        };
        let f = fold(&p, q);
        known = (0..w).map(|c| f[c % q]).collect();
        found = Some((p, q, f));
    }
    let Some((p, q, f)) = found else { return none };
    // Significant only if the folded profile stands well above its own standard error.
    let (e, resid_var, used) = fit(&p, &f);
    let se2 = resid_var / (used / q).max(1) as f64;
    let signal = f.iter().map(|&v| (v as f64).powi(2)).sum::<f64>() / q as f64;
    if e < 0.3 || signal < 9.0 * se2 {
        return none;
    }
    let darkest = f
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .map(|(k, _)| k);
    let amp =
        f.iter().copied().fold(f32::MIN, f32::max) - f.iter().copied().fold(f32::MAX, f32::min);
    StripeEstimate {
        field_offset: field,
        column_period: Some(q),
        column_profile: f,
        column_darkest_phase: darkest,
        column_amplitude: amp,
        column_explained: e as f32,
    }
}

/// Subtracts the estimated field shift from the odd rows and the column pattern from every
/// row. Pure offsets: no pixel is mixed with another.
pub fn remove_stripes(img: &mut ImageF32, est: &StripeEstimate) {
    let w = img.width;
    for (r, row) in img.data.chunks_mut(w).enumerate() {
        let off = if r % 2 == 1 { est.field_offset } else { 0.0 };
        for (c, v) in row.iter_mut().enumerate() {
            let col = if est.column_period.is_some() {
                est.column_profile[c % est.column_profile.len()]
            } else {
                0.0
            };
            *v -= off + col;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_a_synthetic_pattern_exactly() {
        // Ramp scene + odd-row shift 4.5 + period-12 pattern at phase 5.
        let (w, h) = (240, 64);
        let pat = |c: usize| match ((c + 7) % 12) / 3 {
            0 => -3.5,
            2 => -2.0,
            _ => 0.0,
        };
        let mut img = ImageF32::new(w, h);
        for r in 0..h {
            for c in 0..w {
                img.data[r * w + c] =
                    100.0 + 0.3 * c as f32 + if r % 2 == 1 { 4.5 } else { 0.0 } + pat(c);
            }
        }
        let e = estimate_stripes(&img);
        assert!((e.field_offset - 4.5).abs() < 1e-3, "{}", e.field_offset);
        assert_eq!(e.column_period, Some(12));
        assert!((e.column_amplitude - 3.5).abs() < 1e-3, "{e:?}");
        assert_eq!(e.column_darkest_phase, Some(5));
        remove_stripes(&mut img, &e);
        // What is left is the ramp plus a constant.
        let k = img.at(0, 0) - 100.0;
        for r in 0..h {
            for c in 0..w {
                assert!((img.at(c, r) - (100.0 + 0.3 * c as f32 + k)).abs() < 1e-3);
            }
        }
    }

    #[test]
    fn no_pattern_means_none() {
        let (w, h) = (200, 50);
        let mut img = ImageF32::new(w, h);
        let mut x = 12345u64;
        for v in img.data.iter_mut() {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            *v = 100.0 + (x % 1000) as f32 / 1000.0;
        }
        assert_eq!(estimate_stripes(&img).column_period, None);
    }
}
