//! Bicubic resampling with its gradient, for least-squares matching. Coordinates are continuous
//! pixel coordinates with the origin at the top-left corner of the top-left pixel, so pixel
//! (c, r) covers [c, c+1) × [r, r+1) and its centre is (c + 0.5, r + 0.5) — the convention of
//! [`crate::coords::PixelXY`].

use crate::digitise::ImageF32;

/// Keys' cubic convolution kernel with a = −0.5 (third-order accurate) and its derivative.
#[inline]
fn keys(t: f64) -> (f64, f64) {
    const A: f64 = -0.5;
    let (s, x) = (t.signum(), t.abs());
    if x <= 1.0 {
        (
            (A + 2.0) * x * x * x - (A + 3.0) * x * x + 1.0,
            s * (3.0 * (A + 2.0) * x * x - 2.0 * (A + 3.0) * x),
        )
    } else if x < 2.0 {
        (
            A * x * x * x - 5.0 * A * x * x + 8.0 * A * x - 4.0 * A,
            s * (3.0 * A * x * x - 10.0 * A * x + 8.0 * A),
        )
    } else {
        (0.0, 0.0)
    }
}

/// The four taps' weights and derivative weights for continuous coordinate `x`; the first tap.
#[inline]
fn taps(x: f64) -> (i64, [f64; 4], [f64; 4]) {
    let u = x - 0.5;
    let i0 = u.floor();
    let t = u - i0;
    let mut w = [0.0; 4];
    let mut d = [0.0; 4];
    for k in 0..4 {
        // Tap i0 − 1 + k lies at distance (k − 1 − t) from u.
        let (wk, dk) = keys(t - (k as f64 - 1.0));
        w[k] = wk;
        d[k] = dk;
    }
    (i0 as i64 - 1, w, d)
}

/// The image's value and gradient (∂/∂x, ∂/∂y) at (x, y), or `None` where the 4×4
/// neighbourhood leaves the image.
pub fn sample(img: &ImageF32, x: f64, y: f64) -> Option<(f64, f64, f64)> {
    let (c0, wx, dx) = taps(x);
    let (r0, wy, dy) = taps(y);
    if c0 < 0 || r0 < 0 || c0 + 4 > img.width as i64 || r0 + 4 > img.height as i64 {
        return None;
    }
    let (c0, r0) = (c0 as usize, r0 as usize);
    let (mut v, mut gx, mut gy) = (0.0, 0.0, 0.0);
    for j in 0..4 {
        let row = &img.data[(r0 + j) * img.width + c0..][..4];
        let (mut s, mut sd) = (0.0, 0.0);
        for i in 0..4 {
            let p = row[i] as f64;
            s += wx[i] * p;
            sd += dx[i] * p;
        }
        v += wy[j] * s;
        gx += wy[j] * sd;
        gy += dy[j] * s;
    }
    Some((v, gx, gy))
}

/// The image's value at (x, y), or `None` where the 4×4 neighbourhood leaves the image.
#[inline]
pub fn value(img: &ImageF32, x: f64, y: f64) -> Option<f64> {
    let (c0, wx, _) = taps(x);
    let (r0, wy, _) = taps(y);
    if c0 < 0 || r0 < 0 || c0 + 4 > img.width as i64 || r0 + 4 > img.height as i64 {
        return None;
    }
    let (c0, r0) = (c0 as usize, r0 as usize);
    let mut v = 0.0;
    for j in 0..4 {
        let row = &img.data[(r0 + j) * img.width + c0..][..4];
        v += wy[j]
            * (wx[0] * row[0] as f64
                + wx[1] * row[1] as f64
                + wx[2] * row[2] as f64
                + wx[3] * row[3] as f64);
    }
    Some(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reproduces_a_quadratic_and_its_gradient() {
        // Keys' kernel reproduces polynomials up to degree 2 exactly.
        let (w, h) = (12, 10);
        let f = |x: f64, y: f64| 3.0 + 0.5 * x - 0.25 * y + 0.03 * x * x - 0.02 * x * y;
        let mut img = ImageF32::new(w, h);
        for r in 0..h {
            for c in 0..w {
                img.data[r * w + c] = f(c as f64 + 0.5, r as f64 + 0.5) as f32;
            }
        }
        for &(x, y) in &[(4.0, 5.0), (5.37, 4.81), (6.5, 6.5), (2.01, 7.99)] {
            let (v, gx, gy) = sample(&img, x, y).unwrap();
            assert!((v - f(x, y)).abs() < 1e-4, "{x},{y}: {v} vs {}", f(x, y));
            assert!((gx - (0.5 + 0.06 * x - 0.02 * y)).abs() < 1e-4);
            assert!((gy - (-0.25 - 0.02 * x)).abs() < 1e-4);
            assert!((value(&img, x, y).unwrap() - v).abs() < 1e-9);
        }
        // Pixel centres give the pixel back.
        let (v, _, _) = sample(&img, 5.5, 4.5).unwrap();
        assert!((v - img.at(5, 4) as f64).abs() < 1e-5);
        assert!(sample(&img, 1.4, 5.0).is_none());
        assert!(sample(&img, 5.0, 8.6).is_none());
    }
}
