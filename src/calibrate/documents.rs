//! The documents a calibration session writes and other commands read back — the scan reads
//! an interior session's descriptor and results, `rig calibrate interior` a pixel session's —
//! as typed structs: each written and read by the same type, so a field renamed on one side
//! cannot silently read as missing on the other.

use super::interior::{InteriorOrientation, PixelTransform};
use super::pixel::PixelCalibration;
use crate::camera::CameraInfo;
use crate::stage::ControllerInfo;

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub use super::session::{read_descriptor, read_results, DocumentError, LogDocument, Results};

pub type PixelResults = Results<PixelCalibration>;
pub type InteriorResults = Results<InteriorOrientation>;

/// Pixel → carriage from a pixel session's results.
pub fn pixel_transform(dir: &Path) -> Result<PixelTransform, DocumentError> {
    let r: PixelResults = read_results(dir, "pixel")?;
    Ok(PixelTransform {
        params: r.calibration.affine.params,
    })
}

/// The descriptor (the log's second document) of a pixel session: what was calibrated with
/// what.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PixelDescriptor {
    pub plate_certificate: PathBuf,
    pub plate: String,
    pub camera: CameraInfo,
    pub stage: ControllerInfo,
    pub frames: u32,
    pub grid: usize,
    pub patch: usize,
    pub blur_px: f64,
    /// The nominal pixel spacing, x and y, µm.
    pub nominal_um_per_px: [f64; 2],
    pub sim: bool,
}

/// The descriptor of an interior-orientation session: the scan takes the rig's record
/// (camera, stage) and the pixel → carriage transformation from it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct InteriorDescriptor {
    pub camera_certificate: PathBuf,
    pub camera_name: String,
    pub pixel_session: PathBuf,
    pub pixel_to_carriage: PixelTransform,
    pub flat_field: Option<PathBuf>,
    pub camera: CameraInfo,
    pub stage: ControllerInfo,
    pub frames: u32,
    pub patch: usize,
    pub film_centre_mm: [f64; 2],
    pub sim: bool,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::session::Session;
    use crate::camera::CameraInfo;
    use crate::stage::ControllerInfo;

    fn descriptor() -> InteriorDescriptor {
        InteriorDescriptor {
            camera_certificate: "cert.toml".into(),
            camera_name: "RC10".into(),
            pixel_session: "sessions/p".into(),
            pixel_to_carriage: PixelTransform {
                params: [1.0, 10.19, 0.09, 2.0, 0.1, 10.96],
            },
            flat_field: None,
            camera: CameraInfo {
                name: "sim".into(),
                driver: "sim".into(),
                width: 640,
                height: 480,
                bit_depth: 12,
                exposure_ms: Some(5.0),
                gain: None,
                frame_rate_hz: Some(15.0),
            },
            stage: ControllerInfo::unknown("grbl"),
            frames: 32,
            patch: 71,
            film_centre_mm: [125.0, 125.0],
            sim: true,
        }
    }

    /// What the session writes, the reader reads back whole; a field of the wrong type is
    /// named by its path; another kind of session is refused as such.
    #[test]
    fn descriptors_and_results_round_trip_and_name_what_is_wrong() {
        let d = tempfile::tempdir().unwrap();
        let dir = d.path().join("s");
        let mut s = Session::create(&dir).unwrap();
        s.start("interior", &descriptor()).unwrap();
        s.event("x", serde_json::json!({"a": 1})).unwrap();
        let back: InteriorDescriptor = read_descriptor(&dir).unwrap();
        assert_eq!(
            back.pixel_to_carriage.params,
            descriptor().pixel_to_carriage.params
        );
        assert_eq!(
            (back.camera.width, back.stage.dialect.as_str()),
            (640, "grbl")
        );
        let log = dir.join(crate::calibrate::session::LOG);
        let text = std::fs::read_to_string(&log).unwrap();
        std::fs::write(&log, text.replacen("\"width\":640", "\"width\":-3", 1)).unwrap();
        let e = read_descriptor::<InteriorDescriptor>(&dir).unwrap_err();
        assert!(e.message.contains("camera.width"), "{e}");
        s.write_results(&Results {
            kind: "pixel".into(),
            session: dir.clone(),
            calibration: 1,
        })
        .unwrap();
        let e = read_results::<u32>(&dir, "interior").unwrap_err();
        assert!(e.message.contains("not an interior session"), "{e}");
        assert_eq!(read_results::<u32>(&dir, "pixel").unwrap().calibration, 1);
    }
}
