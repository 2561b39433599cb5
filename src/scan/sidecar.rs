//! The hand-over to the matching core: a scanned photo is a 16-bit TIFF and this JSON sidecar
//! beside it, which says which photo point every pixel shows, in what grey units, and which
//! calibrations (interior orientation, camera certificate, pixel→carriage) it came through.

use crate::coords::PhotoMm;
use crate::geometry::PhotoGrid;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub const FORMAT: &str = "rig-scanned-photo/1";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Grey {
    /// TIFF counts per camera DN (2^(16 − bit depth)).
    pub counts_per_dn: f64,
    pub camera_bit_depth: u32,
    /// Value of pixels no tile reached.
    pub nodata: u16,
    /// The tiles were divided by a flat field taken on clear film base (then the values are
    /// transmittance relative to that base, times the flat's mean level).
    pub flat_fielded: bool,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InteriorRecord {
    pub session: PathBuf,
    /// Which fiducials' fit: all, corners, mid-sides.
    pub version: String,
    /// Carriage µm → photo µm: x = c0 + c1·X + c2·Y, y = c3 + c4·X + c5·Y.
    pub carriage_to_photo: [f64; 6],
    pub rms_um: f64,
    pub fiducials: Vec<u32>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CertificateFiducial {
    pub id: u32,
    pub photo_mm: PhotoMm,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CertificateRecord {
    pub path: PathBuf,
    pub name: String,
    pub focal_length_mm: f64,
    pub fiducials: Vec<CertificateFiducial>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PixelRecord {
    pub session: PathBuf,
    /// Pixel → carriage: carriage = stage + (a0 + a1·col + a2·row, b0 + b1·col + b2·row).
    pub params: [f64; 6],
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScanRecord {
    pub script: PathBuf,
    pub tiles: usize,
    pub frames_per_tile: u32,
    pub filter: super::script::Filter,
    pub overlap: f64,
    pub resolution_um: f64,
    pub interpolation: String,
    pub antialias_sigma_px: f64,
    pub feather_px: f64,
}

/// The sidecar of one scanned photo region.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScannedPhoto {
    pub format: String,
    /// The TIFF's file name, beside the sidecar.
    pub image: String,
    pub film: String,
    pub region: String,
    pub grid: PhotoGrid,
    pub grey: Grey,
    pub interior_orientation: InteriorRecord,
    pub camera_certificate: CertificateRecord,
    pub pixel_to_carriage: PixelRecord,
    pub scan: ScanRecord,
}

#[derive(Debug, thiserror::Error)]
pub enum SidecarError {
    #[error("{path}: {message}")]
    Bad { path: PathBuf, message: String },
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

impl ScannedPhoto {
    /// Reads a sidecar and the image it names: what the matching core starts from.
    pub fn load(json: &Path) -> Result<(ScannedPhoto, Vec<u16>), SidecarError> {
        let (s, img) = Self::read(json)?;
        let (w, h, px) = crate::digitise::output::read_tiff16(&img)?;
        s.check_size(json, &img, w, h)?;
        Ok((s, px))
    }

    /// The sidecar at `json` and the path of the image it names.
    fn read(json: &Path) -> Result<(ScannedPhoto, PathBuf), SidecarError> {
        let bad = |message: String| SidecarError::Bad {
            path: json.to_path_buf(),
            message,
        };
        let text = std::fs::read_to_string(json).map_err(|e| bad(e.to_string()))?;
        let s: ScannedPhoto = serde_json::from_str(&text).map_err(|e| bad(e.to_string()))?;
        if s.format != FORMAT {
            return Err(bad(format!(
                "format `{}`, expected `{FORMAT}` (a scanned-photo sidecar)",
                s.format
            )));
        }
        let img = json.with_file_name(&s.image);
        Ok((s, img))
    }

    /// The image `img` (`w × h`) must be the size the grid says.
    fn check_size(&self, json: &Path, img: &Path, w: usize, h: usize) -> Result<(), SidecarError> {
        if (w, h) != (self.grid.width, self.grid.height) {
            return Err(SidecarError::Bad {
                path: json.to_path_buf(),
                message: format!(
                    "{} is {w}×{h}, the grid says {}×{}",
                    img.display(),
                    self.grid.width,
                    self.grid.height
                ),
            });
        }
        Ok(())
    }

    /// The scan as the matching core takes it (the hand-over): its image file, its photo grid
    /// and the camera's interior orientation; the core reads the pixels it needs. The image's
    /// size is checked against the grid from its header alone.
    pub fn hand_over(
        json: &Path,
    ) -> Result<crate::matching::block::photo::ScanImage, SidecarError> {
        let (s, img) = Self::read(json)?;
        let (w, h) = crate::image::grey_size(&img)?;
        s.check_size(json, &img, w, h)?;
        Ok(crate::matching::block::photo::ScanImage {
            image: img,
            frame: s.grid.into(),
            // The certificate gives the focal length; the principal point is taken at the
            // fiducial centre (the photo coordinates' origin).
            interior: crate::geometry::Interior {
                focal_mm: s.camera_certificate.focal_length_mm,
                principal_point: crate::coords::PhotoMm::new(0.0, 0.0),
                lens: crate::geometry::Lens::NONE,
            },
        })
    }
}
