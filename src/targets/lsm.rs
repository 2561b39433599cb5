//! Least-squares matching of a template into an image (Gruen's adaptive LSM, as seed 002 uses
//! it for crosses and fiducials): six affine and two radiometric parameters,
//!
//! `g(a0 + a1·x + a2·y, b0 + b1·x + b2·y) = r0 + r1·f(x, y) + v`,
//!
//! with f the template (x, y about its centre), g the image, v the residuals in image DN.
//! Gauss–Newton on the linearised equations; the mark's centre is (a0, b0). A synthetic
//! template is drawn finely, so the rig solves the same model with the roles turned (the
//! template sampled at the image's pixels, see `match_sampling_template`): resampling the
//! image's sharp edges instead biased centres by up to 0.015 px. Reported as seed
//! Tables 1 and 4 list it: shifts, their standard deviations (σ0²·N⁻¹), the correlation
//! coefficient, σ0 and the iterations; failures are typed, never a silent bad position.

use super::mark::Geometry;
use super::resample::sample;
use super::template::{Template, FINE, FINE_PAD};
use crate::coords::PixelXY;
use crate::digitise::ImageF32;
use crate::geometry::affine::{inv2, linear_part, mul2, mul22};
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

impl Geometry {
    /// ∂(u0, u1, u2, v0, v1, v2)/∂(the model's parameters), columns per parameter: the change
    /// of the image → template map U for a change of each parameter. `a` is the template's
    /// pixel → µm 2×2: a change N of the mark's µm → µm map is A⁻¹·N·A in template pixels.
    fn jacobian(self, a: [[f64; 2]; 2]) -> Option<Vec<[f64; 6]>> {
        let ai = inv2(a)?;
        // A⁻¹·N·A as (u1, u2, v1, v2).
        let conj = |n: [[f64; 2]; 2]| mul22(mul22(ai, n), a);
        let lin = |n: [[f64; 2]; 2]| {
            let m = conj(n);
            [0.0, m[0][0], m[0][1], 0.0, m[1][0], m[1][1]]
        };
        let shifts = [
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
        ];
        let scale = lin([[1.0, 0.0], [0.0, 1.0]]);
        let rotation = lin([[0.0, -1.0], [1.0, 0.0]]);
        Some(match self {
            Geometry::Shift => shifts.to_vec(),
            Geometry::ShiftScale => vec![shifts[0], shifts[1], scale],
            Geometry::Similarity => vec![shifts[0], shifts[1], scale, rotation],
            Geometry::Affine => (0..6)
                .map(|i| {
                    let mut e = [0.0; 6];
                    e[i] = 1.0;
                    e
                })
                .collect(),
        })
    }
}

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
    /// The geometric parameters solved for (see [`Geometry`]).
    pub geometry: Geometry,
    /// Residuals beyond this many robust σ (median absolute deviation, at least 3 % of the
    /// mark's contrast) are down-weighted (Huber) and count as outliers: a scratch or a hot
    /// pixel on the mark must not pull the centre.
    pub huber_k: f64,
}

impl Default for LsmOptions {
    fn default() -> Self {
        LsmOptions {
            // Crosses settle in 3–5 iterations, fiducials in 5–8; a ring's weakly determined
            // rotation may swing meanwhile (see the convergence test), so leave room.
            max_iterations: 60,
            tolerance_px: 1e-4,
            max_shift_px: 3.0,
            min_contrast_dn: 3.0,
            geometry: Geometry::Affine,
            huber_k: 3.0,
        }
    }
}

