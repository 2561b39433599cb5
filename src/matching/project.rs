//! A matching project: the two photos (scanned-photo sidecars), the control and check points,
//! and the parameters of seed 000 Tables 3 and 4. TOML; the README documents it. Relative
//! paths are taken from the project file's directory; errors name the file and the field.

use super::pmf_set::StereoPoint;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ProjectError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Photos {
    /// The reference photo's sidecar (REGION.json of a scan, or of `rig sim scene`).
    pub left: PathBuf,
    pub right: PathBuf,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Points {
    /// JSON with `gcps` and `cps`: lists of {id, left: [col, row], right: [col, row],
    /// ground: {x, y, z}}.
    pub file: PathBuf,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PmfSection {
    /// Terms are chosen from the full form of this order (seed 000 started from 2).
    #[serde(default = "two")]
    pub order: u8,
    /// Where the mappings come from: fitted to the control points (seed 000), or derived
    /// from each photo's exterior orientation, resected from the control points, on a 5×5
    /// grid at several heights (seed 004).
    #[serde(default)]
    pub from: PmfSource,
    /// With `from = "file"`: the mappings as JSON (the `pmfs.json` that `rig dtm pmf` writes,
    /// or coefficients from elsewhere in that form).
    pub file: Option<PathBuf>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PmfSource {
    #[default]
    Points,
    Rigorous,
    File,
}

fn two() -> u8 {
    2
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Matching {
    pub h_min: f64,
    pub h_max: f64,
    pub h_step: f64,
    #[serde(default = "nine")]
    pub window: usize,
    #[serde(default = "half")]
    pub threshold: f64,
    #[serde(default = "yes")]
    pub neighbours: bool,
    #[serde(default = "one")]
    pub stride: usize,
}

fn nine() -> usize {
    9
}
fn half() -> f64 {
    0.5
}
fn yes() -> bool {
    true
}
fn one() -> usize {
    1
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Regions {
    #[serde(default = "two_usize")]
    pub search_distance: usize,
    /// Default 1.5 × the height step (seed 000 §3.5).
    pub height_threshold: Option<f64>,
    pub population_threshold: usize,
}

fn two_usize() -> usize {
    2
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GridSection {
    pub cell_m: f64,
    /// A reference elevation model (float32 GeoTIFF) to compare with.
    pub reference: Option<PathBuf>,
    /// Flying height above the terrain, m: the RMSE is also given in per mille of it.
    pub flying_height_m: Option<f64>,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Project {
    pub photos: Photos,
    pub points: Points,
    #[serde(default = "default_pmf")]
    pub pmf: PmfSection,
    pub matching: Matching,
    pub regions: Regions,
    pub grid: GridSection,
    #[serde(skip)]
    pub path: PathBuf,
}

fn default_pmf() -> PmfSection {
    PmfSection {
        order: 2,
        from: PmfSource::Points,
        file: None,
    }
}

#[derive(Debug, Clone, Deserialize, Serialize)]
pub struct PointFile {
    pub gcps: Vec<StereoPoint>,
    pub cps: Vec<StereoPoint>,
}

impl Project {
    pub fn load(path: &Path) -> Result<Project, ProjectError> {
        let text = std::fs::read_to_string(path).map_err(|source| ProjectError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let bad = |message: String| ProjectError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let mut p: Project =
            toml::from_str(&text).map_err(|e| bad(e.to_string().trim_end().to_string()))?;
        let m = &p.matching;
        if !(m.h_step > 0.0 && m.h_max > m.h_min) {
            return Err(bad(format!(
                "[matching] h_min {} … h_max {} by h_step {}: the range must be increasing and the step positive",
                m.h_min, m.h_max, m.h_step
            )));
        }
        if m.window < 3 || m.window.is_multiple_of(2) {
            return Err(bad(format!(
                "[matching] window {}: an odd number of pixels, 3 or more (seed 000: 9)",
                m.window
            )));
        }
        if !(0.0..1.0).contains(&m.threshold) {
            return Err(bad(format!(
                "[matching] threshold {}: a correlation between 0 and 1 (seed 000: 0.5)",
                m.threshold
            )));
        }
        if !(1..=3).contains(&p.pmf.order) {
            return Err(bad(format!("[pmf] order {}: 1, 2 or 3", p.pmf.order)));
        }
        if p.grid.cell_m.is_nan() || p.grid.cell_m <= 0.0 {
            return Err(bad(format!(
                "[grid] cell_m {}: a positive size",
                p.grid.cell_m
            )));
        }
        let base = path.parent().unwrap_or(Path::new("."));
        p.photos.left = base.join(&p.photos.left);
        p.photos.right = base.join(&p.photos.right);
        p.points.file = base.join(&p.points.file);
        p.pmf.file = p.pmf.file.map(|f| base.join(f));
        if p.pmf.from == PmfSource::File && p.pmf.file.is_none() {
            return Err(bad(
                "[pmf] from = \"file\" needs file = \"pmfs.json\" (the mappings as `rig dtm pmf` writes them)".into(),
            ));
        }
        p.grid.reference = p.grid.reference.map(|r| base.join(r));
        p.path = path.to_path_buf();
        Ok(p)
    }

    pub fn points(&self) -> Result<PointFile, ProjectError> {
        let f = &self.points.file;
        let text = std::fs::read_to_string(f).map_err(|source| ProjectError::Read {
            path: f.clone(),
            source,
        })?;
        serde_json::from_str(&text).map_err(|e| ProjectError::Invalid {
            path: f.clone(),
            message: e.to_string(),
        })
    }

    pub fn height_threshold(&self) -> f64 {
        self.regions
            .height_threshold
            .unwrap_or(1.5 * self.matching.h_step)
    }
}
