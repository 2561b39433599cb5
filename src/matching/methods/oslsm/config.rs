//! `[matching.oslsm]` (its keys, defaults and ranges in `matcher_config`) turned into the
//! object-space adjustment's parameters. The posts are the DEM's nodes ([dem] cell_m); the groundels divide a
//! post cell into a whole number of squares about `groundel_px` ground pixels of the
//! reference photo each (seed 001: "the size of groundel ... about the pixel size").

use crate::matching::methods::oslsm::patches::PatchLayout;
use crate::matching::methods::oslsm::solve::OslsmParams;
pub use crate::matching::project::matchers::OslsmConfig;

impl OslsmConfig {
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
