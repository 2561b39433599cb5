//! Mark files (issue 17): a mark as a list of primitives in TOML, used by `rig measure` and by
//! camera certificates. Every number is range-checked, errors name the file and the part.
//!
//! ```toml
//! units = "px"                  # or "um" (then the pixel size is needed)
//! polarity = "dark_on_bright"   # or "bright_on_dark"
//! [[part]]
//! kind = "dot"                  # radius
//! radius = 2.0
//! [[part]]
//! kind = "ring"                 # radius (of the line's centre), width
//! radius = 14.0
//! width = 2.0
//! [[part]]
//! kind = "spokes"               # count, from, to, width, angle0_deg
//! count = 4
//! from = 17.0
//! to = 22.0
//! width = 2.0
//! [[part]]
//! kind = "bar"                  # length (full), width, angle_deg (a cross is two bars)
//! length = 60.0
//! width = 3.0
//! ```

use super::certificate::{parse_error, read, CertificateError, MAX_MARK_UM, MIN_MARK_UM};
use super::mark::{check_parts, MarkShape, Part};
use super::template::Polarity;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// The unit of a mark file's sizes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Units {
    /// Image pixels (square, or as the image's own axes).
    Px,
    /// Micrometres on the film or plate: the pixel size turns them into pixels.
    Um,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    units: Units,
    #[serde(default)]
    polarity: Polarity,
    part: Vec<Part>,
}

/// Sizes in pixels: from a fifth of a pixel to a mark that would still fit a template.
pub const MIN_MARK_PX: f64 = 0.2;
pub const MAX_MARK_PX: f64 = 500.0;

/// A mark as its file gives it.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkFile {
    pub units: Units,
    pub polarity: Polarity,
    /// In the file's units.
    pub shape: MarkShape,
    pub path: PathBuf,
}

impl MarkFile {
    pub fn load(path: &Path) -> Result<Self, CertificateError> {
        Self::parse(&read(path)?, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<Self, CertificateError> {
        let f: File = toml::from_str(text).map_err(|e| parse_error(path, e))?;
        let (lo, hi, unit) = match f.units {
            Units::Px => (MIN_MARK_PX, MAX_MARK_PX, "px"),
            Units::Um => (MIN_MARK_UM, MAX_MARK_UM, "µm"),
        };
        check_parts(&f.part, "", lo, hi, unit).map_err(|message| CertificateError::Invalid {
            path: path.to_path_buf(),
            message,
        })?;
        Ok(MarkFile {
            units: f.units,
            polarity: f.polarity,
            shape: MarkShape { parts: f.part },
            path: path.to_path_buf(),
        })
    }

    /// The mark and the pixel → unit 2×2 to draw it with: a px file on one unit per pixel
    /// (each image axis its own pixel), a µm file on the pixel size along columns and rows.
    pub fn in_um(&self, pixel_um: Option<[f64; 2]>) -> Result<(MarkShape, [[f64; 2]; 2]), String> {
        match (self.units, pixel_um) {
            (Units::Px, _) => Ok((self.shape.clone(), [[1.0, 0.0], [0.0, 1.0]])),
            (Units::Um, Some([sx, sy])) => Ok((self.shape.clone(), [[sx, 0.0], [0.0, sy]])),
            (Units::Um, None) => Err(format!(
                "{}: the mark's sizes are in µm (units = \"um\"): give the pixel size with \
                 --pixel-um SX[,SY], or write the sizes in pixels (units = \"px\")",
                self.path.display()
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::targets::Geometry;

    const CORNER: &str = r#"
units = "px"
polarity = "dark_on_bright"
[[part]]
kind = "dot"
radius = 2.0
[[part]]
kind = "ring"
radius = 14.0
width = 2.0
[[part]]
kind = "spokes"
count = 4
from = 17.0
to = 22.0
width = 2.0
angle0_deg = 0.0
"#;

    #[test]
    fn the_issue_s_corner_fiducial_reads() {
        let m = MarkFile::parse(CORNER, Path::new("corner.toml")).unwrap();
        assert_eq!(m.units, Units::Px);
        assert_eq!(m.polarity, Polarity::DarkOnClear);
        assert_eq!(m.shape.parts.len(), 3);
        assert_eq!(m.shape.reach_um(), 22.0f64.hypot(1.0));
        assert_eq!(m.shape.geometry(), Geometry::Affine);
        assert!(m.shape.contains([0.0, 20.0]) && !m.shape.contains([14.0, 14.0]));
        let neg = CORNER.replace("dark_on_bright", "bright_on_dark");
        let m = MarkFile::parse(&neg, Path::new("c.toml")).unwrap();
        assert_eq!(m.polarity, Polarity::ClearOnDark);
        assert!(m.in_um(None).is_ok());
        let um = CORNER.replace("\"px\"", "\"um\"").replace("2.0", "20.0");
        let e = MarkFile::parse(&um, Path::new("c.toml"))
            .unwrap()
            .in_um(None);
        assert!(e.unwrap_err().contains("--pixel-um"));
    }

    #[test]
    fn bad_files_are_refused_naming_the_part_and_field() {
        let cases = [
            (
                CORNER.replace("radius = 14.0", "radius = -14.0"),
                "part 2 (ring): radius -14",
            ),
            (
                CORNER.replace("count = 4", "count = 0"),
                "part 3 (spokes): count 0",
            ),
            (CORNER.replace("to = 22.0", "to = 12.0"), "from < to"),
            (
                CORNER.replace("radius = 2.0", "radius = nan"),
                "part 1 (dot): radius NaN",
            ),
            (
                CORNER.replace("radius = 2.0", "radius = 1e9"),
                "from 0.2 to 500 px",
            ),
            (
                CORNER.replace("angle0_deg = 0.0", "angle0_deg = inf"),
                "angle inf",
            ),
            (CORNER.replace("kind = \"dot\"", "kind = \"star\""), "star"),
            (
                CORNER.replace("radius = 2.0", "radius = 2.0\nwidht = 1.0"),
                "widht",
            ),
            (CORNER.replace("\"px\"", "\"mm\""), "mm"),
            ("units = \"px\"\npart = []\n".to_string(), "no [[part]]"),
            (
                CORNER.replace("count = 4", "count = 4294967296"),
                "4294967296",
            ),
        ];
        for (text, want) in cases {
            let e = MarkFile::parse(&text, Path::new("m.toml"))
                .unwrap_err()
                .to_string();
            assert!(e.starts_with("m.toml") && e.contains(want), "{want}: {e}");
        }
    }
}
