//! The part of a height's error that comes from the photos' orientation, not the matching.
//!
//! A resected photo (or an RPC with a stated error) puts every ground point where its
//! orientation says, give or take its pointing covariance Cᵢ (px², [`Sensor::pointing_covariance`]).
//! A height intersected from two photos inherits it: with A = [∂q₁/∂G; ∂q₂/∂G] (4 × 3, px per
//! m) and the least-squares intersection δG = (AᵀA)⁻¹Aᵀ·δq, the covariance of G is
//! (AᵀA)⁻¹·Aᵀ·diag(C₁, C₂)·A·(AᵀA)⁻¹ and σ_Z² its last diagonal element (the forward
//! intersection's error propagation; Kraus 2007, "Photogrammetry", §4.4). Every node of a pair
//! shares it (it is a tilt or shift of the pair's model, not noise): the pairs' agreement and
//! the matching's σ cannot show it, the check points do. Two photos resected from the same
//! control share its ground error: their pointing errors then covary (C₁₂), the block's
//! covariance is [[C₁, C₁₂], [C₁₂ᵀ, C₂]], and most of a common shift cancels in the height
//! ([`crate::geometry::control_covariance`]). A node seen by several pairs takes their
//! median, here their mean: its error Σₚ rₚᵀδqₚ / n sums each photo's pointing error once
//! with the weights of every pair it is in, so pairs that share a photo do not average its
//! error away.

use crate::coords::GroundM;
use crate::geometry::Sensor;
use nalgebra::{Matrix3, Matrix4x3};

/// The row of the forward intersection (AᵀA)⁻¹Aᵀ that gives Z from the pointing errors
/// (δcol_a, δrow_a, δcol_b, δrow_b), m per px; `None` where the rays do not intersect.
fn z_row(a: &dyn Sensor, b: &dyn Sensor, g: GroundM) -> Option<[f64; 4]> {
    let (pa, pb) = (a.partials(g)?, b.partials(g)?);
    let mut m = Matrix4x3::<f64>::zeros();
    for k in 0..3 {
        m[(0, k)] = pa[0][k];
        m[(1, k)] = pa[1][k];
        m[(2, k)] = pb[0][k];
        m[(3, k)] = pb[1][k];
    }
    let n: Matrix3<f64> = m.transpose() * m;
    let row = (n.try_inverse()? * m.transpose()).row(2).into_owned();
    let r = [row[0], row[1], row[2], row[3]];
    r.iter().all(|v| v.is_finite()).then_some(r)
}

