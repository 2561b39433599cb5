//! The frame camera: interior orientation (focal length, principal point) and exterior
//! orientation (ω, φ, κ and the projection centre), the collinearity equations and the ray
//! through a photo point.
//!
//! Rotation R = R_ω·R_φ·R_κ takes image-space vectors to object space; collinearity:
//! x − x₀ = −c·(r₁₁ΔX + r₂₁ΔY + r₃₁ΔZ)/(r₁₃ΔX + r₂₃ΔY + r₃₃ΔZ), likewise y with the second
//! column (ΔX = X − X₀ …).

use super::lens::Lens;
use crate::coords::{GroundM, PhotoMm};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Interior {
    pub focal_mm: f64,
    pub principal_point: PhotoMm,
    /// Radial distortion ([`super::lens`]); none for the rig's scans and the simulator.
    #[serde(default, skip_serializing_if = "Lens::is_none")]
    pub lens: Lens,
}

impl Interior {
    /// c, x₀, y₀ (mm), k₁, k₂: the parameters a self-calibration estimates, in its order.
    pub fn parameters(&self) -> [f64; 5] {
        [
            self.focal_mm,
            self.principal_point.x,
            self.principal_point.y,
            self.lens.k1,
            self.lens.k2,
        ]
    }
}

/// Exterior orientation; angles in radians.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Exterior {
    pub omega: f64,
    pub phi: f64,
    pub kappa: f64,
    pub centre: GroundM,
}

impl Exterior {
    /// The central-difference steps for partials by its parameters ω, φ, κ, X0, Y0, Z0: 10
    /// µrad and 1 cm, well inside the linear range and well above rounding.
    pub const STEPS: [f64; 6] = [1e-5, 1e-5, 1e-5, 0.01, 0.01, 0.01];

    /// This orientation with its parameter `k` (ω, φ, κ, X0, Y0, Z0 in that order; rad and
    /// m) moved by `by`.
    pub fn nudged(&self, k: usize, by: f64) -> Exterior {
        let mut e = *self;
        match k {
            0 => e.omega += by,
            1 => e.phi += by,
            2 => e.kappa += by,
            3 => e.centre.x += by,
            4 => e.centre.y += by,
            _ => e.centre.z += by,
        }
        e
    }

    pub fn from_degrees(omega: f64, phi: f64, kappa: f64, centre: GroundM) -> Self {
        Exterior {
            omega: omega.to_radians(),
            phi: phi.to_radians(),
            kappa: kappa.to_radians(),
            centre,
        }
    }

    /// R_ω·R_φ·R_κ. The matchers project millions of points through two or three photos,
    /// and three sines and cosines per point were half the object-space matching's time: the
    /// last few rotations each thread made are kept, keyed by the angles' exact bits (an
    /// exterior changed in place is simply a new key).
    pub fn rotation(&self) -> Matrix3<f64> {
        const KEPT: usize = 4;
        type Kept = ([Option<([u64; 3], Matrix3<f64>)>; KEPT], usize);
        thread_local! {
            static RECENT: std::cell::RefCell<Kept> =
                const { std::cell::RefCell::new(([None; KEPT], 0)) };
        }
        let key = [
            self.omega.to_bits(),
            self.phi.to_bits(),
            self.kappa.to_bits(),
        ];
        RECENT.with(|c| {
            let Ok(mut kept) = c.try_borrow_mut() else {
                return self.rotation_computed();
            };
            if let Some((_, r)) = kept.0.iter().flatten().find(|(k, _)| *k == key) {
                return *r;
            }
            let r = self.rotation_computed();
            let next = kept.1;
            kept.0[next] = Some((key, r));
            kept.1 = (next + 1) % KEPT;
            r
        })
    }

    fn rotation_computed(&self) -> Matrix3<f64> {
        let (so, co) = self.omega.sin_cos();
        let (sp, cp) = self.phi.sin_cos();
        let (sk, ck) = self.kappa.sin_cos();
        let rw = Matrix3::new(1.0, 0.0, 0.0, 0.0, co, -so, 0.0, so, co);
        let rp = Matrix3::new(cp, 0.0, sp, 0.0, 1.0, 0.0, -sp, 0.0, cp);
        let rk = Matrix3::new(ck, -sk, 0.0, sk, ck, 0.0, 0.0, 0.0, 1.0);
        rw * rp * rk
    }
}

#[cfg(test)]
mod rotation_tests {
    use super::*;

    /// The kept rotations are the computed ones, for more exteriors than are kept, in any
    /// order, and a changed angle is not served an old matrix.
    #[test]
    fn kept_rotations_are_the_computed_ones() {
        let centre = GroundM::new(0.0, 0.0, 1000.0);
        let es: Vec<Exterior> = (0..7)
            .map(|k| Exterior::from_degrees(k as f64, -2.0 * k as f64, 0.5 + k as f64, centre))
            .collect();
        for round in 0..3 {
            for (i, e) in es.iter().enumerate().rev().skip(round) {
                assert_eq!(e.rotation(), e.rotation_computed(), "exterior {i}");
            }
        }
        let mut e = es[0];
        let before = e.rotation();
        e.kappa += 1e-12;
        assert_ne!(e.rotation(), before);
        assert_eq!(e.rotation(), e.rotation_computed());
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameCamera {
    pub interior: Interior,
    pub exterior: Exterior,
}

impl FrameCamera {
    /// Collinearity: where ground point `g` appears in the photo. `None` behind the camera.
    pub fn project(&self, g: GroundM) -> Option<PhotoMm> {
        let r = self.exterior.rotation();
        let c = self.exterior.centre;
        let v = r.transpose() * Vector3::new(g.x - c.x, g.y - c.y, g.z - c.z);
        if v.z >= 0.0 {
            return None;
        }
        let f = self.interior.focal_mm;
        let pp = self.interior.principal_point;
        let d = self
            .interior
            .lens
            .distort([-f * v.x / v.z, -f * v.y / v.z], f);
        Some(PhotoMm::new(pp.x + d[0], pp.y + d[1]))
    }

    /// The ray through photo point `p`: the projection centre and a unit direction.
    pub fn ray(&self, p: PhotoMm) -> (Vector3<f64>, Vector3<f64>) {
        let pp = self.interior.principal_point;
        let f = self.interior.focal_mm;
        let u = self.interior.lens.undistort([p.x - pp.x, p.y - pp.y], f);
        let d = self.exterior.rotation() * Vector3::new(u[0], u[1], -f);
        let c = self.exterior.centre;
        (Vector3::new(c.x, c.y, c.z), d.normalize())
    }

    /// Where the ray through `p` reaches height `z`.
    pub fn at_height(&self, p: PhotoMm, z: f64) -> GroundM {
        let (o, d) = self.ray(p);
        let t = (z - o.z) / d.z;
        GroundM::new(o.x + t * d.x, o.y + t * d.y, z)
    }
}
