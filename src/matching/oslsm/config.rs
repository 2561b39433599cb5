//! `[matching.oslsm]`: the parameters of the object-space matching in a project, with their
//! defaults and ranges. The posts are the DEM's nodes ([dem] cell_m); the groundels divide a
//! post cell into a whole number of squares about `groundel_px` ground pixels of the
//! reference photo each (seed 001: "the size of groundel ... about the pixel size").

use super::patches::PatchLayout;
use super::solve::{OslsmParams, MAX_UNKNOWNS};
use serde::{Deserialize, Serialize};

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
    /// The coarse model: a GeoTIFF DEM in the project's CRS (relative to the project file),
    /// e.g. a national DEM; default: the sweep's, run first into `coarse/`. It must be within
    /// a pixel or two of parallax of the terrain: least squares pulls in no further.
    pub coarse: Option<std::path::PathBuf>,
}

impl Default for OslsmConfig {
    fn default() -> Self {
        OslsmConfig {
            groundel_px: 1.15,
            patch_posts: 24,
            overlap_posts: 4,
            max_iterations: 30,
            converged_px: 0.005,
            smoothness: OslsmParams::default().smoothness,
            reference: None,
            coarse: None,
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
        let max_posts = (MAX_UNKNOWNS as f64).sqrt() as usize - 1;
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

    pub fn layout(&self) -> PatchLayout {
        PatchLayout {
            posts: self.patch_posts,
            overlap: self.overlap_posts,
        }
    }

    /// The adjustment's parameters, with `m_per_px` metres of height per pixel of parallax
    /// (visibility re-tested while a post moves more than half a pixel of parallax; stalled
    /// below 0.05 px).
    pub fn params(&self, m_per_px: f64) -> OslsmParams {
        OslsmParams {
            max_iterations: self.max_iterations,
            converged_m: self.converged_px * m_per_px,
            smoothness: self.smoothness,
            retest_sight_m: 0.5 * m_per_px,
            stall_m: 0.05 * m_per_px,
            ..OslsmParams::default()
        }
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
        assert!(c.patch_posts.pow(2) + 2 * 8 <= MAX_UNKNOWNS);
    }
}
