//! The pushbroom (SPOT-like) line scanner as a rigorous sensor (seed 004 §3, Kratky's model;
//! seed 001 on SPOT): a linear array across the track, one image line per instant, each line
//! with its own position and attitude.
//!
//! Frames, stated once:
//! - **ground**: the project's frame (X east, Y north, Z up, metres); the orbit is given in it
//!   directly (the flat-Earth frame of a scene some tens of km wide; a real satellite's
//!   geocentric orbit enters the rig as an RPC instead).
//! - **orbital** at time t: e₁ the horizontal direction of flight (the velocity with its
//!   vertical part removed), e₃ up, e₂ = e₃ × e₁ (left of the track).
//! - **body**: the orbital frame turned by the attitude, R_att = R_x(roll)·R_y(pitch)·R_z(yaw).
//! - **sensor**: the body frame turned by the mirror, R_m = R_y(−tilt_along)·R_x(−tilt_across);
//!   the array lies along the sensor's y axis, detector u = (col − c₀)/f looks along
//!   (0, u, −1). Columns run to the left of the flight direction, so that the image, its
//!   rows running with time, shows the ground as a map does (not mirrored) whichever way the
//!   satellite flies: north up and east right on a descending (southbound) pass, as SPOT's
//!   scenes. A positive across-track tilt looks right of the flight direction, a positive
//!   along-track tilt forward.
//!
//! Rows are time: the continuous row r (corner origin, as everywhere in the core) is taken at
//! t = (r − lines/2)·line period, so t = 0 at the scene's middle line.

use super::convergence::{ulp, Convergence};
use super::ProjectionError;
use crate::coords::{GroundM, PixelXY};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// Newton's iterations for the line of a ground point: each costs two evaluations of the
/// scan plane; the plane's offset is almost linear in time, so 3 to 4 suffice.
const MAX_ITERATIONS: usize = 30;
/// Converged when the last step is below this many lines.
const ROW_TOLERANCE: f64 = 1e-9;
/// Rows this many image heights beyond the image are refused: the orbit's polynomials are
/// not extrapolated that far.
const ROW_MARGIN: f64 = 2.0;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pushbroom {
    /// Detectors of the array (columns) and lines (rows) of the image.
    pub columns: usize,
    pub lines: usize,
    /// Seconds between two lines.
    pub line_period_s: f64,
    /// Focal length over the detector pitch, pixels.
    pub focal_px: f64,
    /// Column (continuous, corner origin) of the detector on the optical axis.
    pub principal_col: f64,
    /// The mirror's tilt across the track, rad (+: right of the flight direction; SPOT: ±27°).
    pub tilt_across: f64,
    /// The tilt along the track, rad (+: forward, as a fore-looking stereo camera).
    pub tilt_along: f64,
    /// Position X, Y, Z (m, ground frame) as polynomials in t (s): `position[axis][power]`.
    pub position: [[f64; 3]; 3],
    /// Roll, pitch, yaw (rad) as polynomials in t: `attitude[angle][power]`.
    pub attitude: [[f64; 3]; 3],
}

fn poly(c: [f64; 3], t: f64) -> f64 {
    c[0] + t * (c[1] + t * c[2])
}

fn rot_x(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}

fn rot_y(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}

