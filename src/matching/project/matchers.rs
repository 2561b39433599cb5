//! The matchers' sections of a project file, `[matching.mgcm]` and `[matching.oslsm]`: their
//! keys, defaults and ranges, as plain data that the project file reads and checks
//! (`project2`) and each matcher turns into its own parameters (`mgcm::config`,
//! `oslsm::config`).

use serde::{Deserialize, Serialize};

/// Unknowns of one object-space patch at the most: its dense normal matrix is then 200 MB
/// (a block is cut into patches of at most `patch_posts`² posts).
pub const OSLSM_MAX_UNKNOWNS: usize = 5000;

/// The object-space curvature observations' weight against a post's mean grey-value
/// information, by default (seed 001's regularisation; see `oslsm::solve`).
pub const OSLSM_SMOOTHNESS: f64 = 0.01;

/// How the points of the finest level are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Selection {
    /// The interest operator: the best point of each cell above the threshold.
    Operator,
    /// Every cell's centre, texture or not.
    Grid,
}

/// How the constraints enter (`constraints = "hard"` or `"soft"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ConstraintKind {
    Hard,
    Soft,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MgcmConfig {
    /// Side of the template at the finest level, px, odd (seed 002: 13).
    pub patch: usize,
    /// Side of the template at the coarser levels, px, odd.
    pub coarse_patch: usize,
    /// Estimate each search patch's shape (4 affine parameters) at the finest level. Seed
    /// 002 matched 13² patches with two shifts at 1:42 500; on the simulated block (1 m
    /// pixels, slopes up to 30 %) the shape that the slope gives the patch is the largest
    /// error left without them (0.24 m RMS against 0.016 m with them).
    pub affine: bool,
    pub constraints: ConstraintKind,
    /// σ of the soft constraints, px.
    pub constraint_sigma_px: f64,
    /// "operator" (the interest operator) or "grid".
    pub points: Selection,
    /// One point per cell of this side, px (seed 002: 21-29). Default: half the DEM's post
    /// spacing in the reference's pixels, 5 to 25 px: the DEM is interpolated between the
    /// points, and seed 002's 25 px left the terrain between them to the interpolation (on
    /// independent scenes with 1 m posts at 0.35 m pixels, 0.34 px of parallax against 0.07
    /// px at 6 px).
    pub cell: Option<usize>,
    /// The interest operator's mask length along the edge, px (seed 002: 5-7).
    pub mask_length: usize,
    /// The interest operator's threshold: mean gradient across the edge, per cent of the
    /// reference image's grey range (1st to 99th percentile) per pixel.
    pub threshold_percent: f64,
    /// A ray correlating below this is a blunder.
    pub min_corr: f64,
    /// Data snooping's critical value, σ.
    pub snoop: f64,
    /// A patch may move this far from its approximation, px of its level.
    pub max_move_px: f64,
    /// Photo whose pixels carry the templates (default: the one overlapping most others).
    pub reference: Option<String>,
    /// Pointing error of the orientation, px, in every point's σ (0: exact orientations; a
    /// resected photo adds its resection's own).
    pub orientation_px: f64,
    /// Short side of the pyramid's top level, px.
    pub top_px: usize,
}

impl Default for MgcmConfig {
    fn default() -> Self {
        MgcmConfig {
            patch: 13,
            coarse_patch: 9,
            affine: true,
            constraints: ConstraintKind::Hard,
            constraint_sigma_px: 0.05,
            points: Selection::Operator,
            cell: None,
            mask_length: 7,
            threshold_percent: 1.0,
            min_corr: 0.6,
            snoop: 4.0,
            max_move_px: 3.0,
            reference: None,
            orientation_px: 0.0,
            top_px: 64,
        }
    }
}

