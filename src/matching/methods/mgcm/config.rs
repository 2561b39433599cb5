//! `[matching.mgcm]` (its keys, defaults — seed 002's where it gives them — and ranges in
//! `matcher_config`) turned into the multiphoto matching's parameters.

use crate::matching::methods::mgcm::adjust::{AdjustParams, Constraint};
use crate::matching::methods::mgcm::interest::InterestParams;
use crate::matching::methods::mgcm::point::RayTests;
pub use crate::matching::project::matchers::{ConstraintKind, MgcmConfig};

impl MgcmConfig {
    /// The adjustment's parameters at the finest level.
    pub fn fine(&self) -> AdjustParams {
        AdjustParams {
            half: self.patch / 2,
            affine: self.affine,
            constraint: match self.constraints {
                ConstraintKind::Hard => Constraint::Hard,
                ConstraintKind::Soft => Constraint::Soft {
                    sigma_px: self.constraint_sigma_px,
                },
            },
            max_move_px: self.max_move_px,
            orientation_px: self.orientation_px,
            ..AdjustParams::default()
        }
    }

    /// The coarser levels': two shifts (through Z) and radiometry, hard constraints (seed
    /// 002: "the use of only two shifts instead of an affine transformation generally
    /// suffices" there).
    pub fn coarse(&self) -> AdjustParams {
        AdjustParams {
            half: self.coarse_patch / 2,
            affine: false,
            constraint: Constraint::Hard,
            max_move_px: self.max_move_px,
            converged_px: 0.01,
            ..AdjustParams::default()
        }
    }

    pub fn tests(&self) -> RayTests {
        RayTests {
            min_corr: self.min_corr,
            snoop: self.snoop,
            ..RayTests::default()
        }
    }

    /// The interest operator's parameters for an image of grey range `range`, one point per
    /// `cell` px.
    pub fn interest(&self, range: f64, cell: usize) -> InterestParams {
        InterestParams {
            selection: self.points,
            cell,
            length: self.mask_length,
            threshold: self.threshold_percent / 100.0 * range,
            margin: self.patch + 4,
        }
    }
}

/// The side of the points' cells when the project gives none: half the DEM's post spacing
/// `cell_m` in reference pixels of `gsd_m`, 5 to 25 px (seed 002's 21-29 px at most).
pub fn auto_cell(cell_m: f64, gsd_m: f64) -> usize {
    let px = 0.5 * cell_m / gsd_m;
    if px.is_finite() {
        px.round().clamp(5.0, 25.0) as usize
    } else {
        25
    }
}

#[cfg(test)]
mod tests {
    use crate::matching::methods::mgcm::config::auto_cell;

    #[test]
    fn the_points_cell_follows_the_posts() {
        assert_eq!(auto_cell(1.0, 0.35), 5);
        assert_eq!(auto_cell(80.0, 5.0), 8);
        assert_eq!(auto_cell(500.0, 1.0), 25);
        assert_eq!(auto_cell(10.0, f64::NAN), 25);
    }
}