/// σ_Z (m) at `g` of the mean of the heights that `pairs` (indices into `sensors`)
/// intersect, from the photos' pointing covariances and `between(i, j)`, Cov(δqᵢ, δqⱼ)
/// (px², rows i's column and row) of photos whose errors are shared. `None` where no photo
/// has a pointing covariance (orientations taken as exact) or no pair intersects at `g`.
pub fn height_sigma<S: Sensor>(
    sensors: &[S],
    pairs: &[(usize, usize)],
    g: GroundM,
    between: &dyn Fn(usize, usize) -> Option<[[f64; 2]; 2]>,
) -> Option<f64> {
    let cov: Vec<Option<[[f64; 2]; 2]>> =
        sensors.iter().map(|s| s.pointing_covariance(g)).collect();
    if cov.iter().all(Option::is_none) {
        return None;
    }
    // Each photo's weight in the mean: Σ over its pairs of its two elements of the row, / n.
    let mut w: Vec<Option<[f64; 2]>> = vec![None; sensors.len()];
    let mut n = 0usize;
    for &(i, j) in pairs {
        let Some(r) = z_row(&sensors[i], &sensors[j], g) else {
            continue;
        };
        n += 1;
        for (k, o) in [(i, 0), (j, 2)] {
            let v = w[k].get_or_insert([0.0; 2]);
            v[0] += r[o];
            v[1] += r[o + 1];
        }
    }
    if n == 0 {
        return None;
    }
    let quad = |a: [f64; 2], c: [[f64; 2]; 2], b: [f64; 2]| {
        a[0] * (c[0][0] * b[0] + c[0][1] * b[1]) + a[1] * (c[1][0] * b[0] + c[1][1] * b[1])
    };
    let mut var = 0.0;
    for i in 0..sensors.len() {
        let Some(wi) = w[i] else { continue };
        if let Some(c) = cov[i] {
            var += quad(wi, c, wi);
        }
        for (j, wj) in w.iter().enumerate().skip(i + 1) {
            if let (Some(wj), Some(c)) = (wj, between(i, j)) {
                var += 2.0 * quad(wi, c, *wj);
            }
        }
    }
    let var = var / (n * n) as f64;
    (var.is_finite() && var >= 0.0).then(|| var.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coords::PixelXY;
    use crate::geometry::ProjectionError;

    /// A normal-case pair as two affine "sensors" of 1 px per m with a parallax of 0.5 px per
    /// m of height along x: a pointing error of σ px in one photo's x moves the intersected
    /// height by σ/0.5·(its share of the least-squares solution), checked against the closed
    /// form of this design.
    #[derive(Clone, Copy)]
    struct Affine {
        px: f64,
        cov: Option<[[f64; 2]; 2]>,
    }
    impl Sensor for Affine {
        fn image_size(&self) -> (usize, usize) {
            (1000, 1000)
        }
        fn try_ground_to_image(&self, g: GroundM) -> Result<PixelXY, ProjectionError> {
            Ok(PixelXY::new(g.x + self.px * g.z, g.y))
        }
        fn try_image_to_ground(&self, q: PixelXY, z: f64) -> Result<GroundM, ProjectionError> {
            Ok(GroundM::new(q.col - self.px * z, q.row, z))
        }
        fn pointing_covariance(&self, _g: GroundM) -> Option<[[f64; 2]; 2]> {
            self.cov
        }
    }

    #[test]
    fn a_pointing_error_becomes_a_height_error_by_the_intersection() {
        let g = GroundM::new(10.0, 20.0, 5.0);
        let one = |a: &Affine, b: &Affine, c: Option<[[f64; 2]; 2]>| {
            height_sigma(&[*a, *b], &[(0, 1)], g, &|_, _| c)
        };
        let exact = Affine {
            px: 0.25,
            cov: None,
        };
        assert_eq!(one(&exact, &exact, None), None);
        let s = 0.2;
        let noisy = Affine {
            px: -0.25,
            cov: Some([[s * s, 0.0], [0.0, s * s]]),
        };
        // x₁ = X + 0.25 Z, x₂ = X − 0.25 Z: Z = 2(x₁ − x₂), so an x error σ in photo 2 alone
        // gives σ_Z = 2σ; y carries no height.
        let got = one(&exact, &noisy, None).unwrap();
        assert!((got - 2.0 * s).abs() < 1e-6, "{got}");
        // Both photos with σ: √2 × that.
        let both = Affine {
            px: 0.25,
            cov: noisy.cov,
        };
        let got = one(&both, &noisy, None).unwrap();
        assert!((got - 2.0 * s * 2f64.sqrt()).abs() < 1e-6, "{got}");
        // The same error in both photos (fully shared: C₁₂ = C): a common shift of x moves
        // both rays alike, and the height not at all.
        let got = one(&both, &noisy, noisy.cov).unwrap();
        assert!(got.abs() < 1e-6, "{got}");
        // Parallel rays (no base): nothing to intersect.
        assert_eq!(one(&both, &both, None), None);
    }

    /// Three photos, every pair, only photo 0 with an error: pair (0, 1) gives δZ = 2·δx₀,
    /// pair (0, 2) (x₂ = X) δZ = 4·δx₀, pair (1, 2) none, so their mean moves by 2·δx₀: σ
    /// 2σ₀, where averaging the pairs' variances would say √(20/3)·σ₀ = 2.58σ₀.
    #[test]
    fn a_photo_in_several_pairs_counts_once_in_their_mean() {
        let s = 0.2;
        let photos = [
            Affine {
                px: 0.25,
                cov: Some([[s * s, 0.0], [0.0, s * s]]),
            },
            Affine {
                px: -0.25,
                cov: None,
            },
            Affine { px: 0.0, cov: None },
        ];
        let g = GroundM::new(10.0, 20.0, 5.0);
        let got = height_sigma(&photos, &[(0, 1), (0, 2), (1, 2)], g, &|_, _| None).unwrap();
        assert!((got - 2.0 * s).abs() < 1e-6, "{got}");
    }
}
