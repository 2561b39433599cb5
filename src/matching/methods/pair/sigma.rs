//! The σ of a rectified pair's disparities: the noise's share, as the matcher gives it, and the
//! sub-pixel estimator's own error on the texture at hand, which the noise's share leaves out.
//!
//! Förstner's precision of a correlation or least-squares match (Förstner 1984, "Quality
//! assessment of object location and point transfer using digital image correlation
//! techniques", IAPRS 25(A3a), eq. for σ_x² = σ_n² / Σ g_x²) holds for an unbiased estimator of
//! a shift between two copies of one signal that differ by white noise. A window's sub-pixel
//! estimator is not unbiased on a given texture: the parabola through three correlations
//! takes a peak that is not a parabola, and the windows at d ± 1 take in pixels the window at d
//! does not, so even two noise-free copies shifted by a whole pixel give an offset that depends
//! on the texture alone (on the benchmark pair's fronto-parallel patch, noise-free, 0.12 px RMS
//! where Förstner's σ is 0.02 px; the "systematic error" of sub-pixel estimation of Shimizu &
//! Okutomi 2005, "Sub-pixel estimation error cancellation on area-based matching", IJCV 63(3),
//! §2, there as a function of the sub-pixel phase, here of the texture). That error is measured
//! exactly, for each pixel, by the same matcher run on the left photo against itself: the
//! truth is 0 everywhere, the noise is the same in both, so every offset it returns is the
//! estimator's own (for SGM through the same aggregation, for least squares through the same
//! iterations). At the pair's true disparity the phase differs and so does the error, so its
//! variance is taken as the mean of the squared self-offsets over the pixel's window (the
//! textures a window around it takes in), and σ² = σ_noise² + that mean: the two are
//! independent (the self-offset is a function of the noise-free texture to first order).

use crate::image::ImageF32;
use crate::matching::methods::pair::matcher::{
    disparities_alone, streams, Filter, PairError, PairParams,
};

/// Disparities searched in the photo's match against itself: the winner is 0 or 1, and ±2
/// keep it off the ends of the range (a winner at an end is refused).
const SELF_RANGE: i64 = 2;

/// The sub-pixel phases at which the estimator is run on its own photo: its error depends on
/// the phase (for the parabola, pixel-locking; for bilinear least squares, the interpolation's
/// bias, Schreier, Braasch & Sutton 2000, "Systematic errors in digital image correlation
/// caused by intensity interpolation", Opt. Eng. 39(11), Fig. 3), so its variance is the mean
/// over the phases of a pixel step.
const PHASES: [f64; 4] = [0.0, 0.25, 0.5, 0.75];

/// Half-width of the windowed-sinc kernel that shifts the photo by a fraction of a pixel.
const LANCZOS_A: i64 = 8;

/// The estimator's error variance (px²) at each pixel of `left` for matching with `p`: the
/// mean over the pixel's window of the squared errors that the same matcher makes on the
/// photo against itself shifted by each phase (each pixel's mean over its phases first);
/// NaN where none.
pub fn estimator_variance(
    left: &ImageF32,
    p: &PairParams,
    max_memory_mb: u64,
) -> Result<Vec<f32>, PairError> {
    let q = self_params(p);
    let (w, h) = (left.width, left.height);
    let k = p.window / 2;
    // Each pixel's squared errors over the phases it was matched at.
    let mut sum = vec![0.0f64; w * h];
    let mut count = vec![0u8; w * h];
    for (j, phase) in PHASES.into_iter().enumerate() {
        // With SGM's 5 streamed paths each phase on every fourth row (the place comes from
        // the paths along the row, which see the row alone): each box below, at least 5
        // rows tall, holds all four, at a quarter of the work.
        let shifted;
        let right = if phase == 0.0 {
            left
        } else {
            shifted = shift_rows(left, phase);
            &shifted
        };
        let m = disparities_alone(left, right, &q, max_memory_mb, Some((j, PHASES.len())))?;
        for ((s, c), &v) in sum.iter_mut().zip(&mut count).zip(&m.d) {
            if v.is_finite() {
                *s += (v as f64 - phase).powi(2);
                *c += 1;
            }
        }
    }
    let mean: Vec<f64> = sum
        .iter()
        .zip(&count)
        .map(|(&s, &c)| if c > 0 { s / c as f64 } else { f64::NAN })
        .collect();
    let ky = if streams(&q) {
        k.max(PHASES.len() / 2)
    } else {
        k
    };
    Ok(box_mean(&mean, w, h, k, ky))
}

