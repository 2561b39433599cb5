//! Radial lens distortion: Brown's (1971) radial terms in OpenCV's normalised form, so that
//! the coefficients a bundle adjustment estimates carry over to OpenCV and COLMAP unchanged.
//!
//! With (xᵤ, yᵤ) the collinear photo point's offset from the principal point (mm) and
//! ρ² = (xᵤ² + yᵤ²)/c² (c the focal length: ρ is the tangent of the ray's angle off the axis),
//! the photo point is offset by (xᵤ, yᵤ)·(1 + k₁ρ² + k₂ρ⁴) (OpenCV's `cv::projectPoints` with
//! only k₁ and k₂; Brown 1971, "Close-range camera calibration", eq. 4). k₁ and k₂ are
//! dimensionless; a metric camera's certificate (distortion ≤ 10 µm at 100 mm) gives |k₁| of
//! some 10⁻⁴.

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Lens {
    pub k1: f64,
    pub k2: f64,
}

impl Lens {
    pub const NONE: Lens = Lens { k1: 0.0, k2: 0.0 };

    pub fn is_none(&self) -> bool {
        self.k1 == 0.0 && self.k2 == 0.0
    }

    /// 1 + k₁ρ² + k₂ρ⁴.
    pub fn factor(&self, rho2: f64) -> f64 {
        1.0 + rho2 * (self.k1 + self.k2 * rho2)
    }

    /// The distorted offset (mm) of the collinear offset `u` (mm) at focal length `c` (mm).
    pub fn distort(&self, u: [f64; 2], c: f64) -> [f64; 2] {
        if self.is_none() {
            return u;
        }
        let d = self.factor((u[0] * u[0] + u[1] * u[1]) / (c * c));
        [u[0] * d, u[1] * d]
    }

    /// The collinear offset whose distortion is `d` (mm): Newton's method on the radius
    /// (r·(1 + k₁r²/c² + k₂r⁴/c⁴) = |d|), from r = |d|; at most 30 steps. Beyond the radius
    /// where the model folds back (its derivative ≤ 0) the last radius before it is kept.
    pub fn undistort(&self, d: [f64; 2], c: f64) -> [f64; 2] {
        let rd = (d[0] * d[0] + d[1] * d[1]).sqrt();
        if self.is_none() || rd == 0.0 {
            return d;
        }
        let s = 1.0 / (c * c);
        let mut r = rd;
        for _ in 0..30 {
            let r2 = r * r * s;
            let g = r * self.factor(r2) - rd;
            let dg = 1.0 + r2 * (3.0 * self.k1 + 5.0 * self.k2 * r2);
            if dg <= 0.0 {
                break;
            }
            let step = g / dg;
            r -= step;
            if step.abs() < 1e-12 * rd.max(1.0) {
                break;
            }
        }
        [d[0] * r / rd, d[1] * r / rd]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Undistorting a distorted offset gives it back, across the film's format and for
    /// coefficients of both signs far beyond a metric camera's.
    #[test]
    fn undistort_inverts_distort() {
        for lens in [
            Lens {
                k1: 2e-4,
                k2: -1e-5,
            },
            Lens {
                k1: -0.05,
                k2: 0.01,
            },
            Lens { k1: 0.1, k2: 0.02 },
        ] {
            for &(x, y) in &[(0.0, 0.0), (100.0, -80.0), (-3.0, 0.5), (150.0, 150.0)] {
                let d = lens.distort([x, y], 153.0);
                let u = lens.undistort(d, 153.0);
                assert!(
                    (u[0] - x).abs() < 1e-9 && (u[1] - y).abs() < 1e-9,
                    "{lens:?} ({x}, {y}) → {d:?} → {u:?}"
                );
            }
        }
        // OpenCV's normalised form, by hand: at ρ = 0.5 with k₁ = 0.1, k₂ = 0.02 the offset
        // grows by 1 + 0.025 + 0.00125.
        let d = Lens { k1: 0.1, k2: 0.02 }.distort([50.0, 0.0], 100.0);
        assert!((d[0] - 50.0 * 1.02625).abs() < 1e-12 && d[1] == 0.0);
    }
}