/// A converged match.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
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
    /// Share of the template's mark (its ink) that the image's part of the window holds: below
    /// 1 when the frame cuts the window through the mark.
    #[serde(default = "one")]
    pub inside_share: f64,
    /// Share of the evidence (the template's squared gradients) on pixels whose residuals are
    /// outliers ([`LsmOptions::huber_k`]): noise puts a few tenths of a per cent there, a
    /// scratch or a wrong mark far more.
    #[serde(default)]
    pub outlier_share: f64,
    /// Share of the mark's own pixels (where the template's squared gradient is at least 5 %
    /// of its largest) whose residuals are outliers: noise puts 0.3 % there; a scratch across
    /// the mark's lines more, however the evidence is weighted. Dust on the background away
    /// from the lines counts in neither.
    #[serde(default)]
    pub outlier_pixels: f64,
    /// How many pixels [`LsmMatch::outlier_pixels`] is a share of: the gate's allowance for
    /// the outliers noise alone makes depends on it.
    #[serde(default)]
    pub mark_pixels: usize,
    /// The largest share of the evidence one pixel carries: the most that each outlier noise
    /// makes can add to [`LsmMatch::outlier_share`].
    #[serde(default)]
    pub evidence_peak_share: f64,
}

fn one() -> f64 {
    1.0
}

/// The residuals' robust σ is taken as at least this share of the mark's contrast: a template
/// a little unlike the mark (its line ends, a blur not quite Gaussian) leaves residuals of a
/// few per cent of the contrast along every edge, which on a quiet image would read as
/// outliers; a scratch or a wrong mark leaves residuals of tens of per cent.
const ROBUST_FLOOR: f64 = 0.03;

/// Largest lag of the residuals' autocovariance taken into the centre's σ, px.
const HAC_LAG: usize = 12;

/// The work of one match with a template of side `n`, in multiply-adds: the iterations' normal
/// equations and the centre's σ (to refuse a match too large before it starts).
pub fn match_work(n: usize) -> f64 {
    let lags = (2 * HAC_LAG + 1) as f64;
    (n * n) as f64 * (LsmOptions::default().max_iterations as f64 * 64.0 + 2.0 * lags * lags)
}

/// The residuals' robust σ: the median absolute deviation × 1.4826 (a Gaussian's σ), at least
/// `floor`.
fn robust_sigma(v: &[f64], floor: f64) -> f64 {
    let mut a: Vec<f64> = v.to_vec();
    let mid = a.len() / 2;
    if a.is_empty() {
        return floor;
    }
    let (_, m, _) = a.select_nth_unstable_by(mid, f64::total_cmp);
    let m = *m;
    let mut d: Vec<f64> = v.iter().map(|x| (x - m).abs()).collect();
    let (_, mad, _) = d.select_nth_unstable_by(mid, f64::total_cmp);
    (1.4826 * *mad).max(floor)
}

#[derive(Debug, Clone, PartialEq, thiserror::Error, Serialize, serde::Deserialize)]
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
    #[error("the template was drawn without its fine version (TemplateSpec::fine), which matching samples")]
    NoFineDrawing,
}

/// Matches `tpl` into `img` starting with its centre at `start` and the template's axes along
/// the image's (the template is drawn at the image's pixel spacing).
pub fn match_template(
    img: &ImageF32,
    tpl: &Template,
    start: PixelXY,
    opt: &LsmOptions,
) -> Result<LsmMatch, LsmError> {
    match &tpl.fine {
        Some(fine) => match_sampling_template(img, tpl, fine, start, opt),
        None => Err(LsmError::NoFineDrawing),
    }
}