/// The self-match's parameters for a match with `p`.
pub(super) fn self_params(p: &PairParams) -> PairParams {
    PairParams {
        d_min: -SELF_RANGE,
        d_max: SELF_RANGE,
        // Every pixel kept: the checks would remove nothing true, only time.
        threshold: -1.0,
        filter: if p.filter == Filter::Sgm {
            Filter::Sgm
        } else {
            Filter::None
        },
        lr_tolerance: None,
        uniqueness: 0.0,
        ..p.clone()
    }
}

/// `img` shifted along its rows so that out(x) = img(x + phase): the disparity of `img`
/// against `out` is `phase`. A Lanczos windowed sinc (Duchon 1979, "Lanczos filtering in one
/// and two dimensions", J. Appl. Meteor. 18, eq. 8) of half-width [`LANCZOS_A`], nearly the
/// band-limited shift, so that the matcher's own interpolation is not measured against
/// itself; NaN where a tap is NaN or outside the photo.
fn shift_rows(img: &ImageF32, phase: f64) -> ImageF32 {
    let (w, h) = (img.width, img.height);
    let a = LANCZOS_A;
    let sinc = |x: f64| {
        if x.abs() < 1e-12 {
            1.0
        } else {
            let px = std::f64::consts::PI * x;
            px.sin() / px
        }
    };
    // Taps j = −a + 1 … a at x + j, weights L(phase − j), normalised to sum 1.
    let taps: Vec<(i64, f64)> = (-a + 1..=a)
        .map(|j| {
            let t = phase - j as f64;
            (j, sinc(t) * sinc(t / a as f64))
        })
        .collect();
    let norm: f64 = taps.iter().map(|t| t.1).sum();
    let weights: Vec<f64> = taps.iter().map(|t| t.1 / norm).collect();
    let mut out = ImageF32::new(w, h);
    use rayon::prelude::*;
    // Columns whose taps c − a + 1 … c + a all lie in the row; NaN beyond them, and where a
    // tap is NaN (the sum is).
    let (c0, c1) = ((a - 1) as usize, (w as i64 - a).max(0) as usize);
    out.data
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(r, o)| {
            let row = &img.data[r * w..(r + 1) * w];
            o.fill(f32::NAN);
            for c in c0..c1.max(c0) {
                let src = &row[c + 1 - a as usize..c + 1 + a as usize];
                let v: f64 = src
                    .iter()
                    .zip(&weights)
                    .map(|(&x, &wt)| wt * x as f64)
                    .sum();
                o[c] = v as f32;
            }
        });
    out
}

