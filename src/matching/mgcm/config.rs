//! `[matching.mgcm]`: the parameters of the multiphoto matching in a project, with their
//! defaults (seed 002's where it gives them) and ranges.

use super::adjust::{AdjustParams, Constraint};
use super::interest::{InterestParams, Selection};
use super::point::RayTests;
use serde::{Deserialize, Serialize};

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
    /// One point per cell of this side, px (seed 002: 21-29).
    pub cell: usize,
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
            cell: 25,
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
        if !(5..=500).contains(&self.cell) {
            return Err(format!("[matching.mgcm] cell = {}: 5 to 500 px", self.cell));
        }
        if !(16..=4096).contains(&self.top_px) {
            return Err(format!(
                "[matching.mgcm] top_px = {}: 16 to 4096 px",
                self.top_px
            ));
        }
        Ok(())
    }

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

    /// The interest operator's parameters for an image of grey range `range`.
    pub fn interest(&self, range: f64) -> InterestParams {
        InterestParams {
            selection: self.points,
            cell: self.cell,
            length: self.mask_length,
            threshold: self.threshold_percent / 100.0 * range,
            margin: self.patch + 4,
        }
    }
}
