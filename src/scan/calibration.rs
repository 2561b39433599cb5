//! What a scan takes from the calibration sessions: pixel→carriage (the pixel session, through
//! the interior session that used it), carriage→photo (the interior session's chosen version),
//! the camera certificate, and what the sessions recorded about the rig (frame size, soft
//! limits, speeds) so that a scan can be planned without the hardware.

use super::script::FiducialVersion;
use crate::calibrate::affine_fit::{inv2, mul2, solve_linear};
use crate::calibrate::documents::{
    read_descriptor, read_results, DocumentError, InteriorDescriptor, InteriorResults,
};
use crate::calibrate::PixelTransform;
use crate::coords::{CarriageUm, PhotoMm, PixelXY};
use crate::stage::SoftLimits;
use crate::targets::certificate::CameraCertificate;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
#[error("{path}: {message}")]
pub struct CalibrationError {
    pub path: PathBuf,
    pub message: String,
}

/// The rig as the calibration session recorded it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RigRecord {
    pub width: usize,
    pub height: usize,
    pub bit_depth: u32,
    pub frame_rate_hz: Option<f64>,
    pub limits: SoftLimits,
    pub max_speed_um_s: f64,
    pub accel_um_s2: f64,
    /// The longest homing takes on this controller, s (its own bound, recorded at calibration).
    #[serde(default)]
    pub homing_s: Option<f64>,
}

