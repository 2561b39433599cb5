//! The matching project, one model for both formats. Format 2: any number of photos as plain
//! images with their cameras and orientations (or the rig's own scan hand-overs), control and
//! check points in a CSV file, the ground CRS, the DEM's cell, extent and heights. Format 1
//! (one scanned pair, [`pair`]) is read as the format-2 project [`upgrade`] writes.
//! docs/elevation-models.md documents every key; the names are the contract. Every number is
//! range-checked here with the file and the key named.
//!
//! Pixel coordinates in this format (and in the points file) follow the convention of docs/conventions.md:
//! (col, row) with integer values at pixel centres, (0, 0) the centre of the top-left pixel.
//! The core's images use the corner origin (pixel c covers [c, c + 1)): `col + 0.5`.

pub mod matchers;
pub mod pair;
pub mod upgrade;

use crate::coords::{GroundM, PhotoMm};
use crate::geometry::{Crs, Exterior};
use crate::matching::project::pair::{check_sweep, Limits};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ProjectError {
    #[error("cannot read {path}: {cause}")]
    Read {
        path: PathBuf,
        cause: std::io::Error,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    /// A format-1 project that cannot be read as format 2.
    #[error(transparent)]
    Format1(Box<upgrade::UpgradeError>),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    focal_mm: f64,
    #[serde(default)]
    principal_point_mm: [f64; 2],
    /// Radial distortion [k₁, k₂] ([`crate::geometry::lens`]: OpenCV's normalised form).
    #[serde(default)]
    distortion: [f64; 2],
    pixel_mm: Option<f64>,
    pixel_to_photo: Option<[f64; 6]>,
    /// A self-calibrated camera's σ, as `rig orient` writes it (for the reader; checked).
    sigma: Option<RawCameraSigma>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCameraSigma {
    focal_mm: f64,
    principal_point_mm: [f64; 2],
    distortion: [f64; 2],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPhoto {
    id: String,
    image: Option<String>,
    camera: Option<String>,
    position: Option<[f64; 3]>,
    angles_deg: Option<[f64; 3]>,
    scan: Option<String>,
    pushbroom: Option<String>,
    rpc: Option<String>,
    /// With `position` and `angles_deg`: they are approximations (a flight index map's), known
    /// to this σ, and `rig orient` (or `rig dtm`, first) adjusts them.
    position_sigma_m: Option<f64>,
    angles_sigma_deg: Option<f64>,
    /// An oriented photo's σ (as `rig orient` writes it): position m, angles deg.
    sigma: Option<RawSigma>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSigma {
    position_m: [f64; 3],
    angles_deg: [f64; 3],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPoints {
    file: String,
    ground_sigma_m: Option<GroundSigma>,
}

/// `ground_sigma_m = 0.5` (X, Y and Z) or `[0.3, 0.5]` (X and Y, Z).
#[derive(Debug, Deserialize)]
#[serde(
    untagged,
    expecting = "ground_sigma_m: one number (m) or two, [X and Y, Z]"
)]
enum GroundSigma {
    All(f64),
    PlanHeight([f64; 2]),
}

/// The coarsest `[dem] photo_level` a project may give: photos 64 times smaller.
pub const MAX_PHOTO_LEVEL: u8 = 6;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDem {
    cell_m: f64,
    extent: Option<[f64; 4]>,
    heights: Option<[f64; 2]>,
    /// "auto" or a pyramid level 0 … 6 (see [`Project::photo_level`]).
    photo_level: Option<toml::Value>,
}

fn d_window() -> usize {
    9
}
fn d_threshold() -> f64 {
    0.5
}
fn d_stride() -> usize {
    1
}
fn d_order() -> u8 {
    3
}
fn d_true() -> bool {
    true
}
fn d_search() -> usize {
    2
}
fn d_population() -> usize {
    200
}
/// `[matching] method`: which matcher makes the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Every overlapping pair swept along its epipolar lines, the heights merged (seed 000).
    #[default]
    Sweep,
    /// Multiphoto geometrically constrained matching (seed 002).
    Mgcm,
    /// Object-space least-squares matching (seed 001).
    Oslsm,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Sweep => "sweep",
            Method::Mgcm => "mgcm",
            Method::Oslsm => "oslsm",
        }
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        [Method::Sweep, Method::Mgcm, Method::Oslsm]
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| format!(
                "[matching] method `{s}`: \"sweep\" (seed 000's height sweep), \"mgcm\" (seed 002's multiphoto geometrically constrained matching) or \"oslsm\" (seed 001's object-space least-squares matching)"
            ))
    }
}

impl<'de> Deserialize<'de> for Method {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d)?
            .parse()
            .map_err(serde::de::Error::custom)
    }
}

