//! The collinearity equations and their partial derivatives in closed form, for the bundle
//! adjustment's Jacobian (the resection's and the matchers' central differences cost two
//! projections a parameter; a block of 200 000 rays is linearised every iteration).
//!
//! With u = Rᵀ(X − C) (docs/conventions.md: R = R_ω·R_φ·R_κ takes image vectors to object
//! space): x = x₀ − c·u₁/u₃, y = y₀ − c·u₂/u₃ (Kraus 2007, "Photogrammetry", eq. 4.1-7).
//! ∂u/∂X = Rᵀ, ∂u/∂C = −Rᵀ, ∂u/∂ω = (∂R/∂ω)ᵀ(X − C) and likewise for φ and κ.
//!
//! With radial distortion ([`crate::geometry::lens`]): a = u₁/u₃, b = u₂/u₃, ρ² = a² + b²,
//! D = 1 + k₁ρ² + k₂ρ⁴, x = x₀ − c·a·D, y = y₀ − c·b·D. Then ∂x/∂c = −a·D, ∂x/∂k₁ = −c·a·ρ²,
//! ∂x/∂k₂ = −c·a·ρ⁴, and ∂(x, y)/∂(a, b) = −c·(D·I + 2K·(a, b)ᵀ(a, b)) with K = k₁ + 2k₂ρ².

use crate::geometry::{Exterior, Interior};
use nalgebra::{Matrix3, SMatrix, Vector2, Vector3};

/// The interior parameters a self-calibrating adjustment can estimate, in the order of
/// [`Linearised::d_interior`]'s columns: c, x₀, y₀ (mm), k₁, k₂; the sixth column is unused
/// (the normal equations keep blocks of six).
pub const INTERIOR: [&str; 5] = [
    "focal",
    "principal_point_x",
    "principal_point_y",
    "k1",
    "k2",
];

/// One ray's projection and partials: the photo point (mm), ∂(x, y)/∂(ω, φ, κ, X₀, Y₀, Z₀)
/// (mm per rad, per m), ∂(x, y)/∂(X, Y, Z) (mm per m) and ∂(x, y)/∂(c, x₀, y₀, k₁, k₂, —).
#[derive(Debug, Clone, Copy)]
pub struct Linearised {
    pub xy: Vector2<f64>,
    pub d_exterior: SMatrix<f64, 2, 6>,
    pub d_ground: SMatrix<f64, 2, 3>,
    pub d_interior: SMatrix<f64, 2, 6>,
}

/// The rotation R and its three partials ∂R/∂ω, ∂R/∂φ, ∂R/∂κ.
#[derive(Debug, Clone, Copy)]
pub struct Rotation {
    pub r: Matrix3<f64>,
    pub d: [Matrix3<f64>; 3],
}

impl Rotation {
    pub fn of(e: &Exterior) -> Rotation {
        let (so, co) = e.omega.sin_cos();
        let (sp, cp) = e.phi.sin_cos();
        let (sk, ck) = e.kappa.sin_cos();
        let rw = Matrix3::new(1.0, 0.0, 0.0, 0.0, co, -so, 0.0, so, co);
        let rp = Matrix3::new(cp, 0.0, sp, 0.0, 1.0, 0.0, -sp, 0.0, cp);
        let rk = Matrix3::new(ck, -sk, 0.0, sk, ck, 0.0, 0.0, 0.0, 1.0);
        let dw = Matrix3::new(0.0, 0.0, 0.0, 0.0, -so, -co, 0.0, co, -so);
        let dp = Matrix3::new(-sp, 0.0, cp, 0.0, 0.0, 0.0, -cp, 0.0, -sp);
        let dk = Matrix3::new(-sk, -ck, 0.0, ck, -sk, 0.0, 0.0, 0.0, 0.0);
        Rotation {
            r: rw * rp * rk,
            d: [dw * rp * rk, rw * dp * rk, rw * rp * dk],
        }
    }
}