fn rot_z(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

impl Pushbroom {
    /// The ranges every field must lie in, with the field named: a model from a file is
    /// checked before it is used.
    pub fn check(&self) -> Result<(), String> {
        const MAX_SIDE: usize = 200_000;
        if !(1..=MAX_SIDE).contains(&self.columns) || !(1..=MAX_SIDE).contains(&self.lines) {
            return Err(format!(
                "columns and lines must be 1 … {MAX_SIDE} (got {} × {})",
                self.columns, self.lines
            ));
        }
        let positive = [
            ("line_period_s", self.line_period_s, 1e-7, 10.0),
            ("focal_px", self.focal_px, 1.0, 1e7),
        ];
        for (name, v, lo, hi) in positive {
            if !(lo..=hi).contains(&v) {
                return Err(format!("{name} must be {lo:e} … {hi:e} (got {v})"));
            }
        }
        let limit = 45f64.to_radians();
        for (name, v) in [
            ("tilt_across", self.tilt_across),
            ("tilt_along", self.tilt_along),
        ] {
            if v.is_nan() || v.abs() > limit {
                return Err(format!("{name} must be within ±45° (got {v} rad)"));
            }
        }
        let span = self.columns as f64;
        if self.principal_col.is_nan() || self.principal_col.abs() > 10.0 * span {
            return Err(format!(
                "principal_col must be within ±10 image widths (got {})",
                self.principal_col
            ));
        }
        let all = self.position.iter().chain(&self.attitude).flatten();
        if all.clone().any(|v| !v.is_finite()) {
            return Err("position and attitude coefficients must be finite numbers".into());
        }
        // Over the whole span the model is used for (the image and its margin): the sensor
        // moves, its attitude stays within ±45°, its height within −1 km … 100 000 km.
        let span = (0.5 + ROW_MARGIN) * self.lines as f64 * self.line_period_s;
        let v0 = self.velocity(0.0).xy();
        for k in 0..=8 {
            let t = span * (k as f64 / 4.0 - 1.0);
            let v = self.velocity(t).xy();
            // Moving, and within 60° of the direction at the image's centre.
            if v.norm() < 1e-3 || v.dot(&v0) < 0.5 * v.norm() * v0.norm() {
                return Err(format!(
                    "the orbit must move horizontally and steadily over the image (at t = {t:.3} s it stands still or turns away: check position's linear and quadratic terms)"
                ));
            }
            for (name, c) in ["roll", "pitch", "yaw"].iter().zip(&self.attitude) {
                let a = poly(*c, t);
                if a.abs() > limit {
                    return Err(format!(
                        "attitude {name} must stay within ±45° over the image (it reaches {a:.3} rad at t = {t:.3} s)"
                    ));
                }
            }
            let z = self.position(t).z;
            if !(-1e3..=1e8).contains(&z) {
                return Err(format!(
                    "the sensor's height must stay within -1 km … 100 000 km over the image (it reaches {z:.0} m at t = {t:.3} s)"
                ));
            }
        }
        Ok(())
    }

    /// Time of continuous row `row`, s.
    pub fn time(&self, row: f64) -> f64 {
        (row - self.lines as f64 / 2.0) * self.line_period_s
    }

    /// Continuous row taken at time `t`.
    pub fn row(&self, t: f64) -> f64 {
        t / self.line_period_s + self.lines as f64 / 2.0
    }

    pub fn position(&self, t: f64) -> Vector3<f64> {
        let p = &self.position;
        Vector3::new(poly(p[0], t), poly(p[1], t), poly(p[2], t))
    }

    pub fn velocity(&self, t: f64) -> Vector3<f64> {
        let d = |c: [f64; 3]| c[1] + 2.0 * c[2] * t;
        let p = &self.position;
        Vector3::new(d(p[0]), d(p[1]), d(p[2]))
    }

    /// The sensor's axes in the ground frame at time `t` (columns: x along the scan plane's
    /// normal, y along the array, z against the optical axis): E·R_att·R_m.
    pub fn rotation(&self, t: f64) -> Matrix3<f64> {
        let v = self.velocity(t);
        let e1 = Vector3::new(v.x, v.y, 0.0).normalize();
        let e3 = Vector3::z();
        let e2 = e3.cross(&e1);
        let orbital = Matrix3::from_columns(&[e1, e2, e3]);
        let a = &self.attitude;
        let att = rot_x(poly(a[0], t)) * rot_y(poly(a[1], t)) * rot_z(poly(a[2], t));
        let mirror = rot_y(-self.tilt_along) * rot_x(-self.tilt_across);
        orbital * att * mirror
    }

    /// The ground point in the sensor frame at time `t`.
    fn in_sensor(&self, g: &Vector3<f64>, t: f64) -> Vector3<f64> {
        self.rotation(t).transpose() * (g - self.position(t))
    }

    /// The time at which `g` lies in the scan plane (the sensor's x = 0), by Newton's method
    /// with the derivative over one line period; converged by [`Convergence`] (below
    /// [`ROW_TOLERANCE`] lines, or the resolution of the coordinates); an error if it does
    /// not within [`MAX_ITERATIONS`] or leaves the orbit's valid span.
    pub fn time_of(&self, g: GroundM) -> Result<f64, ProjectionError> {
        let gv = Vector3::new(g.x, g.y, g.z);
        // Start where the nadir passes the point, shifted by the along-track look.
        let v0 = self.velocity(0.0);
        let speed = v0.xy().norm();
        let along = Vector3::new(v0.x, v0.y, 0.0) / speed;
        let p0 = self.position(0.0);
        let height = (p0.z - g.z).max(0.0);
        let mut t = ((gv - p0).dot(&along) - height * self.tilt_along.tan()) / speed;
        let h = self.line_period_s;
        let span = (0.5 + ROW_MARGIN) * self.lines as f64 * h;
        let mut test = Convergence::new(ROW_TOLERANCE);
        for _ in 0..MAX_ITERATIONS {
            let f = self.in_sensor(&gv, t).x;
            let slope = (self.in_sensor(&gv, t + h).x - f) / h;
            if !(slope.is_finite() && f.is_finite()) || slope >= 0.0 {
                return Err(ProjectionError::Model(
                    "the point never crosses the scan plane (the orbit turns away from it)",
                ));
            }
            let step = -f / slope;
            t += step;
            if !t.is_finite() || t.abs() > span {
                return Err(ProjectionError::Model(
                    "the point is seen beyond the orbit's valid span (two image heights past the image)",
                ));
            }
            // The scan plane's offset resolves a unit in the last place of the coordinates.
            let scale = gv.amax().max(self.position(t).amax());
            if test.done(step.abs() / h, ulp(scale) / (slope.abs() * h)) {
                return Ok(t);
            }
        }
        Err(ProjectionError::NoConvergence {
            iterations: MAX_ITERATIONS,
            last_px: test.last_px,
        })
    }
}

impl super::Sensor for Pushbroom {
    fn image_size(&self) -> (usize, usize) {
        (self.columns, self.lines)
    }

    fn try_ground_to_image(&self, g: GroundM) -> Result<PixelXY, ProjectionError> {
        let t = self.time_of(g)?;
        let s = self.in_sensor(&Vector3::new(g.x, g.y, g.z), t);
        if s.z >= 0.0 {
            return Err(ProjectionError::Behind);
        }
        // s ∝ (0, u, −1).
        let u = -s.y / s.z;
        Ok(PixelXY::new(
            self.principal_col + self.focal_px * u,
            self.row(t),
        ))
    }

    fn try_image_to_ground(&self, q: PixelXY, z: f64) -> Result<GroundM, ProjectionError> {
        let t = self.time(q.row);
        let u = (q.col - self.principal_col) / self.focal_px;
        let d = self.rotation(t) * Vector3::new(0.0, u, -1.0);
        let p = self.position(t);
        let lambda = (z - p.z) / d.z;
        if !lambda.is_finite() || lambda <= 0.0 {
            return Err(ProjectionError::HeightNotReached { z });
        }
        let g = p + lambda * d;
        if [g.x, g.y].iter().all(|v| v.is_finite()) {
            Ok(GroundM::new(g.x, g.y, z))
        } else {
            Err(ProjectionError::HeightNotReached { z })
        }
    }
}

/// The line scanner the core's unit tests share.
#[cfg(test)]
pub(crate) mod fixtures {
    use super::Pushbroom;

    /// A SPOT-like view: 830 km up, 10 m pixels, 3000 × 3000, flown north over UTM zone 16
    /// (EPSG:32616), looking right (east) by `tilt_across_deg` at (746 800, 4 055 840), so
    /// its track lies west of the scene; a curved orbit and a drifting attitude (the
    /// quadratic model of seed 004's rigorous solution).
    pub fn spot_like(tilt_across_deg: f64) -> Pushbroom {
        let h = 830_000.0;
        let tilt = tilt_across_deg.to_radians();
        Pushbroom {
            columns: 3000,
            lines: 3000,
            line_period_s: 10.0 / 6600.0,
            focal_px: 83_000.0 / tilt.cos(),
            principal_col: 1500.0,
            tilt_across: tilt,
            tilt_along: 0.0,
            position: [
                [746_800.0 - h * tilt.tan(), 900.0, 0.4],
                [4_055_840.0, 6540.0, -0.2],
                [h, -8.0, 0.01],
            ],
            attitude: [[1e-4, 3e-6, 1e-8], [-2e-4, -1e-6, 0.0], [2e-3, 5e-7, 0.0]],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Sensor;

    /// SPOT-like: 830 km up, 6.6 km/s over the ground, 10 m pixels (f = 83 000 px).
    fn straight(tilt_across_deg: f64, tilt_along_deg: f64) -> Pushbroom {
        Pushbroom {
            columns: 3000,
            lines: 3000,
            line_period_s: 10.0 / 6600.0,
            focal_px: 83_000.0,
            principal_col: 1500.0,
            tilt_across: tilt_across_deg.to_radians(),
            tilt_along: tilt_along_deg.to_radians(),
            position: [
                [500_000.0, 6600.0, 0.0],
                [4_000_000.0, 0.0, 0.0],
                [830_000.0, 0.0, 0.0],
            ],
            attitude: [[0.0; 3]; 3],
        }
    }

    /// A straight orbit along +X at constant height with no attitude is a cylinder
    /// perspective: along the track the row is the time the scan plane reaches the point,
    /// X − X₀ − v·t = tan θ·(H − Z); across it col = c₀ − f·tan(ψ − β), ψ = atan(y_right/(H − Z))
    /// (columns run to the left of the track).
    #[test]
    fn a_straight_orbit_is_the_cylinder_perspective() {
        for (beta, theta) in [
            (0.0, 0.0),
            (27.0, 0.0),
            (-27.0, 0.0),
            (0.0, 20.0),
            (0.0, -20.0),
        ] {
            let s = straight(beta, theta);
            let (b, th) = (beta.to_radians(), theta.to_radians());
            let (h, v) = (830_000.0, 6600.0);
            for (dx, dy, z) in [
                (0.0, 0.0, 0.0),
                (4000.0, -9000.0, 1500.0),
                (-12000.0, 8000.0, 300.0),
            ] {
                // Place the point where the tilted view sees it, near the image's middle.
                let y_right = -dy + (h - z) * b.tan();
                let x = 500_000.0 + dx + (h - z) * th.tan();
                let g = GroundM::new(x, 4_000_000.0 - y_right, z);
                let q = s.ground_to_image(g).unwrap();
                let t = (x - 500_000.0 - th.tan() * (h - z)) / v;
                let psi = (y_right / (h - z)).atan();
                // The along-track tilt lengthens the slant range: the array sees
                // y_right/(H − Z) scaled by cos θ.
                let psi = (psi.tan() * th.cos()).atan();
                let want = PixelXY::new(1500.0 - 83_000.0 * (psi - b).tan(), s.row(t));
                assert!(
                    q.dist(want) < 1e-6,
                    "tilts {beta}°, {theta}°, point {g:?}: {q:?} vs {want:?}"
                );
                let back = s.image_to_ground(q, z).unwrap();
                assert!((back.x - g.x).abs() < 1e-4 && (back.y - g.y).abs() < 1e-4);
            }
        }
    }

    /// With a curved orbit, drifting attitude and both tilts, image → ground → image comes
    /// back to the pixel over the whole image and at several heights.
    #[test]
    fn image_to_ground_and_back_round_trips_with_attitude_and_curvature() {
        let mut s = straight(15.0, -10.0);
        s.position[0][2] = 0.8;
        s.position[1][1] = 900.0;
        s.position[2][1] = -12.0;
        s.attitude = [[1e-4, 2e-6, 1e-8], [-2e-4, -1e-6, 0.0], [3e-4, 5e-7, 0.0]];
        s.check().unwrap();
        for r in [0.0, 700.5, 1500.0, 2999.9] {
            for c in [0.0, 1234.5, 2999.9] {
                for z in [-100.0, 800.0, 4000.0] {
                    let q = PixelXY::new(c, r);
                    let g = s.image_to_ground(q, z).unwrap();
                    let back = s.ground_to_image(g).unwrap();
                    assert!(q.dist(back) < 1e-6, "{q:?} at {z} m → {g:?} → {back:?}");
                }
            }
        }
    }

    /// A southbound pass shows the ground as a map does: east to the right, north up.
    #[test]
    fn a_descending_pass_is_not_mirrored() {
        let mut s = straight(10.0, 0.0);
        s.position[0] = [500_000.0, 0.0, 0.0];
        s.position[1] = [4_000_000.0, -6600.0, 0.0];
        let c = s
            .ground_to_image(GroundM::new(500_000.0, 4e6, 0.0))
            .unwrap();
        let e = s
            .ground_to_image(GroundM::new(500_100.0, 4e6, 0.0))
            .unwrap();
        let n = s
            .ground_to_image(GroundM::new(500_000.0, 4e6 + 100.0, 0.0))
            .unwrap();
        assert!(
            e.col > c.col + 5.0 && (e.row - c.row).abs() < 0.5,
            "{c:?} {e:?}"
        );
        assert!(
            n.row < c.row - 5.0 && (n.col - c.col).abs() < 0.5,
            "{c:?} {n:?}"
        );
    }

    /// Above the satellite nothing is seen, and models out of range are refused by name.
    #[test]
    fn impossible_points_and_models_are_refused() {
        let s = straight(0.0, 0.0);
        assert!(s
            .ground_to_image(GroundM::new(500_000.0, 4e6, 900_000.0))
            .is_none());
        assert!(s
            .image_to_ground(PixelXY::new(10.0, 10.0), 900_000.0)
            .is_none());
        // Far beyond the orbit's span along the track.
        assert!(s.ground_to_image(GroundM::new(9e6, 4e6, 0.0)).is_none());
        let mut bad = s;
        bad.tilt_across = 1.0;
        assert!(bad.check().unwrap_err().contains("tilt_across"));
        let mut bad = s;
        bad.line_period_s = f64::NAN;
        assert!(bad.check().unwrap_err().contains("line_period_s"));
        let mut bad = s;
        bad.position[0][1] = 0.0;
        assert!(bad.check().unwrap_err().contains("move horizontally"));
        let mut bad = s;
        bad.attitude[2][0] = f64::INFINITY;
        assert!(bad.check().is_err());
        // Valid at t = 0, not over the image: the speed turns, the roll drifts to 60°, the
        // orbit sinks under the ground.
        let half = 1500.0 * s.line_period_s;
        let mut bad = s;
        bad.position[0][2] = -6600.0 / (2.0 * half);
        bad.position[1][1] = 0.0;
        assert!(bad.check().unwrap_err().contains("move horizontally"));
        let mut bad = s;
        bad.attitude[0][1] = 1.05 / half;
        assert!(bad.check().unwrap_err().contains("roll"));
        let mut bad = s;
        bad.position[2][1] = -830_100.0 / half;
        assert!(bad.check().unwrap_err().contains("height"));
    }

    /// A WorldView-3-like scanner: 617 km up, 0.31 m pixels, a 40 000 × 40 000 scene 20° off
    /// nadir at 8 880 km northing (80° north in UTM), its orbit curved and its attitude
    /// drifting. There a unit in the last place of the coordinates is up to 6e-9 px: the
    /// line search stops on what floating point resolves, not on a fixed 1e-9 line.
    fn worldview_like() -> Pushbroom {
        let (h, tilt) = (617_000.0, 20f64.to_radians());
        Pushbroom {
            columns: 40_000,
            lines: 40_000,
            line_period_s: 0.31 / 6800.0,
            focal_px: h / 0.31 / tilt.cos(),
            principal_col: 20_000.0,
            tilt_across: tilt,
            tilt_along: 0.0,
            position: [
                [500_000.0 - h * tilt.tan(), 40.0, 0.3],
                [8_880_000.0, 6800.0, -0.4],
                [h, -6.0, 0.02],
            ],
            attitude: [[1e-4, 3e-6, 1e-8], [-2e-4, -1e-6, 0.0], [2e-3, 5e-7, 0.0]],
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 300, failure_persistence: None, .. Default::default() })]

        /// Image → ground → image returns to the pixel anywhere in the scene and its heights.
        #[test]
        fn at_0_31_m_pixels_image_to_ground_to_image_round_trips(
            c in 0.0f64..40_000.0,
            r in 0.0f64..40_000.0,
            z in -100.0f64..4000.0,
        ) {
            let s = worldview_like();
            let q = PixelXY::new(c, r);
            let g = s.try_image_to_ground(q, z);
            proptest::prop_assert!(g.is_ok(), "{:?} at {} m: {:?}", q, z, g);
            let back = s.try_ground_to_image(g.unwrap());
            proptest::prop_assert!(back.is_ok(), "{:?} at {} m back: {:?}", q, z, back);
            let d = q.dist(back.unwrap());
            proptest::prop_assert!(d < 1e-6, "{:?} at {} m: {:e} px", q, z, d);
        }
    }
}
