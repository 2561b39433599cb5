//! Least-squares matching of a template into an image (Gruen's adaptive LSM, as seed 002 uses
//! it for crosses and fiducials): six affine and two radiometric parameters,
//!
//! `g(a0 + a1·x + a2·y, b0 + b1·x + b2·y) = r0 + r1·f(x, y) + v`,
//!
//! with f the template (x, y about its centre), g the image, v the residuals in image DN.
//! Gauss–Newton on the linearised equations; the mark's centre is (a0, b0). Reported as seed
//! Tables 1 and 4 list it: shifts, their standard deviations (σ0²·N⁻¹), the correlation
//! coefficient, σ0 and the iterations; failures are typed, never a silent bad position.

use super::resample::sample;
use super::template::Template;
use crate::coords::PixelXY;
use crate::digitise::ImageF32;
use nalgebra::{SMatrix, SVector};
use serde::Serialize;

/// When to stop and when to give up.
#[derive(Debug, Clone, Copy)]
pub struct LsmOptions {
    pub max_iterations: u32,
    /// Converged when the shift corrections fall below this (px) and the affine ones move the
    /// patch's edge by less than ten times it.
    pub tolerance_px: f64,
    /// Give up when the centre wanders this far from the start (px).
    pub max_shift_px: f64,
    /// The image patch's grey-level σ must reach this (DN) for a match to mean anything.
    pub min_contrast_dn: f64,
}

impl Default for LsmOptions {
    fn default() -> Self {
        LsmOptions {
            // A ring's rotation is weakly determined (only by the pixels' anisotropy): it can
            // take some 30 iterations to settle, and the centre moves with it by ~0.01 px.
            max_iterations: 60,
            tolerance_px: 1e-4,
            max_shift_px: 3.0,
            min_contrast_dn: 3.0,
        }
    }
}

/// A converged match.
#[derive(Debug, Clone, Serialize)]
pub struct LsmMatch {
    /// The mark's centre in the image.
    pub centre: PixelXY,
    /// Standard deviations of the two shifts, px.
    pub sigma_px: [f64; 2],
    /// a0, a1, a2, b0, b1, b2.
    pub affine: [f64; 6],
    /// r0 (offset, DN) and r1 (contrast, DN per template unit).
    pub radiometric: [f64; 2],
    /// σ0: the residuals' standard deviation, DN.
    pub sigma0_dn: f64,
    /// Correlation coefficient of the template and the resampled image patch.
    pub correlation: f64,
    pub iterations: u32,
    /// How far the centre moved from the start (the coarse location's error), px.
    pub moved_px: [f64; 2],
}

#[derive(Debug, Clone, PartialEq, thiserror::Error, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum LsmError {
    #[error("least-squares matching did not converge in {iterations} iterations")]
    Diverged { iterations: u32 },
    #[error("least-squares matching moved {moved_px:.2} px from the start (more than allowed)")]
    Wandered { moved_px: f64 },
    #[error("least-squares matching: singular normal equations (no texture in one direction?)")]
    Singular,
    #[error("least-squares matching: the patch left the image")]
    LeftWindow,
    #[error("too little contrast to match: σ {contrast_dn:.2} DN")]
    LowContrast { contrast_dn: f64 },
}