/// `[matching] mappings`: where each pair's mapping functions come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Mappings {
    /// Sampled from the two photos' sensors on a grid of image points and heights (Wang,
    /// 2012's rigorous derivation; seed 004 §4).
    #[default]
    Sensors,
    /// Fitted to the control points the two photos share, the check points reporting the
    /// fit (seed 000's mapping functions, its Table 2): no orientation enters them.
    Points,
    /// Read from `mappings_file` (a run's mappings.json, or format 1's pmfs.json for two
    /// photos): the mappings as given, fitted nowhere.
    File,
}

impl Mappings {
    pub fn name(self) -> &'static str {
        match self {
            Mappings::Sensors => "sensors",
            Mappings::Points => "points",
            Mappings::File => "file",
        }
    }
}

/// `[matching]`: the method and its parameters (seed 000 Table 3, with defaults).
#[derive(Debug, Clone, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Matching {
    #[serde(default)]
    pub method: Method,
    #[serde(default = "d_window")]
    pub window: usize,
    #[serde(default = "d_threshold")]
    pub threshold: f64,
    /// Below the height step: "lsm" (least squares on a plane tilted across the window;
    /// pixels where it fails get no height) or "parabola".
    #[serde(default = "crate::matching::plane_sweep::refine::default_subpixel")]
    pub subpixel: crate::matching::plane_sweep::refine::Subpixel,
    /// Height step of the sweep, m; default: half a pixel of parallax in each pair.
    pub h_step: Option<f64>,
    #[serde(default = "d_stride")]
    pub stride: usize,
    /// Obsolete: the plane sweep scores every height at every pixel, so there is no range to
    /// narrow. Accepted (and ignored) so that older projects still load.
    #[serde(default = "d_true")]
    pub neighbours: bool,
    /// Where the sweep's mapping functions come from: "sensors" (default), "points" or "file".
    #[serde(default)]
    pub mappings: Mappings,
    /// With `mappings = "file"`: the file (relative to the project's directory).
    pub mappings_file: Option<PathBuf>,
    /// Order of the mapping functions derived from the sensors (seed 004: 3) or fitted to
    /// the control points (seed 000: 2); "auto": chosen by the check points among 1 … 3.
    #[serde(
        default = "d_order",
        deserialize_with = "crate::matching::project::pair::order_or_auto"
    )]
    pub order: u8,
    /// The grid the mapping functions sample the sensors on, [n, heights]: n × n image
    /// points at that many heights (seed 004: [5, 3]; default [5, 5]).
    pub pmf_grid: Option<[usize; 2]>,
    #[serde(default = "d_search")]
    pub search_distance: usize,
    pub height_threshold: Option<f64>,
    #[serde(default = "d_population")]
    pub population_threshold: usize,
    /// `[matching.mgcm]`: the multiphoto matching's parameters (method = "mgcm").
    #[serde(default)]
    pub mgcm: crate::matching::project::matchers::MgcmConfig,
    /// `[matching.oslsm]`: the object-space matching's parameters (method = "oslsm").
    #[serde(default)]
    pub oslsm: crate::matching::project::matchers::OslsmConfig,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCheck {
    reference: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Raw {
    format: u32,
    crs: Crs,
    #[serde(default)]
    camera: BTreeMap<String, RawCamera>,
    photo: Vec<RawPhoto>,
    points: Option<RawPoints>,
    dem: RawDem,
    matching: Option<Matching>,
    check: Option<RawCheck>,
    orientation: Option<RawOrientation>,
    #[serde(default)]
    limits: Limits,
}

/// `[orientation]`: what `rig orient` found beyond each photo's own σ.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawOrientation {
    /// The orientations' covariance, blocks of photos that see the same ground
    /// ([`crate::orientation::covariance`]).
    covariance: Option<String>,
    /// Atmospheric refraction and the Earth's curvature ([`crate::geometry::radial`]).
    #[serde(default)]
    refraction: bool,
    #[serde(default)]
    earth_curvature: bool,
    /// The cameras' interior parameters the block orientation estimates: any of "focal",
    /// "principal_point", "k1", "k2" ([`crate::orientation::bundle::SelfCalibration`]).
    #[serde(default)]
    self_calibration: Vec<String>,
}

/// `[orientation] self_calibration`'s names, each with the interior parameters it frees (c,
/// x₀, y₀, k₁, k₂).
const SELF_CALIBRATION: [(&str, [bool; 5]); 4] = [
    ("focal", [true, false, false, false, false]),
    ("principal_point", [false, true, true, false, false]),
    ("k1", [false, false, false, true, false]),
    ("k2", [false, false, false, false, true]),
];