impl RigRecord {
    /// Every number a plan is computed from, range-checked (they come from files).
    fn check(&self) -> Result<(), String> {
        let pos = |v: f64, what: &str, max: f64| {
            if v.is_finite() && v > 0.0 && v <= max {
                Ok(())
            } else {
                Err(format!("{what} {v}: from above 0 to {max}"))
            }
        };
        if !(16..=65_536).contains(&self.width) || !(16..=65_536).contains(&self.height) {
            return Err(format!(
                "camera frame {} × {} px: 16 to 65536 px a side",
                self.width, self.height
            ));
        }
        if !(1..=16).contains(&self.bit_depth) {
            return Err(format!("camera bit_depth {}: 1 to 16", self.bit_depth));
        }
        if let Some(r) = self.frame_rate_hz {
            pos(r, "camera frame_rate_hz", 10_000.0)?;
        }
        pos(self.max_speed_um_s, "stage max_speed_um_s", 1e7)?;
        pos(self.accel_um_s2, "stage accel_um_s2", 1e9)?;
        if let Some(h) = self.homing_s {
            pos(h, "stage homing_s", 3600.0)?;
        }
        let l = &self.limits;
        let ok = |v: f64| v.is_finite() && v.abs() <= 1e7;
        if !(ok(l.min.x) && ok(l.min.y) && ok(l.max.x) && ok(l.max.y))
            || l.min.x >= l.max.x
            || l.min.y >= l.max.y
        {
            return Err(format!(
                "stage soft limits {} … {}: finite, within ±10 m, min below max",
                l.min, l.max
            ));
        }
        Ok(())
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ScanCalibration {
    pub interior_session: PathBuf,
    pub pixel_session: PathBuf,
    pub pixel: PixelTransform,
    pub version: FiducialVersion,
    /// Carriage µm → photo µm: x = c0 + c1·X + c2·Y, y = c3 + c4·X + c5·Y.
    pub carriage_to_photo: [f64; 6],
    pub rms_um: f64,
    pub fiducials: Vec<u32>,
    pub camera_certificate: PathBuf,
    #[serde(skip)]
    pub certificate: CameraCertificate,
    pub rig: RigRecord,
}

fn err(path: &Path, message: impl Into<String>) -> CalibrationError {
    CalibrationError {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// A path a session recorded: as written, or relative to the session's own directory.
fn recorded_path(session: &Path, recorded: &Path, fallback_name: &str) -> Option<PathBuf> {
    let own = session.join(fallback_name);
    if own.is_file() {
        return Some(own);
    }
    recorded.exists().then(|| recorded.to_path_buf())
}

impl ScanCalibration {
    /// The calibration a script scans with: its `[film] interior_session`, else the newest
    /// interior session in `store`; `limits` (the operator's) tighten the recorded soft limits.
    pub fn for_script(
        s: &crate::scan::ScanScript,
        store: &Path,
        limits: Option<&crate::stage::SoftLimits>,
    ) -> Result<Self, crate::scan::ScanError> {
        let interior = match &s.interior_session {
            Some(d) => d.clone(),
            None => crate::calibrate::session::list(store, "interior")?
                .pop()
                .ok_or_else(|| crate::scan::ScanError::NoInterior {
                    script: s.path.clone(),
                    store: store.to_path_buf(),
                })?,
        };
        let mut cal = ScanCalibration::load(&interior, s.fiducials)?;
        if let Some(l) = limits {
            cal.rig.limits = cal.rig.limits.intersect(l);
        }
        Ok(cal)
    }

    pub fn load(interior: &Path, version: FiducialVersion) -> Result<Self, CalibrationError> {
        let results_path = interior.join(crate::calibrate::session::RESULTS);
        let doc = |e: DocumentError| err(&e.path, e.message);
        let results: InteriorResults = read_results(interior, "interior").map_err(doc)?;
        let v = results
            .calibration
            .versions
            .iter()
            .find(|v| v.name == version.name())
            .ok_or_else(|| err(&results_path, "no carriage→photo versions in it"))?;
        let params = v.fit.as_ref().map(|f| f.params).ok_or_else(|| {
            err(
                &results_path,
                format!(
                    "the `{}` version has no fit ({}); choose another with [film] fiducials",
                    version.name(),
                    v.error.as_deref().unwrap_or("unknown reason")
                ),
            )
        })?;
        let d: InteriorDescriptor = read_descriptor(interior).map_err(doc)?;
        let log = interior.join(crate::calibrate::session::LOG);
        let cert_path = recorded_path(interior, &d.camera_certificate, "camera-cert.toml")
            .ok_or_else(|| err(&log, "its camera certificate is not found"))?;
        let certificate =
            CameraCertificate::load(&cert_path).map_err(|e| err(&cert_path, e.to_string()))?;
        let (cam, st) = (&d.camera, &d.stage);
        let homing_s = {
            let mut info = crate::stage::ControllerInfo::unknown("recorded");
            info.max_speed_um_s = st.max_speed_um_s;
            info.accel_um_s2 = st.accel_um_s2;
            // Sessions recorded before these were kept: the fastest speed, the limits' span.
            info.home_speed_um_s = if st.home_speed_um_s > 0.0 {
                st.home_speed_um_s
            } else {
                st.max_speed_um_s
            };
            info.homing_bound_s = st.homing_bound_s;
            info.travel = if st.travel == CarriageUm::default() {
                st.limits.max - st.limits.min
            } else {
                st.travel
            };
            let s = info.homing_duration().as_secs_f64();
            (s.is_finite() && s > 0.0).then_some(s.min(3600.0))
        };
        let count = |n: usize, what: &str| {
            (n <= 65_536).then_some(n).ok_or_else(|| {
                err(
                    &log,
                    format!("the descriptor's {what} {n} is not a count up to 65536"),
                )
            })
        };
        let rig = RigRecord {
            width: count(cam.width, "camera.width")?,
            height: count(cam.height, "camera.height")?,
            bit_depth: count(cam.bit_depth as usize, "camera.bit_depth")? as u32,
            frame_rate_hz: cam.frame_rate_hz,
            limits: st.limits,
            max_speed_um_s: st.max_speed_um_s,
            accel_um_s2: st.accel_um_s2,
            homing_s,
        };
        rig.check().map_err(|m| err(&log, m))?;
        let cal = ScanCalibration {
            interior_session: interior.to_path_buf(),
            pixel_session: d.pixel_session.clone(),
            pixel: d.pixel_to_carriage,
            version,
            carriage_to_photo: params,
            rms_um: v.rms_um.unwrap_or(f64::NAN),
            fiducials: v.fiducials.clone(),
            camera_certificate: cert_path,
            certificate,
            rig,
        };
        cal.check().map_err(|m| err(&results_path, m))?;
        Ok(cal)
    }

    /// The calibration's numbers are usable: the rig record in range, both affines finite and
    /// invertible (a scan directory's copy is read back from a file).
    pub fn check(&self) -> Result<(), String> {
        self.rig.check()?;
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        let (t, m) = self.photo_to_pixel(CarriageUm::default());
        if !finite(&self.pixel.params)
            || !finite(&self.carriage_to_photo)
            || !finite(&t)
            || !finite(&[m[0][0], m[0][1], m[1][0], m[1][1]])
        {
            return Err(
                "the pixel→carriage or carriage→photo affine is not finite or not invertible"
                    .into(),
            );
        }
        let um = self.pixel.um_per_px();
        let px = um[0][0].hypot(um[1][0]).min(um[0][1].hypot(um[1][1]));
        if !(0.1..=1000.0).contains(&px) {
            return Err(format!(
                "pixel spacing {px} µm on the carriage: 0.1 to 1000 µm expected"
            ));
        }
        Ok(())
    }

    /// A calibration with seed 002's pixel spacings and shears and a film laid about 0.2°
    /// turned near the middle of a 250 mm carriage, for benchmarks and tests that need one
    /// without sessions on disk.
    pub fn synthetic() -> ScanCalibration {
        ScanCalibration {
            interior_session: PathBuf::new(),
            pixel_session: PathBuf::new(),
            pixel: PixelTransform {
                params: [-2430.0, 10.19, 0.09, -2520.0, 0.10, 10.96],
            },
            version: FiducialVersion::All,
            carriage_to_photo: [-125_735.0, 0.99999, 0.0035, -124_164.0, -0.0035, 1.00002],
            rms_um: 0.0,
            fiducials: vec![],
            camera_certificate: PathBuf::new(),
            certificate: CameraCertificate::default(),
            rig: RigRecord {
                width: 512,
                height: 512,
                bit_depth: 12,
                frame_rate_hz: None,
                limits: SoftLimits {
                    min: CarriageUm::new(0.0, 0.0),
                    max: CarriageUm::new(250_000.0, 250_000.0),
                },
                max_speed_um_s: 20_000.0,
                accel_um_s2: 100_000.0,
                homing_s: Some(20.0),
            },
        }
    }

    pub fn photo(&self, c: CarriageUm) -> PhotoMm {
        let p = &self.carriage_to_photo;
        PhotoMm::new(
            (p[0] + p[1] * c.x + p[2] * c.y) / 1000.0,
            (p[3] + p[4] * c.x + p[5] * c.y) / 1000.0,
        )
    }

    pub fn carriage(&self, p: PhotoMm) -> CarriageUm {
        let c = &self.carriage_to_photo;
        let [x, y] = solve_linear(c, [p.x * 1000.0 - c[0], p.y * 1000.0 - c[3]]);
        CarriageUm::new(x, y)
    }

    /// Photo point seen at pixel `q` with the stage at `stage`.
    pub fn photo_at(&self, stage: CarriageUm, q: PixelXY) -> PhotoMm {
        self.photo(self.pixel.carriage(stage, q))
    }

    /// Photo mm → pixel for a tile taken with the stage at `stage`, as an affine
    /// `q = t + M·p` (t in px, M in px per mm): the inverse of the two calibrations chained.
    pub fn photo_to_pixel(&self, stage: CarriageUm) -> ([f64; 2], [[f64; 2]; 2]) {
        // p = photo(stage + a0 + A·q) = P0 + (C·A)·q, with P0 = photo(stage + a0).
        let a = &self.pixel.params;
        let c = &self.carriage_to_photo;
        let p0 = self.photo(stage + CarriageUm::new(a[0], a[3]));
        // C·A in mm per px.
        let ca = [
            [
                (c[1] * a[1] + c[2] * a[4]) / 1000.0,
                (c[1] * a[2] + c[2] * a[5]) / 1000.0,
            ],
            [
                (c[4] * a[1] + c[5] * a[4]) / 1000.0,
                (c[4] * a[2] + c[5] * a[5]) / 1000.0,
            ],
        ];
        let m = inv2(ca).unwrap_or([[f64::NAN; 2]; 2]);
        let t = mul2(m, [-p0.x, -p0.y]);
        (t, m)
    }

    /// The stage position that puts photo point `p` at pixel `q`.
    pub fn stage_for(&self, p: PhotoMm, q: PixelXY) -> CarriageUm {
        let c = self.carriage(p);
        c - (self.pixel.carriage(CarriageUm::default(), q))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cal() -> ScanCalibration {
        ScanCalibration::synthetic()
    }

    #[test]
    fn photo_to_pixel_inverts_the_chain() {
        let c = cal();
        let stage = CarriageUm::new(101_234.5, 150_321.25);
        let (t, m) = c.photo_to_pixel(stage);
        for q in [[0.0, 0.0], [511.0, 3.5], [238.3, 229.6]] {
            let p = c.photo_at(stage, PixelXY::new(q[0], q[1]));
            let back = [
                t[0] + m[0][0] * p.x + m[0][1] * p.y,
                t[1] + m[1][0] * p.x + m[1][1] * p.y,
            ];
            assert!((back[0] - q[0]).abs() < 1e-9 && (back[1] - q[1]).abs() < 1e-9);
        }
        let want = PhotoMm::new(-12.5, 33.0);
        let q = PixelXY::new(256.0, 256.0);
        let s = c.stage_for(want, q);
        let got = c.photo_at(s, q);
        assert!((got.x - want.x).abs() < 1e-9 && (got.y - want.y).abs() < 1e-9);
    }
}