/// The mean of the finite values in the (2kx + 1) × (2ky + 1) box around each pixel
/// (clipped at the photo's edges); NaN where there are none. Separable: each row's sums
/// along the row, then each column's down the rows, both in f64 and in parallel.
fn box_mean(v: &[f64], w: usize, h: usize, kx: usize, ky: usize) -> Vec<f32> {
    use rayon::prelude::*;
    if w == 0 || h == 0 {
        return Vec::new();
    }
    // Along the rows: the box's sum and count of the finite values at each pixel.
    let mut hs = vec![0.0f64; w * h];
    let mut hn = vec![0u32; w * h];
    hs.par_chunks_mut(w)
        .zip(hn.par_chunks_mut(w))
        .enumerate()
        .for_each(|(r, (s, n))| {
            let row = &v[r * w..(r + 1) * w];
            // Prefix sums, then the box from two of them.
            let mut ps = vec![0.0f64; w + 1];
            let mut pn = vec![0u32; w + 1];
            for c in 0..w {
                let x = row[c];
                let ok = x.is_finite();
                ps[c + 1] = ps[c] + if ok { x } else { 0.0 };
                pn[c + 1] = pn[c] + u32::from(ok);
            }
            for c in 0..w {
                let (c0, c1) = (c.saturating_sub(kx), (c + kx + 1).min(w));
                s[c] = ps[c1] - ps[c0];
                n[c] = pn[c1] - pn[c0];
            }
        });
    // Down the columns, in strips of columns.
    let mut out = vec![f32::NAN; w * h];
    const STRIP: usize = 64;
    let strips: Vec<usize> = (0..w).step_by(STRIP).collect();
    let cols: Vec<Vec<f32>> = strips
        .par_iter()
        .map(|&c0| {
            let c1 = (c0 + STRIP).min(w);
            let m = c1 - c0;
            let mut ps = vec![0.0f64; (h + 1) * m];
            let mut pn = vec![0u32; (h + 1) * m];
            for r in 0..h {
                for j in 0..m {
                    ps[(r + 1) * m + j] = ps[r * m + j] + hs[r * w + c0 + j];
                    pn[(r + 1) * m + j] = pn[r * m + j] + hn[r * w + c0 + j];
                }
            }
            let mut o = vec![f32::NAN; h * m];
            for r in 0..h {
                let (r0, r1) = (r.saturating_sub(ky), (r + ky + 1).min(h));
                for j in 0..m {
                    let cnt = pn[r1 * m + j] - pn[r0 * m + j];
                    if cnt > 0 {
                        let sum = ps[r1 * m + j] - ps[r0 * m + j];
                        o[r * m + j] = (sum.max(0.0) / cnt as f64) as f32;
                    }
                }
            }
            o
        })
        .collect();
    for (&c0, o) in strips.iter().zip(&cols) {
        let m = (c0 + STRIP).min(w) - c0;
        for r in 0..h {
            out[r * w + c0..r * w + c0 + m].copy_from_slice(&o[r * m..(r + 1) * m]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The box mean skips NaN and clips at the edges.
    #[test]
    fn box_mean_of_the_finite_values() {
        let v = [1.0, f64::NAN, 3.0, 5.0];
        let m = box_mean(&v, 2, 2, 1, 1);
        assert!(m.iter().all(|&x| (x - 3.0).abs() < 1e-6), "{m:?}");
        let m0 = box_mean(&v, 2, 2, 0, 0);
        assert!(m0[1].is_nan() && m0[3] == 5.0, "{m0:?}");
    }

    /// The separable box mean is the plain one: each box's finite values summed and
    /// counted, over photos wider than a strip, boxes wider than tall and taller than wide.
    #[test]
    fn box_mean_is_the_plain_mean() {
        let (w, h) = (150usize, 37usize);
        let mut seed = 17u64;
        let v: Vec<f64> = (0..w * h)
            .map(|_| {
                seed = seed
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                if seed >> 61 == 0 {
                    f64::NAN
                } else {
                    (seed >> 40) as f64 / (1u64 << 24) as f64
                }
            })
            .collect();
        for (kx, ky) in [(2, 2), (1, 2), (3, 0), (0, 4)] {
            let got = box_mean(&v, w, h, kx, ky);
            for r in 0..h {
                for c in 0..w {
                    let (mut s, mut n) = (0.0, 0);
                    for rr in r.saturating_sub(ky)..(r + ky + 1).min(h) {
                        for cc in c.saturating_sub(kx)..(c + kx + 1).min(w) {
                            let x = v[rr * w + cc];
                            if x.is_finite() {
                                s += x;
                                n += 1;
                            }
                        }
                    }
                    let g = got[r * w + c];
                    if n == 0 {
                        assert!(g.is_nan());
                    } else {
                        assert!((g as f64 - s / n as f64).abs() < 1e-5, "({c}, {r}): {g}");
                    }
                }
            }
        }
    }

    /// The shift moves a smooth row by the phase: out(x) = img(x + phase).
    #[test]
    fn rows_shift_by_the_phase() {
        let (w, h) = (64usize, 2usize);
        let f = |x: f64| (x * 0.37).sin() * 20.0 + (x * 0.11).cos() * 30.0;
        let mut img = ImageF32::new(w, h);
        for r in 0..h {
            for c in 0..w {
                img.data[r * w + c] = f(c as f64) as f32;
            }
        }
        let out = shift_rows(&img, 0.25);
        for c in 10..54 {
            assert!(
                (out.data[c] as f64 - f(c as f64 + 0.25)).abs() < 0.05,
                "{c}"
            );
        }
        assert!(out.data[0].is_nan() && out.data[w - 1].is_nan());
    }
}
