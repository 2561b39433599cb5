//! The collinearity equations and their partial derivatives in closed form, for the bundle
//! adjustment's Jacobian (the resection's and the matchers' central differences cost two
//! projections a parameter; a block of 200 000 rays is linearised every iteration).
//!
//! With u = Rᵀ(X − C) (docs/conventions.md: R = R_ω·R_φ·R_κ takes image vectors to object
//! space): x = x₀ − c·u₁/u₃, y = y₀ − c·u₂/u₃ (Kraus 2007, "Photogrammetry", eq. 4.1-7).
//! ∂u/∂X = Rᵀ, ∂u/∂C = −Rᵀ, ∂u/∂ω = (∂R/∂ω)ᵀ(X − C) and likewise for φ and κ.

use crate::geometry::Exterior;
use nalgebra::{Matrix3, SMatrix, Vector2, Vector3};

/// One ray's projection and partials: the photo point (mm), ∂(x, y)/∂(ω, φ, κ, X₀, Y₀, Z₀)
/// (mm per rad, per m) and ∂(x, y)/∂(X, Y, Z) (mm per m).
#[derive(Debug, Clone, Copy)]
pub struct Linearised {
    pub xy: Vector2<f64>,
    pub d_exterior: SMatrix<f64, 2, 6>,
    pub d_ground: SMatrix<f64, 2, 3>,
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

/// Projects ground point `g` through a camera of focal length `focal_mm` and principal point
/// `pp` (mm) at exterior `e` (whose rotation is `rot`), with the partials; `None` when the
/// point is not in front of the camera.
pub fn linearise(
    focal_mm: f64,
    pp: [f64; 2],
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
    let c = focal_mm;
    let iz = 1.0 / u.z;
    let xy = Vector2::new(pp[0] - c * u.x * iz, pp[1] - c * u.y * iz);
    // ∂(x, y)/∂u.
    let du = SMatrix::<f64, 2, 3>::new(
        -c * iz,
        0.0,
        c * u.x * iz * iz,
        0.0,
        -c * iz,
        c * u.y * iz * iz,
    );
    let d_ground = du * rt;
    let mut d_exterior = SMatrix::<f64, 2, 6>::zeros();
    for k in 0..3 {
        let col = du * (rot.d[k].transpose() * d);
        d_exterior.set_column(k, &col);
    }
    for k in 0..3 {
        d_exterior.set_column(3 + k, &(-d_ground.column(k)));
    }
    Some(Linearised {
        xy,
        d_exterior,
        d_ground,
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
        };
        let e = Exterior::from_degrees(3.0, -4.0, 25.0, GroundM::new(1000.0, 2000.0, 2500.0));
        let g = Vector3::new(1400.0, 1700.0, 350.0);
        let cam = |e: Exterior| FrameCamera {
            interior,
            exterior: e,
        };
        let l = linearise(153.0, [0.02, -0.01], &e, &Rotation::of(&e), g).unwrap();
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
        // Behind the camera: no projection.
        assert!(linearise(
            153.0,
            [0.0, 0.0],
            &e,
            &Rotation::of(&e),
            Vector3::new(1000.0, 2000.0, 3000.0)
        )
        .is_none());
    }
}