impl MgcmConfig {
    /// Every value in its range; the message names the key and the range.
    pub fn check(&self) -> Result<(), String> {
        let odd = |k: &str, v: usize, lo: usize, hi: usize| {
            if v % 2 == 1 && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(format!("[matching.mgcm] {k} = {v}: odd, {lo} to {hi} px"))
            }
        };
        odd("patch", self.patch, 5, 41)?;
        odd("coarse_patch", self.coarse_patch, 5, 41)?;
        odd("mask_length", self.mask_length, 3, 15)?;
        let within = |k: &str, v: f64, lo: f64, hi: f64| {
            if v.is_finite() && v >= lo && v <= hi {
                Ok(())
            } else {
                Err(format!("[matching.mgcm] {k} = {v}: {lo} to {hi}"))
            }
        };
        within("constraint_sigma_px", self.constraint_sigma_px, 0.001, 10.0)?;
        within("threshold_percent", self.threshold_percent, 0.0, 100.0)?;
        within("min_corr", self.min_corr, -1.0, 1.0)?;
        within("snoop", self.snoop, 1.0, 1000.0)?;
        within("max_move_px", self.max_move_px, 0.5, 50.0)?;
        within("orientation_px", self.orientation_px, 0.0, 100.0)?;
        if let Some(cell) = self.cell.filter(|c| !(5..=500).contains(c)) {
            return Err(format!("[matching.mgcm] cell = {cell}: 5 to 500 px"));
        }
        if !(16..=4096).contains(&self.top_px) {
            return Err(format!(
                "[matching.mgcm] top_px = {}: 16 to 4096 px",
                self.top_px
            ));
        }
        Ok(())
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OslsmConfig {
    /// Groundel side in ground pixels of the reference photo. Not 1: groundels aligned with
    /// the datum photo's pixels bias the gains by about 1 % (see `solve`'s documentation).
    pub groundel_px: f64,
    /// Posts along a patch's side; each patch is one dense adjustment (its unknowns, posts²
    /// plus 2 per photo, at most 5000).
    pub patch_posts: usize,
    /// Posts shared by neighbouring patches (merged with linear weights).
    pub overlap_posts: usize,
    pub max_iterations: usize,
    /// Converged when no post moves more than this, px of parallax.
    pub converged_px: f64,
    /// Weight of the curvature observations against a post's mean grey-value information.
    pub smoothness: f64,
    /// The radiometric datum (its offset 0, gain 1) and the photo whose footprint is
    /// modelled; default: the one overlapping most others.
    pub reference: Option<String>,
    /// The coarse model: "sweep" (the default: the sweep's, run first into `coarse/`),
    /// "features" (seed 001's route: edges matched as strings along epipolar line pairs,
    /// for weak texture or a long base where correlation fails), or a GeoTIFF DEM in the
    /// project's CRS (a path relative to the project file, e.g. a national DEM). It must be
    /// within a pixel or two of parallax of the terrain: least squares pulls in no further.
    pub coarse: CoarseSource,
}

/// Where the object-space matching's coarse model comes from (`[matching.oslsm] coarse`).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(from = "String", into = "String")]
pub enum CoarseSource {
    #[default]
    Sweep,
    Features,
    File(std::path::PathBuf),
}

impl From<String> for CoarseSource {
    fn from(s: String) -> Self {
        match s.as_str() {
            "sweep" => CoarseSource::Sweep,
            "features" => CoarseSource::Features,
            _ => CoarseSource::File(s.into()),
        }
    }
}

impl From<CoarseSource> for String {
    fn from(c: CoarseSource) -> String {
        match c {
            CoarseSource::Sweep => "sweep".into(),
            CoarseSource::Features => "features".into(),
            CoarseSource::File(f) => f.display().to_string(),
        }
    }
}

impl Default for OslsmConfig {
    fn default() -> Self {
        OslsmConfig {
            groundel_px: 1.15,
            patch_posts: 24,
            overlap_posts: 4,
            max_iterations: 60,
            converged_px: 0.005,
            smoothness: OSLSM_SMOOTHNESS,
            reference: None,
            coarse: CoarseSource::Sweep,
        }
    }
}

impl OslsmConfig {
    /// Every value in its range; the message names the key and the range.
    pub fn check(&self) -> Result<(), String> {
        let within = |k: &str, v: f64, lo: f64, hi: f64| {
            if v.is_finite() && v >= lo && v <= hi {
                Ok(())
            } else {
                Err(format!("[matching.oslsm] {k} = {v}: {lo} to {hi}"))
            }
        };
        within("groundel_px", self.groundel_px, 0.25, 8.0)?;
        within("converged_px", self.converged_px, 1e-4, 1.0)?;
        within("smoothness", self.smoothness, 0.0, 100.0)?;
        let max_posts = (OSLSM_MAX_UNKNOWNS as f64).sqrt() as usize - 1;
        if !(4..=max_posts).contains(&self.patch_posts) {
            return Err(format!(
                "[matching.oslsm] patch_posts = {}: 4 to {max_posts} (a patch is one dense adjustment of patch_posts² heights)",
                self.patch_posts
            ));
        }
        if !(1..=self.patch_posts / 2).contains(&self.overlap_posts) {
            return Err(format!(
                "[matching.oslsm] overlap_posts = {}: 1 to {} (half of patch_posts)",
                self.overlap_posts,
                self.patch_posts / 2
            ));
        }
        if !(1..=200).contains(&self.max_iterations) {
            return Err(format!(
                "[matching.oslsm] max_iterations = {}: 1 to 200",
                self.max_iterations
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The defaults pass; each value out of its range is refused with its key and range.
    #[test]
    fn values_out_of_range_are_refused_by_name() {
        assert_eq!(OslsmConfig::default().check(), Ok(()));
        let bad: [(&str, OslsmConfig); 7] = [
            (
                "groundel_px",
                OslsmConfig {
                    groundel_px: f64::NAN,
                    ..Default::default()
                },
            ),
            (
                "groundel_px",
                OslsmConfig {
                    groundel_px: 0.1,
                    ..Default::default()
                },
            ),
            (
                "converged_px",
                OslsmConfig {
                    converged_px: 0.0,
                    ..Default::default()
                },
            ),
            (
                "smoothness",
                OslsmConfig {
                    smoothness: -1.0,
                    ..Default::default()
                },
            ),
            (
                "patch_posts",
                OslsmConfig {
                    patch_posts: 80,
                    ..Default::default()
                },
            ),
            (
                "overlap_posts",
                OslsmConfig {
                    overlap_posts: 0,
                    ..Default::default()
                },
            ),
            (
                "max_iterations",
                OslsmConfig {
                    max_iterations: 0,
                    ..Default::default()
                },
            ),
        ];
        for (key, c) in bad {
            let e = c.check().unwrap_err();
            assert!(e.contains(&format!("[matching.oslsm] {key}")), "{e}");
        }
        // The largest patch allowed stays within the solver's dense limit.
        let c = OslsmConfig {
            patch_posts: 69,
            overlap_posts: 4,
            ..Default::default()
        };
        assert_eq!(c.check(), Ok(()));
        // (with up to 8 photos' radiometry)
        assert!(c.patch_posts.pow(2) + 2 * 8 <= OSLSM_MAX_UNKNOWNS);
    }
}
