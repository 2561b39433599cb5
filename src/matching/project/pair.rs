//! A matching project: the two photos (scanned-photo sidecars), the control and check points,
//! and the parameters of seed 000 Tables 3 and 4. TOML; docs/elevation-models.md documents it. Relative
//! paths are taken from the project file's directory; errors name the file and the field.

use crate::matching::mapping::pmf_set::StereoPoint;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum PairProjectError {
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

/// A mapping order: a number, or "auto" (0: chosen by the check points).
pub(crate) fn order_or_auto<'de, D: serde::Deserializer<'de>>(d: D) -> Result<u8, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum O {
        N(u8),
        S(String),
    }
    match O::deserialize(d)? {
        O::N(n) => Ok(n),
        O::S(s) if s == "auto" => Ok(0),
        O::S(s) => Err(serde::de::Error::custom(format!(
            "order `{s}`: 1, 2, 3, or \"auto\""
        ))),
    }
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PmfSection {
    /// Terms are chosen from the full form of this order (seed 000 started from 2); 0, or
    /// "auto", lets the check points choose it among 1 … 3.
    #[serde(default = "two", deserialize_with = "order_or_auto")]
    pub order: u8,
    /// Where the mappings come from: fitted to the control points (seed 000), or derived
    /// from each photo's exterior orientation, resected from the control points, on a 5×5
    /// grid at several heights (seed 004).
    #[serde(default)]
    pub from: PmfSource,
    /// With `from = "file"`: the mappings as JSON (format 1's `pmfs.json`, a sweep's `mappings.json`,
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
pub struct PairMatching {
    pub h_min: f64,
    pub h_max: f64,
    /// Height step, m; default: half a pixel of parallax where it is largest (derived from
    /// the mapping functions).
    #[serde(default)]
    pub h_step: Option<f64>,
    #[serde(default = "nine")]
    pub window: usize,
    #[serde(default = "half")]
    pub threshold: f64,
    /// Below the height step: "lsm" (least squares on a plane tilted across the window;
    /// pixels where it fails get no height) or "parabola".
    #[serde(default = "crate::matching::plane_sweep::refine::default_subpixel")]
    pub subpixel: crate::matching::plane_sweep::refine::Subpixel,
    /// Obsolete: the plane sweep scores every height at every pixel, so there is no range to
    /// narrow. Accepted (and ignored) so that older projects still load.
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

/// What a run may take before it starts: memory and work are estimated first and the run is
/// refused above these (raise them here or with `rig dtm pmf --max-memory`).
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Limits {
    /// Memory for images, height maps, points and the grid, MiB.
    #[serde(default = "default_memory_mb")]
    pub max_memory_mb: u64,
    /// Candidate heights the sweep may try (matched pixels × heights), billions.
    #[serde(default = "default_work_g")]
    pub max_candidates_g: f64,
}

impl Limits {
    /// Both limits in their ranges (the message names the key and the range).
    pub(crate) fn check(&self) -> Result<(), String> {
        if !(16..=1_048_576).contains(&self.max_memory_mb) {
            return Err(format!(
                "[limits] max_memory_mb {}: 16 to 1048576 MiB",
                self.max_memory_mb
            ));
        }
        let g = self.max_candidates_g;
        if !(g.is_finite() && g > 0.0 && g <= 1e6) {
            return Err(format!(
                "[limits] max_candidates_g {g}: above 0, at most 1000000 (billions)"
            ));
        }
        Ok(())
    }
}

/// The sweep's parameters (window, threshold, stride) and the wrong-height removal's
/// (search distance, population and height thresholds), as both project formats take them;
/// the first argument names the sections the two groups stand in.
pub(crate) fn check_sweep(
    (m, r): (&str, &str),
    (window, threshold, stride): (usize, f64, usize),
    (search_distance, population, height): (usize, usize, Option<f64>),
) -> Result<(), String> {
    if !(3..=101).contains(&window) || window.is_multiple_of(2) {
        return Err(format!(
            "{m} window {window}: an odd number of pixels from 3 to 101 (seed 000: 9)"
        ));
    }
    if !(0.0..1.0).contains(&threshold) {
        return Err(format!(
            "{m} threshold {threshold}: a correlation from 0 up to (not including) 1 (seed 000: 0.5)"
        ));
    }
    if !(1..=1000).contains(&stride) {
        return Err(format!("{m} stride {stride}: 1 to 1000 pixels"));
    }
    if !(1..=100).contains(&search_distance) {
        return Err(format!(
            "{r} search_distance {search_distance}: 1 to 100 grid steps (seed 000: 2)"
        ));
    }
    if population > 1_000_000_000 {
        return Err(format!(
            "{r} population_threshold {population}: 0 to 1000000000 points"
        ));
    }
    if let Some(h) = height {
        if !(h.is_finite() && h > 0.0 && h <= 10_000.0) {
            return Err(format!(
                "{r} height_threshold {h}: above 0, at most 10000 m"
            ));
        }
    }
    Ok(())
}

pub fn default_memory_mb() -> u64 {
    4096
}
fn default_work_g() -> f64 {
    20.0
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_memory_mb: default_memory_mb(),
            max_candidates_g: default_work_g(),
        }
    }
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PairProject {
    /// The ground coordinates' system, written into every output (default "local").
    #[serde(default)]
    pub crs: crate::geometry::Crs,
    pub photos: Photos,
    pub points: Points,
    #[serde(default = "default_pmf")]
    pub pmf: PmfSection,
    pub matching: PairMatching,
    pub regions: Regions,
    pub grid: GridSection,
    #[serde(default)]
    pub limits: Limits,
    #[serde(skip)]
    pub path: PathBuf,
}

/// Heights above or below any terrain on Earth (and any aircraft), m.
pub const HEIGHT_RANGE: std::ops::RangeInclusive<f64> = -12_000.0..=100_000.0;
/// Most heights one sweep may try.
pub const MAX_HEIGHTS: f64 = 100_000.0;

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

impl PairProject {
    pub fn load(path: &Path) -> Result<PairProject, PairProjectError> {
        let text = std::fs::read_to_string(path).map_err(|source| PairProjectError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// The project in `text`, as if read from `path` (its relative paths are resolved against
    /// `path`'s directory; nothing is read).
    pub fn parse(text: &str, path: &Path) -> Result<PairProject, PairProjectError> {
        let bad = |message: String| PairProjectError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let mut p: PairProject =
            toml::from_str(text).map_err(|e| bad(e.to_string().trim_end().to_string()))?;
        p.check().map_err(bad)?;
        let base = path.parent().unwrap_or(Path::new("."));
        p.photos.left = base.join(&p.photos.left);
        p.photos.right = base.join(&p.photos.right);
        p.points.file = base.join(&p.points.file);
        p.pmf.file = p.pmf.file.map(|f| base.join(f));
        if p.pmf.from == PmfSource::File && p.pmf.file.is_none() {
            return Err(bad(
                "[pmf] from = \"file\" needs file = \"pmfs.json\" (format 1's pmfs.json, or a sweep's mappings.json)".into(),
            ));
        }
        p.grid.reference = p.grid.reference.map(|r| base.join(r));
        p.path = path.to_path_buf();
        Ok(p)
    }

    /// Every number of the project in its range; the message names the field and the range.
    fn check(&self) -> Result<(), String> {
        let m = &self.matching;
        let in_heights = |v: f64| HEIGHT_RANGE.contains(&v);
        if !(in_heights(m.h_min) && in_heights(m.h_max) && m.h_max > m.h_min) {
            return Err(format!(
                "[matching] h_min {} … h_max {}: an increasing range within {} … {} m",
                m.h_min,
                m.h_max,
                HEIGHT_RANGE.start(),
                HEIGHT_RANGE.end()
            ));
        }
        if let Some(step) = m.h_step {
            let steps = (m.h_max - m.h_min) / step;
            if !(step.is_finite() && step > 0.0 && steps <= MAX_HEIGHTS) {
                return Err(format!(
                    "[matching] h_step {step}: positive, and at most {MAX_HEIGHTS} steps from h_min to h_max (here {steps:.3e}); or leave it out for half a pixel of parallax"
                ));
            }
        }
        if !(0..=3).contains(&self.pmf.order) {
            return Err(format!(
                "[pmf] order {}: 1, 2, 3, or \"auto\" (the check points choose)",
                self.pmf.order
            ));
        }
        let r = &self.regions;
        check_sweep(
            ("[matching]", "[regions]"),
            (m.window, m.threshold, m.stride),
            (
                r.search_distance,
                r.population_threshold,
                r.height_threshold,
            ),
        )?;
        let g = &self.grid;
        if !(g.cell_m.is_finite() && (0.01..=10_000.0).contains(&g.cell_m)) {
            return Err(format!("[grid] cell_m {}: 0.01 to 10000 m", g.cell_m));
        }
        if let Some(h) = g.flying_height_m {
            if !(h.is_finite() && h > 0.0 && h <= 1_000_000.0) {
                return Err(format!(
                    "[grid] flying_height_m {h}: above 0, at most 1000000 m"
                ));
            }
        }
        self.limits.check()
    }

    /// The control and check points; every number finite, ids given.
    pub fn points(&self) -> Result<PointFile, PairProjectError> {
        let f = &self.points.file;
        let text = std::fs::read_to_string(f).map_err(|source| PairProjectError::Read {
            path: f.clone(),
            source,
        })?;
        let bad = |message: String| PairProjectError::Invalid {
            path: f.clone(),
            message,
        };
        let pts: PointFile = serde_json::from_str(&text).map_err(|e| bad(e.to_string()))?;
        for (list, v) in [("gcps", &pts.gcps), ("cps", &pts.cps)] {
            for (i, p) in v.iter().enumerate() {
                let px = p.left.iter().chain(&p.right);
                let ok = px.clone().all(|v| v.is_finite() && v.abs() < 1e7)
                    && [p.ground.x, p.ground.y, p.ground.z]
                        .iter()
                        .all(|v| v.is_finite() && v.abs() < 1e9);
                if !ok {
                    return Err(bad(format!(
                        "{list}[{i}] (id {:?}): pixels must be finite and within ±1e7 px, ground coordinates finite and within ±1e9 m",
                        p.id
                    )));
                }
            }
        }
        Ok(pts)
    }

    /// The region filter's height threshold: given, or 1.5 × the step the sweep takes.
    pub fn height_threshold(&self, h_step: f64) -> f64 {
        self.regions.height_threshold.unwrap_or(1.5 * h_step)
    }
}