/// A camera as the project gives it.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Camera {
    pub focal_mm: f64,
    pub principal_point: PhotoMm,
    /// Radial distortion ([`crate::geometry::lens`]).
    pub lens: crate::geometry::Lens,
    /// Square pixels, mm: x = (col − (W−1)/2)·p, y = ((H−1)/2 − row)·p.
    pub pixel_mm: f64,
    /// Or any affine pixel → photo (docs/conventions.md: integer values at pixel centres):
    /// x = a0 + a1·col + a2·row, y = b0 + b1·col + b2·row; used when given.
    pub pixel_to_photo: Option<[f64; 6]>,
}

/// Where a photo comes from.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub enum Source {
    /// A plain image and its camera (`[camera.NAME]`).
    Image {
        path: PathBuf,
        camera_name: String,
        camera: Camera,
    },
    /// The rig's own scanned photo (its sidecar): image, grid and focal length from the scan.
    Scan { sidecar: PathBuf },
    /// A plain image with its own geometry: a line scanner's rigorous model or RPCs (read
    /// and checked when the project is read).
    Model {
        path: PathBuf,
        model: Box<GivenModel>,
    },
}

/// A photo's geometry given with it, not a frame camera's.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub enum GivenModel {
    /// The rig's line-scanner model (JSON, as `rig sim scene --sensor pushbroom` writes it).
    Pushbroom(crate::geometry::Pushbroom),
    /// RPC00B in any form [`crate::geometry::Rpc::read`] takes: GDAL's `_RPC.TXT`, a
    /// DigitalGlobe `.RPB`, an Airbus DIMAP `RPC_*.XML`, or a TIFF with the RPC tag (50844).
    Rpc(Box<crate::geometry::Rpc>),
}

/// Reads a photo's pushbroom model or RPC file, every number checked with the file named.
fn read_model(path: &Path, rpc: bool) -> Result<GivenModel, String> {
    if rpc {
        return crate::geometry::Rpc::read(path)
            .map(|r| GivenModel::Rpc(Box::new(r)))
            .map_err(|e| e.to_string());
    }
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let m: crate::geometry::Pushbroom = serde_json::from_str(&text)
        .map_err(|e| format!("{}: not a line-scanner model: {e}", path.display()))?;
    m.check().map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(GivenModel::Pushbroom(m))
}

#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PhotoEntry {
    pub id: String,
    pub source: Source,
    /// Given, or `None`: resected from the control points (or, in a block to orient, found
    /// from the control and tie points).
    pub exterior: Option<Exterior>,
    /// `position_sigma_m` and `angles_sigma_deg` (m, deg): `exterior` is an approximation to be
    /// adjusted with the block ([`crate::orientation`]), weighted by these.
    pub approximate: Option<[f64; 2]>,
    /// `sigma`: the σ of an oriented photo's position (m) and angles (deg), as `rig orient`
    /// wrote them.
    pub sigma: Option<[[f64; 3]; 2]>,
}

/// What a point observation is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Kind {
    Gcp,
    Cp,
    Tie,
}

/// One line of the points file: a point seen in one photo.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Observation {
    pub id: String,
    pub kind: Kind,
    pub ground: Option<GroundM>,
    pub photo: String,
    /// Corner-origin continuous pixel (the core's): the file's centre-origin value + 0.5.
    pub col: f64,
    pub row: f64,
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct Project {
    pub path: PathBuf,
    pub crs: Crs,
    pub photos: Vec<PhotoEntry>,
    pub points_file: Option<PathBuf>,
    /// The points, where they were read with the project (format 1's JSON).
    #[serde(skip)]
    pub points_given: Option<Vec<Observation>>,
    /// How well the control and check points' ground was surveyed, σ in m (X and Y, Z),
    /// when the project states it: the control's error is then shared by every photo
    /// resected from it ([`crate::geometry::control_covariance`]), and a check point's adds
    /// to the model's σ where they are compared.
    pub control_sigma_m: Option<[f64; 2]>,
    pub cell_m: f64,
    pub extent: Option<[f64; 4]>,
    pub heights: Option<[f64; 2]>,
    /// `[dem] photo_level`: the pyramid level the photos are read at, 2ᴸ times smaller than
    /// scanned (`None`: "auto", chosen from the cell: see
    /// [`crate::matching::block::photos::level_for`]).
    pub photo_level: Option<u8>,
    pub matching: Matching,
    pub reference: Option<PathBuf>,
    /// `[orientation] covariance`: the oriented photos' covariance as `rig orient` wrote it,
    /// correlated between photos (read by [`crate::orientation::covariance::read`]).
    pub orientation_covariance: Option<PathBuf>,
    /// `[orientation] refraction` and `earth_curvature`: the frame photos' radial
    /// displacements, in the orientation and in every matcher alike.
    pub radial: crate::geometry::Radial,
    /// `[orientation] self_calibration`: which of each camera's c, x₀, y₀, k₁, k₂ the block
    /// orientation estimates (none: the cameras as given).
    pub self_calibration: [bool; 5],
    pub limits: Limits,
}