/// The same model with the roles turned: each image pixel x of a fixed window is predicted
/// from the finely drawn template, `g(x) = r0 + r1·f(U(x − s))` with U affine (u0, u1, u2,
/// v0, v1, v2) from the window's start s to template coordinates. The image is used only at
/// its own pixels, so no interpolation error enters; the template is smooth and drawn
/// [`FINE`] times finer, so sampling it is all but exact. The mark's centre is where U is
/// zero, and its covariance follows from the parameters' by the Jacobian of that solution.
fn match_sampling_template(
    img: &ImageF32,
    tpl: &Template,
    fine: &ImageF32,
    start: PixelXY,
    opt: &LsmOptions,
) -> Result<LsmMatch, LsmError> {
    let n = tpl.size();
    let half = n as f64 / 2.0;
    let k = FINE as f64;
    // The window: the n×n image pixels around the start, as far as the image has them (the
    // share of the mark's ink they hold is reported; the gate decides).
    if !(start.col.is_finite() && start.row.is_finite()) {
        return Err(LsmError::LeftWindow);
    }
    let c0 = (start.col - half).round();
    let r0 = (start.row - half).round();
    let (w, h) = (img.width as f64, img.height as f64);
    if c0 + n as f64 <= 0.0 || r0 + n as f64 <= 0.0 || c0 >= w || r0 >= h {
        return Err(LsmError::LeftWindow);
    }
    let (c0, r0) = (c0 as i64, r0 as i64);
    let background = tpl.image.data[0] as f64;
    let (mut ink_all, mut ink_in) = (0.0, 0.0);
    let mut pix: Vec<(f64, f64, f64)> = Vec::with_capacity(n * n);
    // Each of them's place in the window, for the residuals' correlation.
    let mut place: Vec<usize> = Vec::with_capacity(n * n);
    for i in 0..n * n {
        let ink = (tpl.image.data[i] as f64 - background).abs();
        ink_all += ink;
        let (c, r) = (c0 + (i % n) as i64, r0 + (i / n) as i64);
        if c < 0 || r < 0 || c >= img.width as i64 || r >= img.height as i64 {
            continue;
        }
        ink_in += ink;
        place.push(i);
        let (c, r) = (c as usize, r as usize);
        pix.push((
            c as f64 + 0.5 - start.col,
            r as f64 + 0.5 - start.row,
            img.data[r * img.width + c] as f64,
        ));
    }
    let inside_share = if ink_all > 0.0 { ink_in / ink_all } else { 0.0 };
    // Too little of the window or of the mark to solve anything.
    if pix.len() < n * n / 4 || inside_share < 0.25 {
        return Err(LsmError::LeftWindow);
    }
    let np = pix.len() as f64;
    let gm = pix.iter().map(|p| p.2).sum::<f64>() / np;
    let gs = (pix.iter().map(|p| (p.2 - gm).powi(2)).sum::<f64>() / np).sqrt();
    if gs < opt.min_contrast_dn {
        return Err(LsmError::LowContrast { contrast_dn: gs });
    }
    // Template coordinates (template pixels, about its centre) → the fine drawing's.
    let off = (half + FINE_PAD as f64) * k;
    let sample_f = |u: &[f64; 6]| -> Option<Vec<(f64, f64, f64)>> {
        pix.iter()
            .map(|&(dx, dy, _)| {
                let tx = u[0] + u[1] * dx + u[2] * dy;
                let ty = u[3] + u[4] * dx + u[5] * dy;
                sample(fine, off + tx * k, off + ty * k).map(|(v, fx, fy)| (v, fx * k, fy * k))
            })
            .collect()
    };
    let mut u = [0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let f0 = sample_f(&u).ok_or(LsmError::LeftWindow)?;
    let fm = f0.iter().map(|f| f.0).sum::<f64>() / np;
    let fs = (f0.iter().map(|f| (f.0 - fm).powi(2)).sum::<f64>() / np).sqrt();
    if fs < 1e-6 {
        return Err(LsmError::LowContrast { contrast_dn: gs });
    }
    let mut r = [gm - gs / fs * fm, gs / fs];
    // The centre: where U(d) = 0, d = −M⁻¹·(u0, v0).
    let centre_of = |u: &[f64; 6]| -> Option<[f64; 2]> {
        inv2(linear_part(u)).map(|m| {
            let v = mul2(m, [u[0], u[3]]);
            [-v[0], -v[1]]
        })
    };
    // The model's parameters: its geometric ones (their effect on U in `jac`), then r0, r1.
    let jac = opt
        .geometry
        .jacobian(tpl.um_per_px)
        .ok_or(LsmError::Singular)?;
    let ng = jac.len();
    let nu = ng + 2;
    // Residuals, their robust σ and the Huber weights.
    let weights = |r: &[f64; 2], f: &[(f64, f64, f64)]| {
        let v: Vec<f64> = pix
            .iter()
            .zip(f)
            .map(|(p, f)| p.2 - r[0] - r[1] * f.0)
            .collect();
        let s = robust_sigma(&v, ROBUST_FLOOR * r[1].abs());
        let cut = opt.huber_k * s;
        let w: Vec<f64> = v
            .iter()
            .map(|x| if x.abs() <= cut { 1.0 } else { cut / x.abs() })
            .collect();
        (v, w, s)
    };
    // One observation's row of the design matrix: ∂g/∂(the geometric parameters, r0, r1).
    let design_row = |r: &[f64; 2],
                      &(dx, dy, _): &(f64, f64, f64),
                      &(fv, fx, fy): &(f64, f64, f64),
                      row: &mut DVector<f64>| {
        let (ax, ay) = (r[1] * fx, r[1] * fy);
        let full = [ax, ax * dx, ax * dy, ay, ay * dx, ay * dy];
        for (j, col) in jac.iter().enumerate() {
            row[j] = (0..6).map(|i| full[i] * col[i]).sum();
        }
        row[ng] = 1.0;
        row[ng + 1] = fv;
    };
    let normal = |r: &[f64; 2], f: &[(f64, f64, f64)], wt: &[f64]| {
        let mut nm = DMatrix::<f64>::zeros(nu, nu);
        let mut rhs = DVector::<f64>::zeros(nu);
        let mut row = DVector::<f64>::zeros(nu);
        let mut vv = 0.0;
        for ((p, fi), &wi) in pix.iter().zip(f).zip(wt) {
            design_row(r, p, fi, &mut row);
            let (g, fv) = (p.2, fi.0);
            let l = g - r[0] - r[1] * fv;
            vv += wi * l * l;
            nm.ger(wi, &row, &row, 1.0);
            rhs.axpy(wi * l, &row, 1.0);
        }
        (nm, rhs, vv)
    };
    let mut prev = centre_of(&u).unwrap_or([0.0, 0.0]);
    let mut settled = 0;
    let mut it = 0;
    loop {
        it += 1;
        let f = sample_f(&u).ok_or(LsmError::LeftWindow)?;
        let (_, wt, _) = weights(&r, &f);
        let (nm, rhs, _) = normal(&r, &f, &wt);
        let dp = nm.cholesky().ok_or(LsmError::Singular)?.solve(&rhs);
        // The change of U, and of the radiometry.
        let mut d = [0.0; 6];
        for (j, col) in jac.iter().enumerate() {
            for i in 0..6 {
                d[i] += col[i] * dp[j];
            }
        }
        for j in 0..6 {
            u[j] += d[j];
        }
        r[0] += dp[ng];
        r[1] += dp[ng + 1];
        let det = u[1] * u[5] - u[2] * u[4];
        if !(0.5..2.0).contains(&det) {
            return Err(LsmError::Diverged { iterations: it });
        }
        let c = centre_of(&u).ok_or(LsmError::Singular)?;
        let moved = c[0].hypot(c[1]);
        if !moved.is_finite() || moved > opt.max_shift_px {
            return Err(LsmError::Wandered { moved_px: moved });
        }
        let step = (c[0] - prev[0]).hypot(c[1] - prev[1]);
        prev = c;
        // The centre is what is wanted. Converged when it has settled twice running with the
        // shape settled too, or four times running while the shape still swings along a
        // weakly determined direction (a ring's rotation oscillates by ±0.1° there, moving
        // nothing of the centre).
        let shape_small = [d[1], d[2], d[4], d[5]]
            .iter()
            .all(|v| v.abs() * half < opt.tolerance_px * 10.0);
        settled = if step < opt.tolerance_px {
            settled + 1
        } else {
            0
        };
        if (settled >= 2 && shape_small) || settled >= 4 {
            let f = sample_f(&u).ok_or(LsmError::LeftWindow)?;
            let (v, wt, s) = weights(&r, &f);
            let (nm, _, vv) = normal(&r, &f, &wt);
            let (mut e_all, mut e_out) = (0.0, 0.0);
            let e_max = f
                .iter()
                .map(|fi| fi.1 * fi.1 + fi.2 * fi.2)
                .fold(0.0, f64::max);
            let (mut n_mark, mut n_out) = (0usize, 0usize);
            for (fi, vi) in f.iter().zip(&v) {
                let e = fi.1 * fi.1 + fi.2 * fi.2;
                let out = vi.abs() > opt.huber_k * s;
                e_all += e;
                if out {
                    e_out += e;
                }
                if e >= 0.05 * e_max {
                    n_mark += 1;
                    n_out += out as usize;
                }
            }
            let n_eff: f64 = wt.iter().sum();
            let qp = nm.try_inverse().ok_or(LsmError::Singular)?;
            let sigma0 = (vv / (n_eff - nu as f64).max(1.0)).sqrt();
            // ∂centre/∂u: −M⁻¹ applied to the unit vectors (shifts) and to d (shape).
            let mi = inv2(linear_part(&u)).ok_or(LsmError::Singular)?;
            let col = |v: [f64; 2]| {
                let w = mul2(mi, v);
                [-w[0], -w[1]]
            };
            let cols = [
                col([1.0, 0.0]),
                col([c[0], 0.0]),
                col([c[1], 0.0]),
                col([0.0, 1.0]),
                col([0.0, c[0]]),
                col([0.0, c[1]]),
            ];
            // The centre's variance without assuming white residuals: each pixel's influence on
            // the centre, h = g·N⁻¹·aᵢ (g = ∂centre/∂parameters), against the residuals'
            // own autocovariance up to HAC_LAG px (Bartlett-tapered: the Newey–West
            // estimator, with Huber's ψ(v) = w·v), so that column stripes, grain or a blur
            // that the template lacks widen σ as they widen the true error.
            let influence = |a: usize| -> Vec<f64> {
                let mut gp = DVector::<f64>::zeros(nu);
                for (p, jc) in jac.iter().enumerate() {
                    gp[p] = (0..6).map(|i| cols[i][a] * jc[i]).sum();
                }
                let t = &qp * gp;
                let mut h = vec![0.0; n * n];
                let mut row = DVector::<f64>::zeros(nu);
                for (k, (p, fi)) in pix.iter().zip(&f).enumerate() {
                    design_row(&r, p, fi, &mut row);
                    h[place[k]] = row.dot(&t);
                }
                h
            };
            let mut psi = vec![0.0; n * n];
            let mut inside = vec![false; n * n];
            for k in 0..pix.len() {
                psi[place[k]] = wt[k] * v[k];
                inside[place[k]] = true;
            }
            let var = crate::hac::variance(
                [&influence(0), &influence(1)],
                &psi,
                &inside,
                n,
                HAC_LAG,
                np / (np - nu as f64).max(1.0),
            );
            let (g, t): (Vec<f64>, Vec<f64>) = pix.iter().zip(&f).map(|(p, f)| (p.2, f.0)).unzip();
            let corr = crate::correlation::ncc(&g, &t);
            let centre = PixelXY::new(start.col + c[0], start.row + c[1]);
            return Ok(LsmMatch {
                centre,
                sigma_px: [var[0].sqrt(), var[1].sqrt()],
                // Image from template: x = centre + M⁻¹·t.
                affine: [
                    centre.col, mi[0][0], mi[0][1], centre.row, mi[1][0], mi[1][1],
                ],
                radiometric: r,
                sigma0_dn: sigma0,
                correlation: corr,
                iterations: it,
                moved_px: c,
                inside_share,
                outlier_share: if e_all > 0.0 { e_out / e_all } else { 0.0 },
                outlier_pixels: n_out as f64 / n_mark.max(1) as f64,
                mark_pixels: n_mark,
                evidence_peak_share: if e_all > 0.0 { e_max / e_all } else { 0.0 },
            });
        }
        if it >= opt.max_iterations {
            return Err(LsmError::Diverged { iterations: it });
        }
    }
}