/// Projects ground point `g` through a camera of interior `interior` at exterior `e` (whose
/// rotation is `rot`), with the partials; `None` when the point is not in front of the camera.
pub fn linearise(
    interior: &Interior,
    e: &Exterior,
    rot: &Rotation,
    g: Vector3<f64>,
) -> Option<Linearised> {
    let d = g - Vector3::new(e.centre.x, e.centre.y, e.centre.z);
    let rt = rot.r.transpose();
    let u = rt * d;
    if u.z >= 0.0 {
        return None;
    }
    let c = interior.focal_mm;
    let (k1, k2) = (interior.lens.k1, interior.lens.k2);
    let pp = interior.principal_point;
    let iz = 1.0 / u.z;
    let (a, b) = (u.x * iz, u.y * iz);
    let rho2 = a * a + b * b;
    let dd = 1.0 + rho2 * (k1 + k2 * rho2);
    let kk = k1 + 2.0 * k2 * rho2;
    let xy = Vector2::new(pp.x - c * a * dd, pp.y - c * b * dd);
    // ∂(a, b)/∂u, then ∂(x, y)/∂(a, b).
    let dab = SMatrix::<f64, 2, 3>::new(iz, 0.0, -a * iz, 0.0, iz, -b * iz);
    let m = SMatrix::<f64, 2, 2>::new(
        dd + 2.0 * kk * a * a,
        2.0 * kk * a * b,
        2.0 * kk * a * b,
        dd + 2.0 * kk * b * b,
    ) * -c;
    let du = m * dab;
    let d_ground = du * rt;
    let mut d_exterior = SMatrix::<f64, 2, 6>::zeros();
    for k in 0..3 {
        let col = du * (rot.d[k].transpose() * d);
        d_exterior.set_column(k, &col);
    }
    for k in 0..3 {
        d_exterior.set_column(3 + k, &(-d_ground.column(k)));
    }
    let mut d_interior = SMatrix::<f64, 2, 6>::zeros();
    d_interior.set_column(0, &Vector2::new(-a * dd, -b * dd));
    d_interior[(0, 1)] = 1.0;
    d_interior[(1, 2)] = 1.0;
    d_interior.set_column(3, &Vector2::new(-c * a * rho2, -c * b * rho2));
    d_interior.set_column(4, &Vector2::new(-c * a * rho2 * rho2, -c * b * rho2 * rho2));
    Some(Linearised {
        xy,
        d_exterior,
        d_ground,
        d_interior,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coords::{GroundM, PhotoMm};
    use crate::geometry::{FrameCamera, Interior};

    /// The closed-form partials agree with central differences of the project's own
    /// collinearity ([`FrameCamera::project`], an independent implementation) at a tilted
    /// camera, and the projection itself agrees with it.
    #[test]
    fn partials_match_central_differences_of_the_frame_camera() {
        let interior = Interior {
            focal_mm: 153.0,
            principal_point: PhotoMm::new(0.02, -0.01),
            lens: crate::geometry::Lens {
                k1: 0.03,
                k2: -0.01,
            },
        };
        let e = Exterior::from_degrees(3.0, -4.0, 25.0, GroundM::new(1000.0, 2000.0, 2500.0));
        let g = Vector3::new(1400.0, 1700.0, 350.0);
        let cam = |e: Exterior| FrameCamera {
            interior,
            exterior: e,
        };
        let l = linearise(&interior, &e, &Rotation::of(&e), g).unwrap();
        let p = cam(e).project(GroundM::new(g.x, g.y, g.z)).unwrap();
        assert!((l.xy.x - p.x).abs() < 1e-9 && (l.xy.y - p.y).abs() < 1e-9);
        for k in 0..6 {
            let h = Exterior::STEPS[k];
            let a = cam(e.nudged(k, h))
                .project(GroundM::new(g.x, g.y, g.z))
                .unwrap();
            let b = cam(e.nudged(k, -h))
                .project(GroundM::new(g.x, g.y, g.z))
                .unwrap();
            let num = [(a.x - b.x) / (2.0 * h), (a.y - b.y) / (2.0 * h)];
            for r in 0..2 {
                let tol = 1e-5 * num[r].abs().max(1e-3);
                assert!(
                    (l.d_exterior[(r, k)] - num[r]).abs() < tol,
                    "exterior {k}, row {r}: {} vs {}",
                    l.d_exterior[(r, k)],
                    num[r]
                );
            }
        }
        for k in 0..3 {
            let mut ga = g;
            let mut gb = g;
            ga[k] += 0.01;
            gb[k] -= 0.01;
            let a = cam(e).project(GroundM::new(ga.x, ga.y, ga.z)).unwrap();
            let b = cam(e).project(GroundM::new(gb.x, gb.y, gb.z)).unwrap();
            let num = [(a.x - b.x) / 0.02, (a.y - b.y) / 0.02];
            for r in 0..2 {
                assert!(
                    (l.d_ground[(r, k)] - num[r]).abs() < 1e-7,
                    "ground {k}, row {r}"
                );
            }
        }
        let at = |k: usize, by: f64| {
            let mut i = interior;
            match k {
                0 => i.focal_mm += by,
                1 => i.principal_point.x += by,
                2 => i.principal_point.y += by,
                3 => i.lens.k1 += by,
                _ => i.lens.k2 += by,
            }
            FrameCamera {
                interior: i,
                exterior: e,
            }
            .project(GroundM::new(g.x, g.y, g.z))
            .unwrap()
        };
        for k in 0..5 {
            let h = 1e-4;
            let (a, b) = (at(k, h), at(k, -h));
            let num = [(a.x - b.x) / (2.0 * h), (a.y - b.y) / (2.0 * h)];
            for r in 0..2 {
                let tol = 1e-6 * num[r].abs().max(1e-3);
                assert!(
                    (l.d_interior[(r, k)] - num[r]).abs() < tol,
                    "interior {k}, row {r}: {} vs {}",
                    l.d_interior[(r, k)],
                    num[r]
                );
            }
        }
        // Behind the camera: no projection.
        assert!(linearise(
            &interior,
            &e,
            &Rotation::of(&e),
            Vector3::new(1000.0, 2000.0, 3000.0)
        )
        .is_none());
    }
}
