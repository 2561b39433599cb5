//! Before a scan resumes, has the film stayed where it was? A tile already taken is taken
//! again and the two are matched: the shift between them (least squares on shift, gain and
//! offset, after a correlation search over whole pixels) must be a fraction of a pixel, or the
//! tiles before and after the interruption would not fit together and the interior
//! orientation would no longer hold.

use super::mosaic::gaussian;
use crate::correlation::ncc;
use crate::digitise::ImageF32;
use crate::targets::resample::sample;
use serde::Serialize;

/// A resumed scan is refused beyond this shift, px.
pub const MAX_SHIFT_PX: f64 = 0.3;
/// σ of the Gaussian both tiles are smoothed with before the fine match, px.
const SMOOTH_PX: f64 = 1.5;
/// Half-width of the whole-pixel search, px.
const SEARCH_PX: i64 = 8;

/// A resampled value with its gradient (∂/∂x, ∂/∂y).
type Sample = (f64, f64, f64);

#[derive(Debug, Clone, Copy, Serialize)]
pub struct FilmCheck {
    /// Where the film now appears relative to where it was, px of the tile (col, row).
    pub shift_px: [f64; 2],
    pub correlation: f64,
}

/// The shift d such that `now(q) ≈ a + b·before(q + d)` over the tiles' central window.
pub fn film_shift(before: &ImageF32, now: &ImageF32) -> FilmCheck {
    let (w, h) = (before.width as i64, before.height as i64);
    let half = (w.min(h) / 4).min(128);
    let (cx, cy) = (w / 2, h / 2);
    let window: Vec<(i64, i64)> = (cy - half..cy + half)
        .flat_map(|r| (cx - half..cx + half).map(move |c| (c, r)))
        .collect();
    let at = |img: &ImageF32, c: i64, r: i64| img.data[(r * w + c) as usize] as f64;
    // Whole pixels first, on every second pixel of the window.
    let mut best = (f64::MIN, [0i64; 2]);
    // The search stays inside the image.
    let reach = SEARCH_PX.min(w.min(h) / 2 - half - 1).max(0);
    for dy in -reach..=reach {
        for dx in -reach..=reach {
            let (a, b): (Vec<f64>, Vec<f64>) = window
                .iter()
                .step_by(2)
                .map(|&(c, r)| (at(before, c + dx, r + dy), at(now, c, r)))
                .unzip();
            let k = ncc(&a, &b);
            if k > best.0 {
                best = (k, [dx, dy]);
            }
        }
    }
    let mut d = [best.1[0] as f64, best.1[1] as f64];
    // Then least squares on shift, gain and offset. Both images are smoothed first:
    // interpolation smooths white noise more at half a pixel than at a whole one, which would
    // pull the shift towards half-pixel positions; on smoothed (oversampled) images it no
    // longer does.
    let (before, now) = (gaussian(before, SMOOTH_PX), gaussian(now, SMOOTH_PX));
    let pairs = |d: [f64; 2]| -> Vec<(Sample, Sample)> {
        window
            .iter()
            .filter_map(|&(c, r)| {
                let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
                let b = sample(&before, x + d[0], y + d[1])?;
                let n = sample(&now, x, y)?;
                Some((b, n))
            })
            .collect()
    };
    let fit = |p: &[(Sample, Sample)]| {
        let nn = p.len() as f64;
        let mb = p.iter().map(|(b, _)| b.0).sum::<f64>() / nn;
        let mn = p.iter().map(|(_, n)| n.0).sum::<f64>() / nn;
        let gain = p.iter().map(|(b, n)| (b.0 - mb) * (n.0 - mn)).sum::<f64>()
            / p.iter()
                .map(|(b, _)| (b.0 - mb).powi(2))
                .sum::<f64>()
                .max(1e-12);
        (mn - gain * mb, gain)
    };
    for _ in 0..30 {
        let p = pairs(d);
        let (off, gain) = fit(&p);
        let mut n = nalgebra::Matrix2::<f64>::zeros();
        let mut g = nalgebra::Vector2::<f64>::zeros();
        for (b, m) in &p {
            // r = now(q) − off − gain·before(q + d)
            let res = m.0 - off - gain * b.0;
            let j = nalgebra::Vector2::new(gain * b.1, gain * b.2);
            n += j * j.transpose();
            g += j * res;
        }
        let Some(step) = n.try_inverse().map(|m| m * g) else {
            break;
        };
        d = [d[0] + step[0], d[1] + step[1]];
        if step.norm() < 1e-4 {
            break;
        }
    }
    let p = pairs(d);
    let (a, b): (Vec<f64>, Vec<f64>) = p.iter().map(|(b, n)| (b.0, n.0)).unzip();
    FilmCheck {
        shift_px: d,
        correlation: ncc(&a, &b),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(dx: f64, dy: f64) -> ImageF32 {
        let mut img = ImageF32::new(200, 180);
        for r in 0..180 {
            for c in 0..200 {
                let (x, y) = (c as f64 + 0.5 + dx, r as f64 + 0.5 + dy);
                img.data[r * 200 + c] = (100.0
                    + 30.0 * (x * 0.21).sin() * (y * 0.17).cos()
                    + 20.0 * (x * 0.05 + y * 0.08).sin())
                    as f32;
            }
        }
        img
    }

    #[test]
    fn finds_a_known_shift_and_none_where_there_is_none() {
        let before = scene(0.0, 0.0);
        let c = film_shift(&before, &scene(0.0, 0.0));
        assert!(
            c.shift_px[0].abs() < 1e-3 && c.shift_px[1].abs() < 1e-3,
            "{c:?}"
        );
        // The film now shows at q what was at q + (2.3, −1.6).
        let c = film_shift(&before, &scene(2.3, -1.6));
        assert!(
            (c.shift_px[0] - 2.3).abs() < 0.02 && (c.shift_px[1] + 1.6).abs() < 0.02,
            "{c:?}"
        );
        assert!(c.correlation > 0.99);
    }

    #[test]
    fn noise_in_both_does_not_pull_towards_half_a_pixel() {
        // Noise in both images: resampling only one of them would prefer a shift where its
        // noise is smoothed most.
        let noisy = |seed: u64| {
            let mut img = scene(0.0, 0.0);
            let mut s = seed;
            for v in img.data.iter_mut() {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                *v += ((s >> 33) as f32 / (1u64 << 31) as f32 - 0.5) * 40.0;
            }
            img
        };
        // Over several pairs: no bias (a mean far below the noise's spread per pair).
        let mut mean = [0.0, 0.0];
        for k in 0..8 {
            let c = film_shift(&noisy(2 * k + 1), &noisy(2 * k + 2));
            assert!(c.shift_px[0].hypot(c.shift_px[1]) < 0.2, "{c:?}");
            mean = [mean[0] + c.shift_px[0] / 8.0, mean[1] + c.shift_px[1] / 8.0];
        }
        assert!(mean[0].hypot(mean[1]) < 0.03, "{mean:?}");
    }
}
