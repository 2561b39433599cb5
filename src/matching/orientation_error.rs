//! The part of a height's error that comes from the photos' orientation, not the matching.
//!
//! A resected photo (or an RPC with a stated error) puts every ground point where its
//! orientation says, give or take its pointing covariance Cᵢ (px², [`Sensor::pointing_covariance`]).
//! A height intersected from two photos inherits it: with A = [∂q₁/∂G; ∂q₂/∂G] (4 × 3, px per
//! m) and the least-squares intersection δG = (AᵀA)⁻¹Aᵀ·δq, the covariance of G is
//! (AᵀA)⁻¹·Aᵀ·diag(C₁, C₂)·A·(AᵀA)⁻¹ and σ_Z² its last diagonal element (the forward
//! intersection's error propagation; Kraus 2007, "Photogrammetry", §4.4). Every node of a pair
//! shares it (it is a tilt or shift of the pair's model, not noise): the pairs' agreement and
//! the matching's σ cannot show it, the check points do.

use crate::coords::GroundM;
use crate::geometry::Sensor;
use nalgebra::{Matrix3, Matrix4x3};

/// σ_Z (m) at `g` of the height intersected from `a` and `b`, from their pointing
/// covariances; `None` where neither has one (orientations taken as exact) or the geometry
/// does not intersect (parallel rays, a point neither sees).
pub fn height_sigma(a: &dyn Sensor, b: &dyn Sensor, g: GroundM) -> Option<f64> {
    let (ca, cb) = (a.pointing_covariance(g), b.pointing_covariance(g));
    if ca.is_none() && cb.is_none() {
        return None;
    }
    let (pa, pb) = (a.partials(g)?, b.partials(g)?);
    let mut m = Matrix4x3::<f64>::zeros();
    for k in 0..3 {
        m[(0, k)] = pa[0][k];
        m[(1, k)] = pa[1][k];
        m[(2, k)] = pb[0][k];
        m[(3, k)] = pb[1][k];
    }
    let n: Matrix3<f64> = m.transpose() * m;
    let ni = n.try_inverse()?;
    // The row of (AᵀA)⁻¹Aᵀ that gives Z.
    let row = (ni * m.transpose()).row(2).into_owned();
    let zero = [[0.0; 2]; 2];
    let (ca, cb) = (ca.unwrap_or(zero), cb.unwrap_or(zero));
    // vᵀ·C·v for each photo's two elements of that row.
    let part = |c: [[f64; 2]; 2], o: usize| {
        let (x, y) = (row[o], row[o + 1]);
        x * (c[0][0] * x + c[0][1] * y) + y * (c[1][0] * x + c[1][1] * y)
    };
    let var = part(ca, 0) + part(cb, 2);
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
        let exact = Affine {
            px: 0.25,
            cov: None,
        };
        assert_eq!(height_sigma(&exact, &exact, g), None);
        let s = 0.2;
        let noisy = Affine {
            px: -0.25,
            cov: Some([[s * s, 0.0], [0.0, s * s]]),
        };
        // x₁ = X + 0.25 Z, x₂ = X − 0.25 Z: Z = 2(x₁ − x₂), so an x error σ in photo 2 alone
        // gives σ_Z = 2σ; y carries no height.
        let got = height_sigma(&exact, &noisy, g).unwrap();
        assert!((got - 2.0 * s).abs() < 1e-6, "{got}");
        // Both photos with σ: √2 × that.
        let both = Affine {
            px: 0.25,
            cov: noisy.cov,
        };
        let got = height_sigma(&both, &noisy, g).unwrap();
        assert!((got - 2.0 * s * 2f64.sqrt()).abs() < 1e-6, "{got}");
        // Parallel rays (no base): nothing to intersect.
        assert_eq!(height_sigma(&both, &both, g), None);
    }
}