/// Which project format `text` is (1 or 2), or what it lacks to be either: a file that parses
/// as TOML but names no format and has neither format's tables is not taken for format 1 (whose
/// first complaint, a missing `photos`, would mislead). Text that is not TOML is left to the
/// loaders, whose errors give the line.
pub fn format_of(text: &str) -> Result<u32, String> {
    let Ok(t) = text.parse::<toml::Table>() else {
        return Ok(if text.contains("format") && text.contains('2') {
            2
        } else {
            1
        });
    };
    match t.get("format") {
        Some(v) if v.as_integer() == Some(2) => Ok(2),
        Some(v) => Err(format!(
            "format = {}: this rig reads format 2 (`format = 2`) and format 1 (no `format` key, a [photos] table)",
            v.as_integer()
                .map_or_else(|| format!("(a {})", v.type_str()), |i| i.to_string())
        )),
        None if t.contains_key("photos") => Ok(1),
        None if t.contains_key("photo") || t.contains_key("camera") => Err(
            "it has [[photo]] or [camera] tables but no `format = 2` line: add it at the top".into(),
        ),
        None => Err(
            "not a matching project: a format-2 project starts with `format = 2` and names [[photo]]s (see docs/elevation-models.md); a format-1 project has a [photos] table".into(),
        ),
    }
}

/// A block of aerial film runs to hundreds of photos; the memory they take together is
/// checked against `[limits]` before any is read ([`crate::matching::block::photos::check_held`]).
const MAX_PHOTOS: usize = 1000;
/// Coordinates of ground points and projection centres, m (any projected CRS fits).
const MAX_GROUND_M: f64 = 1e8;

impl Project {
    /// Whether any photo's orientation is an approximation (`position_sigma_m`): the block is
    /// to be oriented before anything matches it.
    pub fn has_approximate_photos(&self) -> bool {
        self.photos.iter().any(|ph| ph.approximate.is_some())
    }

    /// Reads the project at `path` in whichever format it is: format 2, or format 1 (one
    /// scanned pair) as [`upgrade`] writes it in format 2, its points read from its JSON.
    pub fn load(path: &Path) -> Result<Project, ProjectError> {
        let text = std::fs::read_to_string(path).map_err(|source| ProjectError::Read {
            path: path.to_path_buf(),
            cause: source,
        })?;
        match format_of(&text) {
            Ok(2) => Self::parse(&text, path),
            Ok(_) => upgrade::read(&text, path).map_err(|e| match e {
                upgrade::UpgradeError::Project(e) => e,
                e => ProjectError::Format1(Box::new(e)),
            }),
            Err(message) => Err(ProjectError::Invalid {
                path: path.to_path_buf(),
                message,
            }),
        }
    }

