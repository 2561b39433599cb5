//! Atmospheric refraction and the Earth's curvature as radial displacements of a frame photo's
//! image points: what makes a real photo differ from collinearity in a map's coordinates.
//!
//! Both move an image point along its radius from the principal point (the nadir of a
//! near-vertical photo), by an amount that depends on its radial distance r, the focal length
//! c, the camera's height Z₀ and the ground's height h:
//!
//! - **Earth curvature.** A map's X, Y with heights above a curved datum are not Cartesian: a
//!   point at distance d from the nadir lies d²/(2R) below the tangent plane the collinearity
//!   equations assume. Seen from the camera, that is a height error, which moves the image point
//!   inward by Δr = r³·(Z₀ − h) / (2·R·c²) (Kraus 2007, "Photogrammetry" §4.4; Wolf & Dewitt
//!   2000, "Elements of Photogrammetry" §D-6), R = 6 371 km.
//! - **Refraction.** The air's density falls with height, so a ray bends toward the vertical
//!   on its way up and the point appears farther from the nadir: Δr = K·(r + r³/c²) outward,
//!   with K (rad) from Bertram's model of the ARDC standard atmosphere (ASPRS "Manual of
//!   Photogrammetry", 4th ed.; Wolf & Dewitt eq. D-19):
//!   K = [2410·H/(H² − 6H + 250) − 2410·h²/((h² − 4h + 250)·H)]·10⁻⁶, H and h in km.
//!
//! When they matter: at 1:40 000 with a 153 mm camera (6.1 km above the ground) an image
//! corner (r = 150 mm) moves by 69 µm for curvature (2.8 m on the ground) and 15 µm for
//! refraction; at 1:5 000 (0.8 km) by 9 µm and 2 µm. They are systematic, the same in every
//! photo, and shift and bend the whole block's heights; a lab orienting small-scale film turns
//! them on. The rig's simulator and the validation renderer render a flat world without air,
//! so they are off by default.

use crate::coords::PhotoMm;
use serde::{Deserialize, Serialize};

/// The Earth's mean radius, m.
pub const EARTH_RADIUS_M: f64 = 6_371_000.0;

/// How a point is seen: the camera's principal point and focal length (mm), its height and the
/// ground's (m), all the displacements depend on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Seen {
    pub principal_point: PhotoMm,
    pub focal_mm: f64,
    pub camera_m: f64,
    pub ground_m: f64,
}

impl Seen {
    /// A camera of `interior` at height `camera_m` seeing ground at `ground_m`.
    pub fn of(interior: &super::Interior, camera_m: f64, ground_m: f64) -> Seen {
        Seen {
            principal_point: interior.principal_point,
            focal_mm: interior.focal_mm,
            camera_m,
            ground_m,
        }
    }
}

/// Which radial displacements a frame photo's geometry applies.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Radial {
    pub refraction: bool,
    pub earth_curvature: bool,
}

/// Refraction's K, rad, for a camera at `camera_m` and ground at `ground_m` above sea level
/// (Bertram's model, above); 0 where the camera is not above the ground.
pub fn refraction_k(camera_m: f64, ground_m: f64) -> f64 {
    let (hh, h) = (camera_m / 1000.0, ground_m / 1000.0);
    if hh <= h || hh <= 0.0 {
        return 0.0;
    }
    (2410.0 * hh / (hh * hh - 6.0 * hh + 250.0) - 2410.0 * h * h / ((h * h - 4.0 * h + 250.0) * hh))
        * 1e-6
}

impl Radial {
    pub fn any(self) -> bool {
        self.refraction || self.earth_curvature
    }

    /// The outward radial displacement, mm, of an image point at radius `r_mm` (from the
    /// principal point) of a camera of focal length `c_mm` at height `camera_m`, seeing
    /// ground at `ground_m`.
    pub fn displacement_mm(self, r_mm: f64, c_mm: f64, camera_m: f64, ground_m: f64) -> f64 {
        let r3 = r_mm * r_mm * r_mm / (c_mm * c_mm);
        let mut d = 0.0;
        if self.refraction {
            d += refraction_k(camera_m, ground_m) * (r_mm + r3);
        }
        if self.earth_curvature {
            d -= r3 * (camera_m - ground_m).max(0.0) / (2.0 * EARTH_RADIUS_M);
        }
        d
    }

