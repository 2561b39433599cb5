//! Plate and camera certificates: the calibrated coordinates of the carriage plate's crosses
//! and of a camera's fiducials, with the geometry the templates are drawn from. TOML files;
//! docs/calibration.md documents the format. Errors name the file and the line or the field.

use super::mark::{MarkShape, Part};
use super::template::Polarity;
use crate::coords::{CarriageUm, PhotoMm};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum CertificateError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

/// One calibration cross of the carriage plate.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CertCross {
    pub id: u32,
    pub x_um: f64,
    pub y_um: f64,
}

impl CertCross {
    pub fn position(&self) -> CarriageUm {
        CarriageUm::new(self.x_um, self.y_um)
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct PlateHeader {
    name: String,
    arm_um: f64,
    line_um: f64,
    #[serde(default)]
    polarity: Polarity,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct PlateFile {
    plate: PlateHeader,
    cross: Vec<CertCross>,
}

/// The carriage plate's certificate.
#[derive(Debug, Clone)]
pub struct PlateCertificate {
    pub name: String,
    pub shape: MarkShape,
    pub polarity: Polarity,
    /// Row-major from the origin corner; the central one is the 5th of 9.
    pub crosses: Vec<CertCross>,
    pub path: PathBuf,
}

impl PlateCertificate {
    pub fn load(path: &Path) -> Result<Self, CertificateError> {
        let text = read(path)?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<Self, CertificateError> {
        let f: PlateFile = toml::from_str(text).map_err(|e| parse_error(path, e))?;
        let bad = |message: String| CertificateError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        mark_size(path, "[plate] arm_um", f.plate.arm_um)?;
        mark_size(path, "[plate] line_um", f.plate.line_um)?;
        if f.plate.line_um >= f.plate.arm_um {
            return Err(bad(format!(
                "[plate] line_um {} must be narrower than arm_um {}",
                f.plate.line_um, f.plate.arm_um
            )));
        }
        if f.cross.len() > MAX_MARKS {
            return Err(bad(format!(
                "{} crosses listed; at most {MAX_MARKS}",
                f.cross.len()
            )));
        }
        let mut seen = BTreeMap::new();
        for c in &f.cross {
            let ok = |v: f64| v.is_finite() && v.abs() <= MAX_PLATE_UM;
            if !(ok(c.x_um) && ok(c.y_um)) {
                return Err(bad(format!(
                    "cross {}: x_um {} and y_um {} must be numbers within ±{MAX_PLATE_UM} µm",
                    c.id, c.x_um, c.y_um
                )));
            }
            if seen.insert(c.id, ()).is_some() {
                return Err(bad(format!("cross {} is listed twice", c.id)));
            }
        }
        if f.cross.len() < 3 {
            return Err(bad(format!(
                "{} crosses listed; a plate certificate needs at least 3 (the rig's has 9)",
                f.cross.len()
            )));
        }
        Ok(PlateCertificate {
            name: f.plate.name,
            shape: MarkShape::cross(f.plate.arm_um, f.plate.line_um),
            polarity: f.plate.polarity,
            crosses: f.cross,
            path: path.to_path_buf(),
        })
    }

    /// The cross nearest the middle of the plate (the one the 5×5 grid uses).
    pub fn central(&self) -> CertCross {
        let n = self.crosses.len() as f64;
        let mx = self.crosses.iter().map(|c| c.x_um).sum::<f64>() / n;
        let my = self.crosses.iter().map(|c| c.y_um).sum::<f64>() / n;
        *self
            .crosses
            .iter()
            .min_by(|a, b| {
                let da = (a.x_um - mx).hypot(a.y_um - my);
                let db = (b.x_um - mx).hypot(b.y_um - my);
                da.total_cmp(&db)
            })
            .expect("at least 3 crosses")
    }
}

/// The group of a fiducial (seed 002: corner fiducials are calibrated more precisely than the
/// mid-side ones, and the interior orientation is fitted with each group and with all).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize, PartialOrd, Ord)]
#[serde(rename_all = "snake_case")]
pub enum FiducialGroup {
    Corner,
    MidSide,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "snake_case")]
enum ShapeSpec {
    RingWithDot {
        ring_radius_um: f64,
        dot_radius_um: f64,
        line_um: f64,
    },
    /// The line points from the dot toward the photo centre.
    DotWithLine {
        dot_radius_um: f64,
        line_um: f64,
        from_um: f64,
        to_um: f64,
    },
    Cross {
        arm_um: f64,
        line_um: f64,
    },
    /// Any composite of primitives in µm (see the mark files); `toward_centre` turns the
    /// parts' angle 0 toward the photo centre at each fiducial.
    Parts {
        part: Vec<Part>,
        #[serde(default)]
        toward_centre: bool,
    },
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct FidSpec {
    id: u32,
    x_mm: f64,
    y_mm: f64,
    group: FiducialGroup,
    shape: String,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraHeader {
    name: String,
    focal_length_mm: f64,
    #[serde(default)]
    polarity: Polarity,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraFile {
    camera: CameraHeader,
    shapes: BTreeMap<String, ShapeSpec>,
    fiducial: Vec<FidSpec>,
}

/// One fiducial as the certificate gives it.
#[derive(Debug, Clone, PartialEq)]
pub struct CertFiducial {
    pub id: u32,
    pub photo: PhotoMm,
    pub group: FiducialGroup,
    /// Its form, with lines already turned toward the photo centre.
    pub shape: MarkShape,
}

/// An aerial camera's certificate: calibrated fiducial coordinates and their forms.
#[derive(Debug, Clone, Default)]
pub struct CameraCertificate {
    pub name: String,
    pub focal_length_mm: f64,
    pub polarity: Polarity,
    pub fiducials: Vec<CertFiducial>,
    pub path: PathBuf,
}

impl CameraCertificate {
    pub fn load(path: &Path) -> Result<Self, CertificateError> {
        let text = read(path)?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<Self, CertificateError> {
        let f: CameraFile = toml::from_str(text).map_err(|e| parse_error(path, e))?;
        let bad = |message: String| CertificateError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let fl = f.camera.focal_length_mm;
        if !(fl.is_finite() && (1.0..=5000.0).contains(&fl)) {
            return Err(bad(format!(
                "[camera] focal_length_mm {fl}: give the calibrated focal length, 1 to 5000 mm"
            )));
        }
        if f.fiducial.len() > MAX_MARKS {
            return Err(bad(format!(
                "{} fiducials listed; at most {MAX_MARKS}",
                f.fiducial.len()
            )));
        }
        // Each shape checked once and drawn as a mark; a line's direction is set per fiducial.
        let mut shapes = BTreeMap::new();
        for (name, spec) in &f.shapes {
            let at = format!("[shapes.{name}] ");
            let (shape, toward_centre, sizes): (MarkShape, bool, Vec<(&str, f64)>) = match spec {
                &ShapeSpec::RingWithDot {
                    ring_radius_um,
                    dot_radius_um,
                    line_um,
                } => (
                    MarkShape::ring_with_dot(ring_radius_um, dot_radius_um, line_um),
                    false,
                    vec![
                        ("ring_radius_um", ring_radius_um),
                        ("dot_radius_um", dot_radius_um),
                        ("line_um", line_um),
                    ],
                ),
                &ShapeSpec::DotWithLine {
                    dot_radius_um,
                    line_um,
                    from_um,
                    to_um,
                } => {
                    if from_um.is_nan() || to_um.is_nan() || from_um < 0.0 || to_um <= from_um {
                        return Err(bad(format!(
                            "{at}from_um {from_um} and to_um {to_um}: the line runs from from_um ≥ 0 to a larger to_um"
                        )));
                    }
                    (
                        MarkShape::dot_with_line(
                            dot_radius_um,
                            line_um,
                            from_um,
                            to_um,
                            [1.0, 0.0],
                        ),
                        true,
                        vec![
                            ("dot_radius_um", dot_radius_um),
                            ("line_um", line_um),
                            ("to_um", to_um),
                        ],
                    )
                }
                &ShapeSpec::Cross { arm_um, line_um } => (
                    MarkShape::cross(arm_um, line_um),
                    false,
                    vec![("arm_um", arm_um), ("line_um", line_um)],
                ),
                ShapeSpec::Parts {
                    part,
                    toward_centre,
                } => {
                    super::mark::check_parts(part, &at, MIN_MARK_UM, MAX_MARK_UM, "µm")
                        .map_err(bad)?;
                    (
                        MarkShape {
                            parts: part.clone(),
                        },
                        *toward_centre,
                        Vec::new(),
                    )
                }
            };
            for (field, v) in sizes {
                mark_size(path, &format!("{at}{field}"), v)?;
            }
            shapes.insert(name.clone(), (shape, toward_centre));
        }
        let mut fiducials = Vec::new();
        let mut seen = BTreeMap::new();
        for s in &f.fiducial {
            let ok = |v: f64| v.is_finite() && v.abs() <= MAX_PHOTO_MM;
            if !(ok(s.x_mm) && ok(s.y_mm)) {
                return Err(bad(format!(
                    "fiducial {}: x_mm {} and y_mm {} must lie within ±{MAX_PHOTO_MM} mm of the photo centre",
                    s.id, s.x_mm, s.y_mm
                )));
            }
            if seen.insert(s.id, ()).is_some() {
                return Err(bad(format!("fiducial {} is listed twice", s.id)));
            }
            let (mut shape, toward_centre) = shapes.get(&s.shape).cloned().ok_or_else(|| {
                bad(format!(
                    "fiducial {}: shape `{}` is not among [shapes] ({})",
                    s.id,
                    s.shape,
                    f.shapes.keys().cloned().collect::<Vec<_>>().join(", ")
                ))
            })?;
            if toward_centre {
                let n = s.x_mm.hypot(s.y_mm);
                if n < 1.0 {
                    return Err(bad(format!(
                        "fiducial {}: a line toward the centre needs a fiducial away from it",
                        s.id
                    )));
                }
                // The direction (−x, −y) as the mark's angle.
                shape = shape.turned((-s.y_mm).atan2(-s.x_mm).to_degrees());
            }
            fiducials.push(CertFiducial {
                id: s.id,
                photo: PhotoMm::new(s.x_mm, s.y_mm),
                group: s.group,
                shape,
            });
        }
        if fiducials.len() < 3 {
            return Err(bad(format!(
                "{} fiducials listed; an interior orientation needs at least 3",
                fiducials.len()
            )));
        }
        Ok(CameraCertificate {
            name: f.camera.name,
            focal_length_mm: f.camera.focal_length_mm,
            polarity: f.camera.polarity,
            fiducials,
            path: path.to_path_buf(),
        })
    }
}

/// Largest mark dimension accepted, µm: fiducials and plate crosses are a few mm at most.
pub const MAX_MARK_UM: f64 = 10_000.0;
/// Smallest, µm: below a micrometre no film or plate carries a line.
pub const MIN_MARK_UM: f64 = 1.0;
/// Fiducials lie inside a 230 mm frame; a little more for wider formats.
pub const MAX_PHOTO_MM: f64 = 150.0;
/// Plate crosses lie on a carriage of at most a metre.
pub const MAX_PLATE_UM: f64 = 1_000_000.0;
/// Crosses or fiducials in one certificate.
pub const MAX_MARKS: usize = 10_000;

fn mark_size(path: &Path, field: &str, v: f64) -> Result<(), CertificateError> {
    if v.is_finite() && (MIN_MARK_UM..=MAX_MARK_UM).contains(&v) {
        return Ok(());
    }
    Err(CertificateError::Invalid {
        path: path.to_path_buf(),
        message: format!("{field} {v}: a mark dimension from {MIN_MARK_UM} to {MAX_MARK_UM} µm"),
    })
}

pub(super) fn read(path: &Path) -> Result<String, CertificateError> {
    std::fs::read_to_string(path).map_err(|source| CertificateError::Read {
        path: path.to_path_buf(),
        source,
    })
}

pub(super) fn parse_error(path: &Path, e: toml::de::Error) -> CertificateError {
    CertificateError::Parse {
        path: path.to_path_buf(),
        message: e.to_string().trim_end().to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PLATE: &str = r#"
[plate]
name = "test plate"
arm_um = 1000.0
line_um = 40.0

[[cross]]
id = 1
x_um = 25000.0
y_um = 25000.0

[[cross]]
id = 5
x_um = 125000.4
y_um = 124999.1

[[cross]]
id = 9
x_um = 225000.0
y_um = 225000.0
"#;

    #[test]
    fn a_plate_certificate_reads_and_finds_its_central_cross() {
        let p = PlateCertificate::parse(PLATE, Path::new("p.toml")).unwrap();
        assert_eq!(p.crosses.len(), 3);
        assert_eq!(p.central().id, 5);
        assert_eq!(p.central().x_um, 125000.4);
    }

    #[test]
    fn errors_name_the_file_and_the_line_or_field() {
        let typo = PLATE.replace("y_um = 124999.1", "yum = 124999.1");
        let e = PlateCertificate::parse(&typo, Path::new("plate.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("plate.toml:") && e.contains("yum") && e.contains("line"),
            "{e}"
        );
        let twice = PLATE.replace("id = 9", "id = 1");
        let e = PlateCertificate::parse(&twice, Path::new("plate.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("cross 1 is listed twice"), "{e}");
        let cam = r#"
[camera]
name = "c"
focal_length_mm = 153.0
[shapes.corner]
kind = "ring_with_dot"
ring_radius_um = 300.0
dot_radius_um = 40.0
line_um = 40.0
[[fiducial]]
id = 1
x_mm = -106.0
y_mm = -106.0
group = "corner"
shape = "corners"
"#;
        let e = CameraCertificate::parse(cam, Path::new("cam.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("fiducial 1: shape `corners`") && e.contains("corner"),
            "{e}"
        );
    }
}