    /// The format-2 project in `text`, as if read from `path` (relative paths resolved
    /// against its directory; nothing else is read).
    pub fn parse(text: &str, path: &Path) -> Result<Project, ProjectError> {
        let bad = |message: String| ProjectError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let raw: Raw =
            toml::from_str(text).map_err(|e| bad(e.to_string().trim_end().to_string()))?;
        if raw.format != 2 {
            return Err(bad(format!(
                "format = {}: this reader takes format 2",
                raw.format
            )));
        }
        let base = path.parent().unwrap_or(Path::new("."));
        let finite = |v: &[f64], max: f64| v.iter().all(|x| x.is_finite() && x.abs() <= max);
        let mut cameras = BTreeMap::new();
        for (name, c) in &raw.camera {
            if !(c.focal_mm.is_finite() && (1.0..=5000.0).contains(&c.focal_mm)) {
                return Err(bad(format!(
                    "[camera.{name}] focal_mm {}: 1 to 5000 mm",
                    c.focal_mm
                )));
            }
            if !finite(&c.principal_point_mm, 100.0) {
                return Err(bad(format!(
                    "[camera.{name}] principal_point_mm {:?}: two numbers within ±100 mm",
                    c.principal_point_mm
                )));
            }
            if !finite(&c.distortion, 1.0) {
                return Err(bad(format!(
                    "[camera.{name}] distortion {:?}: [k1, k2], each within ±1 (OpenCV's normalised radial coefficients; a metric camera's are some 1e-4)",
                    c.distortion
                )));
            }
            if let Some(s) = &c.sigma {
                let v = [
                    s.focal_mm,
                    s.principal_point_mm[0],
                    s.principal_point_mm[1],
                    s.distortion[0],
                    s.distortion[1],
                ];
                if !v.iter().all(|x| x.is_finite() && (0.0..=100.0).contains(x)) {
                    return Err(bad(format!(
                        "[camera.{name}.sigma] {v:?}: each σ within 0–100 (mm, and for k1, k2 unitless)"
                    )));
                }
            }
            let (pixel_mm, pixel_to_photo) = match (c.pixel_mm, c.pixel_to_photo) {
                (Some(p), None) if p.is_finite() && (1e-4..=1.0).contains(&p) => (p, None),
                (Some(p), None) => {
                    return Err(bad(format!(
                        "[camera.{name}] pixel_mm {p}: 0.0001 to 1 mm"
                    )))
                }
                (None, Some(a)) => {
                    let shift_ok = finite(&[a[0], a[3]], 1000.0);
                    let lin = [a[1], a[2], a[4], a[5]];
                    let det = a[1] * a[5] - a[2] * a[4];
                    let size = det.abs().sqrt();
                    if !shift_ok || !finite(&lin, 1.0) || !(1e-4..=1.0).contains(&size) {
                        return Err(bad(format!(
                            "[camera.{name}] pixel_to_photo {a:?}: [a0, a1, a2, b0, b1, b2] in mm, shifts within ±1000 mm, a pixel of 0.0001 to 1 mm (not singular)"
                        )));
                    }
                    (size, Some(a))
                }
                (Some(_), Some(_)) => {
                    return Err(bad(format!(
                        "[camera.{name}]: give pixel_mm or pixel_to_photo, not both"
                    )))
                }
                (None, None) => {
                    return Err(bad(format!(
                        "[camera.{name}]: give pixel_mm (square pixels, mm) or pixel_to_photo (an affine)"
                    )))
                }
            };
            cameras.insert(
                name.clone(),
                Camera {
                    focal_mm: c.focal_mm,
                    principal_point: PhotoMm::new(c.principal_point_mm[0], c.principal_point_mm[1]),
                    lens: crate::geometry::Lens {
                        k1: c.distortion[0],
                        k2: c.distortion[1],
                    },
                    pixel_mm,
                    pixel_to_photo,
                },
            );
        }
        if raw.photo.len() < 2 || raw.photo.len() > MAX_PHOTOS {
            return Err(bad(format!(
                "{} [[photo]] entries: 2 to {MAX_PHOTOS}",
                raw.photo.len()
            )));
        }
        let mut photos: Vec<PhotoEntry> = Vec::new();
        for (k, p) in raw.photo.iter().enumerate() {
            let at = format!("[[photo]] {} (`{}`)", k + 1, p.id);
            if p.id.trim().is_empty() || photos.iter().any(|q| q.id == p.id) {
                return Err(bad(format!("{at}: id empty or used twice")));
            }
            let given = match (&p.pushbroom, &p.rpc) {
                (None, None) => None,
                (Some(m), None) => Some(read_model(&base.join(m), false)),
                (None, Some(r)) => Some(read_model(&base.join(r), true)),
                (Some(_), Some(_)) => {
                    return Err(bad(format!("{at}: give pushbroom or rpc, not both")))
                }
            };
            if let Some(model) = given {
                let model = model.map_err(|e| bad(format!("{at}: {e}")))?;
                let (Some(img), None, None, None, None, None, None, None) = (
                    &p.image,
                    &p.camera,
                    &p.scan,
                    &p.position,
                    &p.angles_deg,
                    &p.position_sigma_m,
                    &p.angles_sigma_deg,
                    &p.sigma,
                ) else {
                    return Err(bad(format!(
                        "{at}: a photo with its pushbroom model or RPCs takes image (and no camera, scan, position or angles_deg: the model is its orientation)"
                    )));
                };
                photos.push(PhotoEntry {
                    id: p.id.clone(),
                    source: Source::Model {
                        path: base.join(img),
                        model: Box::new(model),
                    },
                    exterior: None,
                    approximate: None,
                    sigma: None,
                });
                continue;
            }
            let source = match (&p.image, &p.camera, &p.scan) {
                (Some(img), Some(cam), None) => Source::Image {
                    path: base.join(img),
                    camera_name: cam.clone(),
                    camera: *cameras.get(cam).ok_or_else(|| {
                        bad(format!(
                            "{at}: camera `{cam}` is not among [camera.*] ({})",
                            cameras.keys().cloned().collect::<Vec<_>>().join(", ")
                        ))
                    })?,
                },
                (None, None, Some(s)) => Source::Scan {
                    sidecar: base.join(s),
                },
                _ => {
                    return Err(bad(format!(
                        "{at}: give image and camera, or scan (the rig's scanned-photo sidecar), or image and pushbroom (a line-scanner model) or rpc (GDAL's _RPC.TXT)"
                    )))
                }
            };
            let exterior = match (p.position, p.angles_deg) {
                (Some(c), Some(a)) => {
                    if !finite(&c, MAX_GROUND_M) || !finite(&a, 360.0) {
                        return Err(bad(format!(
                            "{at}: position within ±1e8 m and angles_deg within ±360°"
                        )));
                    }
                    Some(Exterior::from_degrees(
                        a[0],
                        a[1],
                        a[2],
                        GroundM::new(c[0], c[1], c[2]),
                    ))
                }
                (None, None) => None,
                _ => {
                    return Err(bad(format!(
                        "{at}: give both position and angles_deg, or neither (resected from the control points)"
                    )))
                }
            };
            let approximate = match (p.position_sigma_m, p.angles_sigma_deg) {
                (None, None) => None,
                (Some(sp), Some(sa)) => {
                    if exterior.is_none() {
                        return Err(bad(format!(
                            "{at}: position_sigma_m and angles_sigma_deg say how well `position` and `angles_deg` are known: give those too (or none of the four, and the block finds the photo from its points)"
                        )));
                    }
                    if !(sp.is_finite() && (0.001..=100_000.0).contains(&sp)) {
                        return Err(bad(format!("{at}: position_sigma_m {sp}: 0.001 to 100000 m")));
                    }
                    if !(sa.is_finite() && (1e-6..=90.0).contains(&sa)) {
                        return Err(bad(format!("{at}: angles_sigma_deg {sa}: 0.000001 to 90°")));
                    }
                    Some([sp, sa])
                }
                _ => {
                    return Err(bad(format!(
                        "{at}: give both position_sigma_m and angles_sigma_deg (how well the approximate orientation is known), or neither"
                    )))
                }
            };
            let sigma = match &p.sigma {
                None => None,
                Some(s) => {
                    let ok = s
                        .position_m
                        .iter()
                        .all(|v| v.is_finite() && (0.0..=1e6).contains(v))
                        && s.angles_deg
                            .iter()
                            .all(|v| v.is_finite() && (0.0..=90.0).contains(v));
                    if !ok || exterior.is_none() || approximate.is_some() {
                        return Err(bad(format!(
                            "{at}: sigma = {{ position_m = [3 numbers, 0 to 1e6 m], angles_deg = [3 numbers, 0 to 90°] }} is an oriented photo's, with position and angles_deg and without the approximations' position_sigma_m and angles_sigma_deg"
                        )));
                    }
                    Some([s.position_m, s.angles_deg])
                }
            };
            photos.push(PhotoEntry {
                id: p.id.clone(),
                source,
                exterior,
                approximate,
                sigma,
            });
        }
        let d = &raw.dem;
        if !(d.cell_m.is_finite() && (0.01..=10_000.0).contains(&d.cell_m)) {
            return Err(bad(format!("[dem] cell_m {}: 0.01 to 10000 m", d.cell_m)));
        }
        if let Some(e) = d.extent {
            if !finite(&e, MAX_GROUND_M) || e[2] <= e[0] || e[3] <= e[1] {
                return Err(bad(format!(
                    "[dem] extent {e:?}: [xmin, ymin, xmax, ymax], increasing, within ±1e8 m"
                )));
            }
        }
        if let Some(h) = d.heights {
            let r = crate::matching::project::pair::HEIGHT_RANGE;
            if !(r.contains(&h[0]) && r.contains(&h[1]) && h[1] > h[0]) {
                return Err(bad(format!(
                    "[dem] heights {h:?}: [min, max], increasing, within {} … {} m",
                    r.start(),
                    r.end()
                )));
            }
        }
        let photo_level = match &d.photo_level {
            None => None,
            Some(toml::Value::String(a)) if a == "auto" => None,
            Some(toml::Value::Integer(l)) if (0..=MAX_PHOTO_LEVEL as i64).contains(l) => {
                Some(*l as u8)
            }
            Some(v) => {
                return Err(bad(format!(
                    "[dem] photo_level {v}: \"auto\" or a pyramid level 0 … {MAX_PHOTO_LEVEL} (the photos read 2^level times smaller; 0: as scanned)"
                )))
            }
        };
        let mut m = raw
            .matching
            .unwrap_or_else(|| toml::from_str("").expect("every [matching] key has a default"));
        m.mgcm.check().map_err(bad)?;
        m.oslsm.check().map_err(bad)?;
        if let Some(s) = m.h_step {
            if !(s.is_finite() && (0.001..=1000.0).contains(&s)) {
                return Err(bad(format!("[matching] h_step {s}: 0.001 to 1000 m")));
            }
        }
        if let Some([n, levels]) = m.pmf_grid {
            if !(2..=50).contains(&n) || !(2..=20).contains(&levels) {
                return Err(bad(format!(
                    "[matching] pmf_grid = [{n}, {levels}]: 2 … 50 image points across, 2 … 20 heights (seed 004: [5, 3])"
                )));
            }
        }
        if m.mappings != Mappings::Sensors && m.method != Method::Sweep {
            return Err(bad(format!(
                "[matching] mappings = \"{}\" is the sweep's (method = \"sweep\"); {} takes the photos' sensors: leave mappings out",
                m.mappings.name(),
                m.method
            )));
        }
        match (m.mappings, &m.mappings_file) {
            (Mappings::File, Some(f)) => m.mappings_file = Some(base.join(f)),
            (Mappings::File, None) => {
                return Err(bad(
                    "[matching] mappings = \"file\" needs mappings_file = \"mappings.json\" (a sweep's, or format 1's pmfs.json)".into(),
                ))
            }
            (other, Some(_)) => {
                return Err(bad(format!(
                    "[matching] mappings_file is read with mappings = \"file\" (here \"{}\"): add that, or leave the file out",
                    other.name()
                )))
            }
            (_, None) => {}
        }
        if !(0..=3).contains(&m.order) {
            return Err(bad(format!(
                "[matching] order {}: 1, 2, 3, or \"auto\" (the check points choose)",
                m.order
            )));
        }
        check_sweep(
            ("[matching]", "[matching]"),
            (m.window, m.threshold, m.stride),
            (
                m.search_distance,
                m.population_threshold,
                m.height_threshold,
            ),
        )
        .map_err(bad)?;
        raw.limits.check().map_err(bad)?;
        let control_sigma_m = match raw.points.as_ref().and_then(|p| p.ground_sigma_m.as_ref()) {
            None => None,
            Some(g) => {
                let v = match g {
                    GroundSigma::All(s) => [*s, *s],
                    GroundSigma::PlanHeight(v) => *v,
                };
                if !v
                    .iter()
                    .all(|s| s.is_finite() && (0.0..=1000.0).contains(s))
                {
                    return Err(bad(format!(
                        "[points] ground_sigma_m {v:?}: each within 0–1000 m (how well the points' ground was surveyed: one number, or [X and Y, Z])"
                    )));
                }
                Some(v)
            }
        };
        let mut self_calibration = [false; 5];
        for name in raw
            .orientation
            .iter()
            .flat_map(|o| o.self_calibration.iter())
        {
            let Some((_, free)) = SELF_CALIBRATION.iter().find(|(n, _)| n == name) else {
                return Err(bad(format!(
                    "[orientation] self_calibration names `{name}`: choose from {}",
                    SELF_CALIBRATION.map(|(n, _)| format!("\"{n}\"")).join(", ")
                )));
            };
            for (s, f) in self_calibration.iter_mut().zip(free) {
                *s |= f;
            }
        }
        Ok(Project {
            path: path.to_path_buf(),
            crs: raw.crs,
            photos,
            points_file: raw.points.map(|p| base.join(p.file)),
            points_given: None,
            control_sigma_m,
            cell_m: d.cell_m,
            extent: d.extent,
            heights: d.heights,
            photo_level,
            matching: m,
            reference: raw.check.map(|c| base.join(c.reference)),
            radial: raw.orientation.as_ref().map_or_else(Default::default, |o| {
                crate::geometry::Radial {
                    refraction: o.refraction,
                    earth_curvature: o.earth_curvature,
                }
            }),
            self_calibration,
            orientation_covariance: raw
                .orientation
                .and_then(|o| o.covariance)
                .map(|c| base.join(c)),
            limits: raw.limits,
        })
    }