    /// Where the photo shows the point that collinearity puts at `ideal`.
    pub fn distort(self, ideal: PhotoMm, at: &Seen) -> PhotoMm {
        if !self.any() {
            return ideal;
        }
        let pp = at.principal_point;
        let (x, y) = (ideal.x - pp.x, ideal.y - pp.y);
        let r = x.hypot(y);
        if r == 0.0 {
            return ideal;
        }
        let s = 1.0 + self.displacement_mm(r, at.focal_mm, at.camera_m, at.ground_m) / r;
        PhotoMm::new(pp.x + s * x, pp.y + s * y)
    }

    /// The collinearity point of an observed `p`: [`Radial::distort`] inverted (a few
    /// fixed-point steps; the displacement is some 10⁻⁴ of r, each step gains four digits).
    pub fn undistort(self, p: PhotoMm, at: &Seen) -> PhotoMm {
        if !self.any() {
            return p;
        }
        let mut q = p;
        for _ in 0..4 {
            let d = self.distort(q, at);
            q = PhotoMm::new(q.x + (p.x - d.x), q.y + (p.y - d.y));
        }
        q
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// Earth curvature against a sphere: a vertical camera 6 km above a spherical Earth sees a
    /// point on the sphere at arc distance s from its nadir; a map gives that point X = s,
    /// Z = 0. (At a height h the sphere's horizontal also grows by s·h/R: the map's scale at
    /// that height, not curvature.)
    /// Collinearity on the map's flat coordinates puts it at r_flat = c·s/(Z₀ − h); the true
    /// direction (the sphere's geometry, no formula of this module) at r_true. Their difference
    /// is the closed form's −r³(Z₀ − h)/(2Rc²) to 1 % (the closed form keeps the first order
    /// in s/R).
    #[test]
    fn curvature_is_the_spheres_geometry() {
        let (c, z0, h) = (153.0, 6000.0, 0.0);
        let corr = Radial {
            refraction: false,
            earth_curvature: true,
        };
        for s in [1000.0, 3000.0, 6000.0] {
            let r_flat = c * s / (z0 - h);
            // On the sphere: centre at (0, −R); the point at angle s/R.
            let a = s / EARTH_RADIUS_M;
            let p = Vector3::new(
                (EARTH_RADIUS_M + h) * a.sin(),
                0.0,
                (EARTH_RADIUS_M + h) * a.cos() - EARTH_RADIUS_M,
            );
            let r_true = c * p.x / (z0 - p.z);
            let want = r_true - r_flat;
            let got = corr.displacement_mm(r_flat, c, z0, h);
            assert!(
                (got - want).abs() < 0.01 * want.abs(),
                "s {s} m: {got:.5} mm, the sphere {want:.5} mm"
            );
        }
        // The figure: at 1:40 000 (c = 153 mm, 6120 m above the ground) an image
        // corner (r = 150 mm) moves by metres on the ground.
        let d = corr.displacement_mm(150.0, 153.0, 6620.0, 500.0);
        let on_ground = d.abs() / 153.0 * 6120.0;
        assert!((2.5..3.0).contains(&on_ground), "{on_ground:.2} m");
    }

    /// Refraction's K against first principles: in a flatly layered atmosphere Snell's law
    /// (n·sin θ constant) bends a ray so that it meets the camera δ = K·tan θ off its chord,
    /// K = mean over the path of (n(z) − n(Z₀)) / n(Z₀); n − 1 from Smith and Weintraub's
    /// 77.6·P/T·10⁻⁶ (dry air, P in hPa, T in K) in the ICAO standard atmosphere, integrated
    /// numerically. Bertram's polynomial fits another standard atmosphere (ARDC 1959): within
    /// 25 % of the integral from 1.5 to 9 km, which is what a standard atmosphere knows of
    /// the day's weather anyway.
    #[test]
    fn refraction_follows_snells_law_in_a_standard_atmosphere() {
        let refractivity = |z: f64| {
            let t = 288.15 - 0.0065 * z;
            let p = 1013.25 * (t / 288.15).powf(5.2559);
            77.6 * p / t * 1e-6
        };
        let integral = |camera: f64, ground: f64| {
            let m = 4000;
            let mean = (0..m)
                .map(|i| refractivity(ground + (camera - ground) * (i as f64 + 0.5) / m as f64))
                .sum::<f64>()
                / m as f64;
            (mean - refractivity(camera)) / (1.0 + refractivity(camera))
        };
        for (camera, ground) in [
            (1500.0, 0.0),
            (3000.0, 0.0),
            (6000.0, 0.0),
            (9000.0, 0.0),
            (7000.0, 500.0),
            (2500.0, 600.0),
            (4000.0, 1000.0),
        ] {
            let (k, want) = (refraction_k(camera, ground), integral(camera, ground));
            assert!(
                (k / want - 1.0).abs() < 0.25,
                "camera {camera} m, ground {ground} m: K {:.2} µrad, Snell's {:.2} µrad",
                k * 1e6,
                want * 1e6
            );
        }
        let corr = Radial {
            refraction: true,
            earth_curvature: false,
        };
        assert!(corr.displacement_mm(100.0, 153.0, 6000.0, 300.0) > 0.0);
        assert_eq!(corr.displacement_mm(0.0, 153.0, 6000.0, 300.0), 0.0);
        // Distort and undistort are inverse to 10⁻⁹ mm.
        let both = Radial {
            refraction: true,
            earth_curvature: true,
        };
        let pp = PhotoMm::new(0.01, -0.02);
        let p = PhotoMm::new(93.0, -121.0);
        let at = Seen {
            principal_point: pp,
            focal_mm: 153.0,
            camera_m: 7000.0,
            ground_m: 400.0,
        };
        let d = both.distort(p, &at);
        let back = both.undistort(d, &at);
        assert!((back.x - p.x).abs() < 1e-9 && (back.y - p.y).abs() < 1e-9);
        assert!((d.x - p.x).abs() > 1e-3);
    }

    /// A frame sensor with the displacements puts a ground point where collinearity does,
    /// moved along its radius by [`Radial::displacement_mm`], and takes it back to the same
    /// ground at its height.
    #[test]
    fn a_frame_sensor_displaces_and_returns() {
        use crate::coords::GroundM;
        use crate::geometry::{Exterior, FrameCamera, FrameSensor, Interior, Sensor};
        let both = Radial {
            refraction: true,
            earth_curvature: true,
        };
        let mut s = FrameSensor {
            camera: FrameCamera {
                interior: Interior {
                    focal_mm: 153.0,
                    principal_point: PhotoMm::new(0.0, 0.0),
                    lens: crate::geometry::Lens::NONE,
                },
                exterior: Exterior::from_degrees(0.3, -0.2, 1.0, GroundM::new(0.0, 0.0, 6500.0)),
            },
            frame: crate::matching::block::photo::centred_grid(9000, 9000, 0.025).into(),
            exterior_cov: None,
            radial: Radial::default(),
        };
        let g = GroundM::new(3500.0, -2800.0, 420.0);
        let flat = s.ground_to_image(g).unwrap();
        s.radial = both;
        let q = s.ground_to_image(g).unwrap();
        let p = s.camera.project(g).unwrap();
        let r = p.x.hypot(p.y);
        let want_px = both.displacement_mm(r, 153.0, 6500.0, 420.0) / 0.025;
        let moved = (q.col - flat.col).hypot(q.row - flat.row);
        assert!(
            (moved - want_px.abs()).abs() < 1e-6,
            "{moved} px, {want_px} px"
        );
        let back = s.image_to_ground(q, g.z).unwrap();
        assert!((back.x - g.x).abs() < 1e-6 && (back.y - g.y).abs() < 1e-6);
    }
}