/// Matches `tpl` into `img` starting with its centre at `start` and the template's axes along
/// the image's (the template is drawn at the image's pixel spacing).
pub fn match_template(
    img: &ImageF32,
    tpl: &Template,
    start: PixelXY,
    opt: &LsmOptions,
) -> Result<LsmMatch, LsmError> {
    let n = tpl.size();
    let c = tpl.centre();
    // Template samples: (x, y) about the centre, and f.
    let pts: Vec<(f64, f64, f64)> = (0..n * n)
        .map(|i| {
            let (col, row) = (i % n, i / n);
            (
                col as f64 + 0.5 - c,
                row as f64 + 0.5 - c,
                tpl.image.data[i] as f64,
            )
        })
        .collect();
    let np = pts.len() as f64;
    let fm = pts.iter().map(|p| p.2).sum::<f64>() / np;
    let fs = (pts.iter().map(|p| (p.2 - fm).powi(2)).sum::<f64>() / np).sqrt();

    let mut a = [start.col, 1.0, 0.0, start.row, 0.0, 1.0];
    // Radiometry from the first resampling: match mean and σ.
    let resample = |a: &[f64; 6]| -> Option<Vec<(f64, f64, f64)>> {
        pts.iter()
            .map(|&(x, y, _)| sample(img, a[0] + a[1] * x + a[2] * y, a[3] + a[4] * x + a[5] * y))
            .collect()
    };
    let g0 = resample(&a).ok_or(LsmError::LeftWindow)?;
    let gm = g0.iter().map(|g| g.0).sum::<f64>() / np;
    let gs = (g0.iter().map(|g| (g.0 - gm).powi(2)).sum::<f64>() / np).sqrt();
    if gs < opt.min_contrast_dn || fs < 1e-6 {
        return Err(LsmError::LowContrast { contrast_dn: gs });
    }
    let mut r = [gm - gs / fs * fm, gs / fs];

    let mut it = 0;
    loop {
        it += 1;
        let g = resample(&a).ok_or(LsmError::LeftWindow)?;
        let mut nm = SMatrix::<f64, 8, 8>::zeros();
        let mut rhs = SVector::<f64, 8>::zeros();
        for (&(x, y, f), &(gv, gx, gy)) in pts.iter().zip(&g) {
            let row = SVector::<f64, 8>::from([gx, gx * x, gx * y, gy, gy * x, gy * y, -1.0, -f]);
            let l = r[0] + r[1] * f - gv;
            nm += row * row.transpose();
            rhs += row * l;
        }
        let chol = nm.cholesky().ok_or(LsmError::Singular)?;
        let d = chol.solve(&rhs);
        for k in 0..6 {
            a[k] += d[k];
        }
        r[0] += d[6];
        r[1] += d[7];
        let moved = (a[0] - start.col).hypot(a[3] - start.row);
        if !moved.is_finite() || moved > opt.max_shift_px {
            return Err(LsmError::Wandered { moved_px: moved });
        }
        let det = a[1] * a[5] - a[2] * a[4];
        if !(0.5..2.0).contains(&det) {
            return Err(LsmError::Diverged { iterations: it });
        }
        let small = d[0].abs() < opt.tolerance_px
            && d[3].abs() < opt.tolerance_px
            && [d[1], d[2], d[4], d[5]]
                .iter()
                .all(|v| v.abs() * c < opt.tolerance_px * 10.0);
        if small {
            // Precision at the solution: one more pass for the residuals and the normal matrix.
            let g = resample(&a).ok_or(LsmError::LeftWindow)?;
            let mut nm = SMatrix::<f64, 8, 8>::zeros();
            let mut vv = 0.0;
            for (&(x, y, f), &(gv, gx, gy)) in pts.iter().zip(&g) {
                let row =
                    SVector::<f64, 8>::from([gx, gx * x, gx * y, gy, gy * x, gy * y, -1.0, -f]);
                nm += row * row.transpose();
                let l = r[0] + r[1] * f - gv;
                vv += l * l;
            }
            let corr = correlation(pts.iter().map(|p| p.2), g.iter().map(|g| g.0));
            let sigma0 = (vv / (np - 8.0)).sqrt();
            let q = nm.try_inverse().ok_or(LsmError::Singular)?;
            return Ok(LsmMatch {
                centre: PixelXY::new(a[0], a[3]),
                sigma_px: [sigma0 * q[(0, 0)].sqrt(), sigma0 * q[(3, 3)].sqrt()],
                affine: a,
                radiometric: r,
                sigma0_dn: sigma0,
                correlation: corr,
                iterations: it,
                moved_px: [a[0] - start.col, a[3] - start.row],
            });
        }
        if it >= opt.max_iterations {
            return Err(LsmError::Diverged { iterations: it });
        }
    }
}

/// Pearson's correlation coefficient of two equally long series.
pub fn correlation(a: impl Iterator<Item = f64>, b: impl Iterator<Item = f64>) -> f64 {
    let (mut n, mut sa, mut sb, mut saa, mut sbb, mut sab) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (x, y) in a.zip(b) {
        n += 1.0;
        sa += x;
        sb += y;
        saa += x * x;
        sbb += y * y;
        sab += x * y;
    }
    let cov = sab - sa * sb / n;
    let va = saa - sa * sa / n;
    let vb = sbb - sb * sb / n;
    if va <= 0.0 || vb <= 0.0 {
        return 0.0;
    }
    cov / (va * vb).sqrt()
}
