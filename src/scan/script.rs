//! The scan script: which film, which calibration, which regions of the photo, at what
//! resolution and how each tile is captured. TOML; docs/scanning.md documents it. Every error names
//! the file, and where it can the line and the field.

use serde::Deserialize;
use std::path::{Path, PathBuf};
use toml::Spanned;

#[derive(Debug, thiserror::Error)]
pub enum ScriptError {
    #[error("cannot read the scan script {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    /// Syntax, an unknown key, a value of the wrong type (the message carries the line).
    #[error("{path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("{path}:{line}: {field}: {message}")]
    Invalid {
        path: PathBuf,
        line: usize,
        field: String,
        message: String,
    },
}

/// Which fiducials' carriage→photo affine to use (the versions of seed 002 Table 5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FiducialVersion {
    All,
    Corners,
    MidSides,
}

impl FiducialVersion {
    pub fn name(self) -> &'static str {
        match self {
            FiducialVersion::All => "all",
            FiducialVersion::Corners => "corners",
            FiducialVersion::MidSides => "mid-sides",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Filter {
    /// Field shift and column stripes removed (the rig's digitiser).
    Stripes,
    /// The plain average.
    None,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFilm {
    name: String,
    interior_session: Option<Spanned<String>>,
    #[serde(default = "default_version")]
    fiducials: FiducialVersion,
}

fn default_version() -> FiducialVersion {
    FiducialVersion::All
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawOutput {
    dir: Spanned<String>,
    resolution_um: Spanned<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCapture {
    #[serde(default = "default_frames")]
    frames: Spanned<u32>,
    #[serde(default = "default_filter")]
    filter: Filter,
    #[serde(default = "default_settle")]
    settle_ms: Spanned<f64>,
    #[serde(default = "default_overlap")]
    overlap: Spanned<f64>,
    #[serde(default = "default_gain")]
    gain: Spanned<f64>,
    exposure_ms: Option<Spanned<f64>>,
    #[serde(default = "default_true")]
    flat_field: bool,
    #[serde(default = "default_flat_at")]
    flat_photo_mm: Spanned<Vec<f64>>,
}

fn default_true() -> bool {
    true
}
fn default_flat_at() -> Spanned<Vec<f64>> {
    Spanned::new(0..0, vec![50.0, 108.0])
}
fn default_frames() -> Spanned<u32> {
    Spanned::new(0..0, 8)
}
fn default_filter() -> Filter {
    Filter::Stripes
}
fn default_settle() -> Spanned<f64> {
    Spanned::new(0..0, 100.0)
}
fn default_overlap() -> Spanned<f64> {
    Spanned::new(0..0, 0.2)
}
fn default_gain() -> Spanned<f64> {
    Spanned::new(0..0, 1.0)
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRegion {
    name: Spanned<String>,
    photo_mm: Option<Spanned<Vec<f64>>>,
    whole: Option<Spanned<bool>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScript {
    film: RawFilm,
    output: RawOutput,
    capture: Option<RawCapture>,
    region: Spanned<Vec<RawRegion>>,
}

/// A region of the photo to scan, photo mm.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Region {
    pub name: String,
    /// x_min, y_min, x_max, y_max, mm; `None` = the whole picture inside the fiducials.
    pub photo_mm: Option<[f64; 4]>,
    /// Line of the region's name in the script, for errors found later (at planning).
    #[serde(skip)]
    pub line: usize,
}

#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Capture {
    pub frames: u32,
    pub filter: Filter,
    pub settle_ms: f64,
    /// Share of a tile's width and height that its neighbour covers too.
    pub overlap: f64,
    /// Fixed for the whole scan, so that tiles match in brightness.
    pub gain: f64,
    pub exposure_ms: Option<f64>,
    /// Divide every tile by a flat field taken on clear film base at `flat_photo_mm`: the
    /// measuring mark, dust on the sensor and uneven lighting sit at the same pixels in
    /// every tile and would otherwise repeat across the mosaic.
    pub flat_field: bool,
    pub flat_photo_mm: [f64; 2],
}

#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ScanScript {
    pub path: PathBuf,
    pub film_name: String,
    /// Resolved against the script's directory.
    pub interior_session: Option<PathBuf>,
    pub fiducials: FiducialVersion,
    pub out_dir: PathBuf,
    pub resolution_um: f64,
    pub capture: Capture,
    pub regions: Vec<Region>,
    /// The script's text, kept with the scan so a resume can tell whether it changed.
    #[serde(skip)]
    pub text: String,
}

/// Names a region may not take: the region's photo is written as `<name>.tiff`, `.json` and
/// `.png` beside these files of the scan directory (compared without case, for file systems
/// that ignore it).
pub const RESERVED_NAMES: &[&str] = &[
    "manifest",
    "calibration",
    "flat",
    "sim-truth",
    "script",
    "camera-cert",
    "tiles",
    "log",
    "plan",
];

/// Line (1-based) of byte offset `at` in `text`.
fn line_of(text: &str, at: usize) -> usize {
    text[..at.min(text.len())].matches('\n').count() + 1
}

impl ScanScript {
    pub fn load(path: &Path) -> Result<Self, ScriptError> {
        let text = std::fs::read_to_string(path).map_err(|source| ScriptError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<Self, ScriptError> {
        let raw: RawScript = toml::from_str(text).map_err(|e| ScriptError::Parse {
            path: path.to_path_buf(),
            message: e.to_string().trim_end().to_string(),
        })?;
        let bad =
            |span: std::ops::Range<usize>, field: &str, message: String| ScriptError::Invalid {
                path: path.to_path_buf(),
                line: line_of(text, span.start),
                field: field.into(),
                message,
            };
        let base = path.parent().unwrap_or(Path::new("."));
        let out = &raw.output;
        let r = *out.resolution_um.get_ref();
        if !(r.is_finite() && (1.0..=1000.0).contains(&r)) {
            return Err(bad(
                out.resolution_um.span(),
                "output.resolution_um",
                format!("{r} µm: give the output pixel size, 1 to 1000 µm"),
            ));
        }
        if out.dir.get_ref().trim().is_empty() {
            return Err(bad(
                out.dir.span(),
                "output.dir",
                "empty: name the directory the scan is written to".into(),
            ));
        }
        let cap = match raw.capture {
            Some(c) => c,
            None => RawCapture {
                frames: default_frames(),
                filter: default_filter(),
                settle_ms: default_settle(),
                overlap: default_overlap(),
                gain: default_gain(),
                exposure_ms: None,
                flat_field: true,
                flat_photo_mm: default_flat_at(),
            },
        };
        let frames = *cap.frames.get_ref();
        if !(1..=1024).contains(&frames) {
            return Err(bad(
                cap.frames.span(),
                "capture.frames",
                format!("{frames}: average 1 to 1024 frames per tile"),
            ));
        }
        let settle = *cap.settle_ms.get_ref();
        if !(settle.is_finite() && (0.0..=60_000.0).contains(&settle)) {
            return Err(bad(
                cap.settle_ms.span(),
                "capture.settle_ms",
                format!("{settle}: 0 to 60000 ms"),
            ));
        }
        let overlap = *cap.overlap.get_ref();
        if !(overlap.is_finite() && (0.02..=0.6).contains(&overlap)) {
            return Err(bad(
                cap.overlap.span(),
                "capture.overlap",
                format!("{overlap}: a share of the tile between 0.02 and 0.6 (neighbours must overlap to be blended)"),
            ));
        }
        let gain = *cap.gain.get_ref();
        if !(gain.is_finite() && gain > 0.0) {
            return Err(bad(
                cap.gain.span(),
                "capture.gain",
                format!("{gain}: a positive gain"),
            ));
        }
        let exposure_ms = match &cap.exposure_ms {
            Some(e) if !(e.get_ref().is_finite() && *e.get_ref() > 0.0) => {
                return Err(bad(
                    e.span(),
                    "capture.exposure_ms",
                    format!("{}: a positive exposure", e.get_ref()),
                ))
            }
            e => e.as_ref().map(|e| *e.get_ref()),
        };
        let fa = cap.flat_photo_mm.get_ref();
        if fa.len() != 2 || fa.iter().any(|v| !v.is_finite() || v.abs() > 120.0) {
            return Err(bad(
                cap.flat_photo_mm.span(),
                "capture.flat_photo_mm",
                "two numbers [x, y] in photo mm: a spot of clear film base inside the frame".into(),
            ));
        }
        let flat_photo_mm = [fa[0], fa[1]];
        if raw.region.get_ref().is_empty() {
            return Err(bad(
                raw.region.span(),
                "region",
                "no regions: add a [[region]] with photo_mm = [x_min, y_min, x_max, y_max] or whole = true".into(),
            ));
        }
        let mut regions = Vec::new();
        for (k, rr) in raw.region.get_ref().iter().enumerate() {
            let name = rr.name.get_ref().trim().to_string();
            let field = |f: &str| format!("region[{}].{f}", k + 1);
            let ok_name = !name.is_empty()
                && name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
            if !ok_name {
                return Err(bad(
                    rr.name.span(),
                    &field("name"),
                    format!("`{name}`: letters, digits, - and _ only (it names the output files)"),
                ));
            }
            if let Some(taken) = RESERVED_NAMES
                .iter()
                .find(|r| r.eq_ignore_ascii_case(&name))
            {
                return Err(bad(
                    rr.name.span(),
                    &field("name"),
                    format!(
                        "`{name}` is the name of one of the scan's own files ({taken}.*): choose another (reserved: {})",
                        RESERVED_NAMES.join(", ")
                    ),
                ));
            }
            if name.len() > 64 {
                return Err(bad(
                    rr.name.span(),
                    &field("name"),
                    format!("{} characters: at most 64", name.len()),
                ));
            }
            if regions
                .iter()
                .any(|r: &Region| r.name.eq_ignore_ascii_case(&name))
            {
                return Err(bad(
                    rr.name.span(),
                    &field("name"),
                    format!("`{name}` is used twice"),
                ));
            }
            let whole = rr.whole.as_ref().is_some_and(|w| *w.get_ref());
            let photo_mm = match (&rr.photo_mm, whole) {
                (Some(p), false) => {
                    let v = p.get_ref();
                    if v.len() != 4 || v.iter().any(|x| !x.is_finite()) {
                        return Err(bad(
                            p.span(),
                            &field("photo_mm"),
                            "four numbers: [x_min, y_min, x_max, y_max] in photo mm".into(),
                        ));
                    }
                    if !(v[2] > v[0] && v[3] > v[1]) {
                        return Err(bad(
                            p.span(),
                            &field("photo_mm"),
                            format!(
                                "[{}, {}, {}, {}]: x_max must exceed x_min and y_max y_min",
                                v[0], v[1], v[2], v[3]
                            ),
                        ));
                    }
                    if v.iter().any(|x| x.abs() > 120.0) {
                        return Err(bad(
                            p.span(),
                            &field("photo_mm"),
                            "reaches beyond ±120 mm, outside any 230 mm aerial film frame".into(),
                        ));
                    }
                    Some([v[0], v[1], v[2], v[3]])
                }
                (None, true) => None,
                (Some(p), true) => {
                    return Err(bad(
                        p.span(),
                        &field("photo_mm"),
                        "give photo_mm or whole = true, not both".into(),
                    ))
                }
                (None, false) => {
                    return Err(bad(
                        rr.name.span(),
                        &field("photo_mm"),
                        "missing: give photo_mm = [x_min, y_min, x_max, y_max] or whole = true"
                            .into(),
                    ))
                }
            };
            regions.push(Region {
                name,
                photo_mm,
                line: line_of(text, rr.name.span().start),
            });
        }
        Ok(ScanScript {
            path: path.to_path_buf(),
            film_name: raw.film.name,
            interior_session: raw.film.interior_session.map(|s| base.join(s.get_ref())),
            fiducials: raw.film.fiducials,
            out_dir: base.join(out.dir.get_ref()),
            resolution_um: r,
            capture: Capture {
                frames,
                filter: cap.filter,
                settle_ms: settle,
                overlap,
                gain,
                exposure_ms,
                flat_field: cap.flat_field,
                flat_photo_mm,
            },
            regions,
            text: text.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
[film]
name = "block 1 photo 2"
interior_session = "sessions/interior"

[output]
dir = "scans/p2"
resolution_um = 25.0

[capture]
frames = 8
overlap = 0.2

[[region]]
name = "left"
photo_mm = [-20.0, -15.0, 20.0, 15.0]

[[region]]
name = "all"
whole = true
"#;

    fn err(text: &str) -> String {
        ScanScript::parse(text, Path::new("/x/s.toml"))
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn a_good_script_resolves_paths_against_its_directory() {
        let s = ScanScript::parse(GOOD, Path::new("/lab/s.toml")).unwrap();
        assert_eq!(s.out_dir, Path::new("/lab/scans/p2"));
        assert_eq!(
            s.interior_session.as_deref(),
            Some(Path::new("/lab/sessions/interior"))
        );
        assert_eq!(s.regions[0].photo_mm, Some([-20.0, -15.0, 20.0, 15.0]));
        assert_eq!(s.regions[1].photo_mm, None);
        assert_eq!(s.capture.filter, Filter::Stripes);
        assert_eq!(s.capture.settle_ms, 100.0);
    }

    #[test]
    fn errors_name_file_line_and_field() {
        let e = err(&GOOD.replace("resolution_um = 25.0", "resolution_um = -5.0"));
        assert_eq!(
            e,
            "/x/s.toml:8: output.resolution_um: -5 µm: give the output pixel size, 1 to 1000 µm"
        );
        let e = err(&GOOD.replace("[-20.0, -15.0, 20.0, 15.0]", "[20.0, -15.0, -20.0, 15.0]"));
        assert!(e.starts_with("/x/s.toml:16: region[1].photo_mm:"), "{e}");
        let e = err(&GOOD.replace("overlap = 0.2", "overlap = 0.9"));
        assert!(e.starts_with("/x/s.toml:12: capture.overlap:"), "{e}");
        let e = err(&GOOD.replace("name = \"all\"", "name = \"left\""));
        assert!(e.contains("region[2].name: `left` is used twice"), "{e}");
        // Unknown keys and wrong types: the TOML parser's own message, with the line.
        let e = err(&GOOD.replace("frames = 8", "frams = 8"));
        assert!(e.contains("line 11") && e.contains("frams"), "{e}");
        let e = err(&GOOD.replace("frames = 8", "frames = \"eight\""));
        assert!(e.contains("line 11"), "{e}");
        for name in ["manifest", "Calibration", "FLAT", "sim-truth", "tiles"] {
            let e = err(&GOOD.replace("name = \"all\"", &format!("name = \"{name}\"")));
            assert!(
                e.contains("region[2].name") && e.contains("scan's own files"),
                "{e}"
            );
        }
        for name in ["../x", "a/b", "..", "", "a.b"] {
            let e = err(&GOOD.replace("name = \"all\"", &format!("name = \"{name}\"")));
            assert!(e.contains("region[2].name"), "{name}: {e}");
        }
        let e = err(&GOOD.replace("name = \"all\"", "name = \"LEFT\""));
        assert!(e.contains("used twice"), "{e}");
        let e = err(&GOOD.replace("whole = true", ""));
        assert!(e.contains("region[2].photo_mm: missing"), "{e}");
    }
}