    /// The points file's observations (`id,kind,x,y,z,photo,col,row`, a header line first;
    /// x, y, z empty for tie points), every number range-checked with its line.
    pub fn observations(&self) -> Result<Vec<Observation>, ProjectError> {
        if let Some(given) = &self.points_given {
            return Ok(given.clone());
        }
        let Some(f) = &self.points_file else {
            return Ok(Vec::new());
        };
        let text = std::fs::read_to_string(f).map_err(|source| ProjectError::Read {
            path: f.clone(),
            cause: source,
        })?;
        parse_points(&text, f, &self.photos)
    }
}

/// The points file's text (see [`Project::observations`]).
pub fn parse_points(
    text: &str,
    f: &Path,
    photos: &[PhotoEntry],
) -> Result<Vec<Observation>, ProjectError> {
    let bad = |line: usize, message: String| ProjectError::Invalid {
        path: f.to_path_buf(),
        message: format!("line {line}: {message}"),
    };
    let mut out = Vec::new();
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    match lines.next() {
        Some((_, h)) if h.replace(' ', "") == "id,kind,x,y,z,photo,col,row" => {}
        _ => {
            return Err(bad(
                1,
                "the header must be `id,kind,x,y,z,photo,col,row`".into(),
            ))
        }
    }
    for (i, l) in lines {
        let n = i + 1;
        if out.len() >= 1_000_000 {
            return Err(bad(n, "more than 1000000 observations".into()));
        }
        let c: Vec<&str> = l.split(',').map(str::trim).collect();
        if c.len() != 8 {
            return Err(bad(n, format!("{} fields, 8 expected", c.len())));
        }
        let num = |s: &str, what: &str, max: f64| {
            s.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite() && v.abs() <= max)
                .ok_or_else(|| bad(n, format!("{what} `{s}`: a number within ±{max}")))
        };
        let kind = match c[1] {
            "gcp" => Kind::Gcp,
            "cp" => Kind::Cp,
            "tie" => Kind::Tie,
            k => return Err(bad(n, format!("kind `{k}`: gcp, cp or tie"))),
        };
        let ground = if kind == Kind::Tie && c[2..5].iter().all(|s| s.is_empty()) {
            None
        } else {
            Some(GroundM::new(
                num(c[2], "x", MAX_GROUND_M)?,
                num(c[3], "y", MAX_GROUND_M)?,
                num(c[4], "z", 100_000.0)?,
            ))
        };
        if !photos.iter().any(|p| p.id == c[5]) {
            return Err(bad(
                n,
                format!("photo `{}` is not among the [[photo]] ids", c[5]),
            ));
        }
        out.push(Observation {
            id: c[0].to_string(),
            kind,
            ground,
            photo: c[5].to_string(),
            col: num(c[6], "col", 1e6)? + 0.5,
            row: num(c[7], "row", 1e6)? + 0.5,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_format_is_told_or_what_is_missing_said() {
        assert_eq!(format_of("format = 2\n[[photo]]\nid = \"1\"\n"), Ok(2));
        assert_eq!(format_of("[photos]\nleft = \"a.json\"\n"), Ok(1));
        assert!(format_of("")
            .unwrap_err()
            .contains("not a matching project"));
        assert!(format_of("format = 3").unwrap_err().contains("format = 3"));
        assert!(format_of("format = \"2\"")
            .unwrap_err()
            .contains("a string"));
        assert!(format_of("[camera.a]\nfocal_mm = 1\n")
            .unwrap_err()
            .contains("format = 2"));
        // Not TOML: the named format's loader gives the line.
        assert_eq!(format_of("format = 2\n[[photo]\n"), Ok(2));
        assert_eq!(format_of("[photos\n"), Ok(1));
    }

    #[test]
    fn the_controls_ground_sigma_is_one_number_or_plan_and_height_within_range() {
        let seed = include_str!("../../../fuzz/seeds/project/format2.toml");
        let with = |v: &str| {
            let t = seed.replace(
                "file = \"points.csv\"",
                &format!("file = \"points.csv\"\nground_sigma_m = {v}"),
            );
            Project::parse(&t, Path::new("p.toml")).map(|p| p.control_sigma_m)
        };
        assert_eq!(
            Project::parse(seed, Path::new("p.toml"))
                .unwrap()
                .control_sigma_m,
            None
        );
        assert_eq!(with("0.5").unwrap(), Some([0.5, 0.5]));
        assert_eq!(with("[0.3, 0.8]").unwrap(), Some([0.3, 0.8]));
        for bad in ["-0.1", "[0.3, 2000.0]", "nan"] {
            let e = with(bad).unwrap_err().to_string();
            assert!(
                e.contains("ground_sigma_m") && e.contains("0–1000 m"),
                "{bad}: {e}"
            );
        }
        for bad in ["\"half a metre\"", "[1, 2, 3]"] {
            let e = with(bad).unwrap_err().to_string();
            assert!(e.contains("one number (m) or two"), "{bad}: {e}");
        }
    }

    /// `mappings = "file"` takes its file from the project's directory; the file without
    /// it, it without the file, and either with another matcher are refused by name.
    #[test]
    fn mappings_from_a_file_need_the_file_and_the_sweep() {
        let seed = include_str!("../../../fuzz/seeds/project/format2.toml");
        let with = |keys: &str, method: &str| {
            let t = seed.replace(
                "method = \"sweep\"",
                &format!("method = \"{method}\"\n{keys}"),
            );
            Project::parse(&t, Path::new("blocks/p.toml"))
        };
        let p = with("mappings = \"file\"\nmappings_file = \"m.json\"", "sweep").unwrap();
        assert_eq!(p.matching.mappings, Mappings::File);
        assert_eq!(
            p.matching.mappings_file,
            Some(PathBuf::from("blocks/m.json"))
        );
        for (keys, method, says) in [
            ("mappings = \"file\"", "sweep", "needs mappings_file"),
            (
                "mappings_file = \"m.json\"",
                "sweep",
                "read with mappings = \"file\"",
            ),
            (
                "mappings = \"file\"\nmappings_file = \"m.json\"",
                "mgcm",
                "is the sweep's",
            ),
            ("mappings = \"points\"", "oslsm", "is the sweep's"),
        ] {
            let e = with(keys, method).unwrap_err().to_string();
            assert!(e.contains(says), "{keys} / {method}: {e}");
        }
    }
}
