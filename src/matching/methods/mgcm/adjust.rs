//! Multiphoto geometrically constrained matching at one point (seed 002; Gruen and Baltsavias
//! 1987/88): a template around a pixel of the reference photo is matched into every search
//! photo at once by least squares, each search patch with its own shape (affine) and
//! radiometry (offset and gain), and every patch centre tied to the one object point X, Y, Z
//! through the sensors (collinearity, or whatever the [`Sensor`] is: seed 004's mapping
//! functions with the same equations).
//!
//! Grey-value observations, per search photo k and template pixel u (offset from the template
//! centre):  t(u) − [r0ₖ + r1ₖ·gₖ(cₖ + Mₖ·u)] = v, linearised in cₖ (the patch centre), Mₖ (its
//! shape), r0ₖ, r1ₖ.  Geometric constraints, per photo k (the reference included, whose centre
//! is the template's q₀): cₖ − Fₖ(X, Y, Z) = 0, Fₖ the sensor's ground → image.
//!
//! * **Hard** constraints (`Constraint::Hard`): the constraints hold exactly, so the point lies
//!   on the reference ray, P(Z), and cₖ = Fₖ(P(Z)); the unknowns are Z and each photo's shape
//!   and radiometry. The search patches move along their epipolar lines only.
//! * **Soft** constraints (`Constraint::Soft`): the constraints are observations of weight
//!   σ₀²/σc² beside the grey values, with X, Y, Z and every cₖ unknown; a patch can leave its
//!   epipolar line by what the grey values insist on, and the constraint residual says how far.
//!
//! Precision: the formal σ's are σ₀·√Q from the normal matrix; the reported ones add what
//! the formal model leaves out (see [`Solution::sigma`]): the residuals' correlation within a
//! patch (resampling, terrain within the patch, a template a little unlike the patch:
//! [`crate::hac`]) and a pointing error of the orientation, each propagated to X, Y, Z.

use crate::coords::{GroundM, PixelXY};
use crate::geometry::Sensor;
use crate::matching::methods::mgcm::pyramid::Textured;
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// How the collinearity constraints enter the adjustment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Constraint {
    /// Exactly: the patches move along their epipolar lines only.
    Hard,
    /// As observations of standard deviation `sigma_px` (pixels of each photo).
    Soft { sigma_px: f64 },
}

/// Parameters of one point's matching.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AdjustParams {
    /// Half-size of the template: the patch is (2·half + 1)² pixels (seed 002's final run:
    /// 13², half = 6).
    pub half: usize,
    /// Estimate each search patch's shape (four affine parameters); otherwise its shape is
    /// the sensors' mapping of the reference patch onto a level plane at the current height
    /// and only the shifts (through X, Y, Z) are estimated, as the seed's final run did.
    pub affine: bool,
    pub constraint: Constraint,
    pub max_iterations: usize,
    /// Converged when no patch centre moves by more than this, pixels.
    pub converged_px: f64,
    /// A patch that moves further than this from its approximation (pixels of its photo) has
    /// wandered: the approximation was wrong or the texture repeats.
    pub max_move_px: f64,
    /// Pointing error of the orientation, pixels per photo (0 when the orientation is exact):
    /// propagated to X, Y, Z in the reported σ's.
    pub orientation_px: f64,
}

impl Default for AdjustParams {
    fn default() -> Self {
        AdjustParams {
            half: 6,
            affine: false,
            constraint: Constraint::Hard,
            max_iterations: 20,
            converged_px: 0.002,
            max_move_px: 3.0,
            orientation_px: 0.0,
        }
    }
}

/// A photo as the matching sees it at one level: its image (with gradients) and its sensor.
#[derive(Clone, Copy)]
pub struct View<'a> {
    pub image: &'a Textured,
    pub sensor: &'a (dyn Sensor + Sync),
}

/// Why a point could not be matched at all.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum PointFailure {
    #[error("the template lies too near the reference photo's edge")]
    TemplateOutside,
    #[error("a search patch left its photo")]
    PatchOutside,
    #[error("the template is flat: nothing to match")]
    Flat,
    #[error("the ray does not reach the height (the sensor cannot see it)")]
    NoRay,
    #[error("fewer than two rays (the reference and one search photo) left")]
    TooFewRays,
    #[error("the normal matrix is singular (no texture across the epipolar lines)")]
    Singular,
    #[error("no convergence in {iterations} iterations")]
    NoConvergence { iterations: usize },
    #[error("a patch moved {moved_px:.1} px from its approximation (more than allowed)")]
    Wandered { moved_px: f64 },
    #[error("a patch's radiometric gain became {gain:.2} (the patch is not the template's)")]
    Gain { gain: f64 },
}

/// The state of one search photo's patch.
#[derive(Debug, Clone, Copy)]
pub(super) struct Patch {
    /// Index into the caller's views.
    pub photo: usize,
    pub centre: PixelXY,
    pub start: PixelXY,
    /// Reference pixel offset → this photo's pixel offset.
    pub shape: [[f64; 2]; 2],
    pub r0: f64,
    pub r1: f64,
}

/// One search photo's part of a solution.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RayFit {
    /// Index into the caller's views.
    pub photo: usize,
    /// Patch centre in the photo's continuous pixels (corner origin).
    pub centre: PixelXY,
    /// How far the centre moved from its approximation, px.
    pub moved_px: f64,
    /// The patch centre minus the object point's projection, px (0 under hard constraints).
    pub constraint_px: [f64; 2],
    /// Correlation of the template and the resampled patch.
    pub corr: f64,
    /// RMS grey residual of this ray.
    pub rms: f64,
    pub gain: f64,
    pub offset: f64,
    /// Reference pixel offset → this photo's pixel offset at the solution.
    pub shape: [[f64; 2]; 2],
}

/// A matched point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Solution {
    pub ground: GroundM,
    /// Standard deviations of X, Y, Z, m, as reported: the grey values' part of the formal σ
    /// scaled by what the residuals' correlation adds (at least a quarter of it, see
    /// [`finish`]), the soft constraints' part, and the orientation's pointing error.
    pub sigma: [f64; 3],
    /// The formal ones: σ₀·√Q from the normal matrix, m.
    pub sigma_formal: [f64; 3],
    /// The orientations' part of `sigma`, m: an error common to neighbouring points (tests
    /// that compare a point with its neighbours leave it out).
    #[serde(default)]
    pub sigma_orientation: [f64; 3],
    /// σ₀ of the grey values (unit weight).
    pub sigma0: f64,
    pub iterations: usize,
    pub rays: Vec<RayFit>,
    /// Metres of height per pixel of movement along the epipolar line of the ray that moves
    /// most with the height (to express errors in pixels of parallax).
    pub m_per_px: f64,
}

impl Solution {
    /// Mean correlation over the search rays.
    pub fn corr(&self) -> f64 {
        self.rays.iter().map(|r| r.corr).sum::<f64>() / self.rays.len().max(1) as f64
    }
}

/// Reference pixel offset (du, dv) → search pixel offset at ground height z: the sensors'
/// local mapping of a level plane, by differences of ±1 px.
pub(super) fn local_shape(
    reference: &dyn Sensor,
    search: &dyn Sensor,
    q0: PixelXY,
    z: f64,
) -> Option<[[f64; 2]; 2]> {
    let at = |dc: f64, dr: f64| {
        let g = reference.image_to_ground(PixelXY::new(q0.col + dc, q0.row + dr), z)?;
        search.ground_to_image(g)
    };
    let (xp, xm, yp, ym) = (at(1.0, 0.0)?, at(-1.0, 0.0)?, at(0.0, 1.0)?, at(0.0, -1.0)?);
    let m = [
        [0.5 * (xp.col - xm.col), 0.5 * (yp.col - ym.col)],
        [0.5 * (xp.row - xm.row), 0.5 * (yp.row - ym.row)],
    ];
    m.iter().flatten().all(|v| v.is_finite()).then_some(m)
}

/// The template: (2h+1)² grey values around integer pixel (c, r) of the reference image, and
/// their gradients.
pub(super) struct Template {
    pub values: Vec<f64>,
    pub grad: Vec<[f64; 2]>,
}

pub(super) fn template(
    img: &Textured,
    c: usize,
    r: usize,
    h: usize,
) -> Result<Template, PointFailure> {
    let im = &img.image;
    if c < h || r < h || c + h >= im.width || r + h >= im.height {
        return Err(PointFailure::TemplateOutside);
    }
    let n = (2 * h + 1).pow(2);
    let (mut values, mut grad) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for y in r - h..=r + h {
        for x in c - h..=c + h {
            values.push(im.at(x, y) as f64);
            grad.push([img.gx.at(x, y) as f64, img.gy.at(x, y) as f64]);
        }
    }
    Ok(Template { values, grad })
}

pub(super) fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    let s = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n).sqrt();
    (m, s)
}

/// One template pixel's sample of a search patch: the modelled grey value r0 + r1·g and two
/// rows of partial derivatives with respect to (centre col, centre row, shape 00, 01, 10,
/// 11, r0, r1): `a` with the slope taken from the template, `j` with the patch's own.
#[derive(Debug, Clone, Copy)]
pub(super) struct Sample {
    pub g: f64,
    pub a: [f64; 8],
    pub j: [f64; 8],
}

/// The patch's samples at the template's pixels.
///
/// The design uses the slope from the template, M⁻ᵀ·∇t (the model says t(u) = r0 +
/// r1·g(c + M·u), so ∇t = r1·Mᵀ·∇g), not the resampled patch's: the patch's own slope,
/// resampled with its noise, correlates with its resampled value and pulls the solution
/// toward whole pixels; the template's slope at a pixel does not contain that pixel. Both
/// slopes are noisy, and independently so: the precision is taken from both (see
/// [`finish`]).
pub(super) fn sample_patch(
    img: &Textured,
    p: &Patch,
    h: usize,
    tgrad: &[[f64; 2]],
    out: &mut Vec<Sample>,
) -> Option<()> {
    out.clear();
    let m = p.shape;
    let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    if det.abs().is_nan() || det.abs() <= 1e-9 {
        return None;
    }
    // M⁻ᵀ.
    let mit = [
        [m[1][1] / det, -m[1][0] / det],
        [-m[0][1] / det, m[0][0] / det],
    ];
    let h = h as i64;
    let mut i = 0;
    for v in -h..=h {
        for u in -h..=h {
            let (du, dv) = (u as f64, v as f64);
            let x = p.centre.col + p.shape[0][0] * du + p.shape[0][1] * dv;
            let y = p.centre.row + p.shape[1][0] * du + p.shape[1][1] * dv;
            let [g, gx, gy] = img.sample(x, y)?;
            let [tx, ty] = tgrad[i];
            i += 1;
            let (ax, ay) = (
                mit[0][0] * tx + mit[0][1] * ty,
                mit[1][0] * tx + mit[1][1] * ty,
            );
            let (jx, jy) = (p.r1 * gx, p.r1 * gy);
            out.push(Sample {
                g: p.r0 + p.r1 * g,
                a: [ax, ay, ax * du, ax * dv, ay * du, ay * dv, 1.0, g],
                j: [jx, jy, jx * du, jx * dv, jy * du, jy * dv, 1.0, g],
            });
        }
    }
    Some(())
}

/// Where the unknowns of patch k sit in the parameter vector, and how many there are.
struct Layout {
    /// Geometric unknowns before the patches': 1 (Z) hard, 3 (X, Y, Z) soft.
    point: usize,
    /// Per patch: 2 centre (soft only) + 4 shape (affine only) + 2 radiometric.
    per: usize,
    soft: bool,
    affine: bool,
}

impl Layout {
    fn new(p: &AdjustParams) -> Layout {
        let soft = matches!(p.constraint, Constraint::Soft { .. });
        Layout {
            point: if soft { 3 } else { 1 },
            per: 2 + if soft { 2 } else { 0 } + if p.affine { 4 } else { 0 },
            soft,
            affine: p.affine,
        }
    }
    fn total(&self, patches: usize) -> usize {
        self.point + self.per * patches
    }

    /// The observation row of patch k's grey value from its derivatives `d` (see
    /// [`Sample`]); `dcdz` the patch centre's movement per metre of height (hard constraints).
    fn design(&self, k: usize, d: &[f64; 8], dcdz: [f64; 2], row: &mut DVector<f64>) {
        row.fill(0.0);
        let base = self.base(k);
        if self.soft {
            row[base] = d[0];
            row[base + 1] = d[1];
        } else {
            row[0] = d[0] * dcdz[0] + d[1] * dcdz[1];
        }
        let mut j = base + if self.soft { 2 } else { 0 };
        if self.affine {
            for s in 2..6 {
                row[j] = d[s];
                j += 1;
            }
        }
        row[j] = d[6];
        row[j + 1] = d[7];
    }
    /// Index of patch k's first own unknown.
    fn base(&self, k: usize) -> usize {
        self.point + self.per * k
    }
}

/// Matches the template around integer pixel `q0` of `reference` into `searches` from the
/// approximate height `z0`. Every search view must see the point; a ray whose patch leaves its
/// image makes the whole solution fail (the caller drops that ray and tries again, see
/// [`crate::matching::methods::mgcm::point::match_point`]).
pub fn solve(
    reference: View<'_>,
    q0: (usize, usize),
    searches: &[View<'_>],
    z0: f64,
    p: &AdjustParams,
) -> Result<Solution, PointFailure> {
    let h = p.half;
    let tpl = template(reference.image, q0.0, q0.1, h)?;
    let t = &tpl.values;
    let (tm, ts) = mean_sd(t);
    if ts <= 1e-9 * tm.abs().max(1.0) {
        return Err(PointFailure::Flat);
    }
    if searches.is_empty() {
        return Err(PointFailure::TooFewRays);
    }
    let qc = PixelXY::new(q0.0 as f64 + 0.5, q0.1 as f64 + 0.5);
    let on_ray = |z: f64| reference.sensor.image_to_ground(qc, z);
    let lay = Layout::new(p);
    let mut point = on_ray(z0).ok_or(PointFailure::NoRay)?;
    let mut patches = Vec::with_capacity(searches.len());
    let mut buf = Vec::new();
    for (k, s) in searches.iter().enumerate() {
        let centre = s.sensor.ground_to_image(point).ok_or(PointFailure::NoRay)?;
        let shape =
            local_shape(reference.sensor, s.sensor, qc, point.z).ok_or(PointFailure::NoRay)?;
        let mut patch = Patch {
            photo: k,
            centre,
            start: centre,
            shape,
            r0: 0.0,
            r1: 1.0,
        };
        // The seed's radiometric equalisation: the patch's mean and σ made the template's.
        sample_patch(s.image, &patch, h, &tpl.grad, &mut buf).ok_or(PointFailure::PatchOutside)?;
        let g: Vec<f64> = buf.iter().map(|b| b.g).collect();
        let (gm, gs) = mean_sd(&g);
        patch.r1 = if gs > 0.0 { ts / gs } else { 1.0 };
        patch.r0 = tm - patch.r1 * gm;
        patches.push(patch);
    }
    let nu = lay.total(patches.len());
    let n_grey = t.len() * patches.len();
    let mut iterations = 0;
    let mut converged = false;
    let mut normal = DMatrix::<f64>::zeros(nu, nu);
    let mut rhs = DVector::<f64>::zeros(nu);
    let mut row = DVector::<f64>::zeros(nu);
    // Per patch: d(centre)/dZ under hard constraints.
    let mut dcdz = vec![[0.0; 2]; patches.len()];
    while iterations < p.max_iterations {
        iterations += 1;
        normal.fill(0.0);
        rhs.fill(0.0);
        if !lay.soft {
            for (k, s) in searches.iter().enumerate() {
                let dz = 0.5;
                let a = on_ray(point.z + dz).and_then(|g| s.sensor.ground_to_image(g));
                let b = on_ray(point.z - dz).and_then(|g| s.sensor.ground_to_image(g));
                let (a, b) = a.zip(b).ok_or(PointFailure::NoRay)?;
                dcdz[k] = [(a.col - b.col) / (2.0 * dz), (a.row - b.row) / (2.0 * dz)];
            }
        }
        let mut vv = 0.0;
        for (k, patch) in patches.iter().enumerate() {
            sample_patch(searches[k].image, patch, h, &tpl.grad, &mut buf)
                .ok_or(PointFailure::PatchOutside)?;
            let base = lay.base(k);
            for (ti, smp) in t.iter().zip(&buf) {
                let l = ti - smp.g;
                vv += l * l;
                lay.design(k, &smp.a, dcdz[k], &mut row);
                // Only this patch's unknowns (and the point's) are non-zero.
                accumulate(&mut normal, &mut rhs, &row, l, 1.0, &lay, base);
            }
        }
        // The grey values' variance at this iteration weighs the constraints against them.
        let dof = (n_grey as f64 - nu as f64).max(1.0);
        let sigma0_sq = vv / dof;
        if let Constraint::Soft { sigma_px } = p.constraint {
            let w = sigma0_sq.max(1e-12) / (sigma_px * sigma_px).max(1e-12);
            let mut add = |k: Option<usize>, target: PixelXY, s: &dyn Sensor| {
                let f = s.ground_to_image(point).ok_or(PointFailure::NoRay)?;
                let j = s.partials(point).ok_or(PointFailure::NoRay)?;
                for a in 0..2 {
                    row.fill(0.0);
                    // c − F(P) = 0: dc − J·dP = F(P⁰) − c⁰.
                    for (i, jv) in j[a].iter().enumerate() {
                        row[i] = -jv;
                    }
                    let (fa, ta) = if a == 0 {
                        (f.col, target.col)
                    } else {
                        (f.row, target.row)
                    };
                    if let Some(k) = k {
                        row[lay.base(k) + a] = 1.0;
                    }
                    let l = fa - ta;
                    accumulate_full(&mut normal, &mut rhs, &row, l, w);
                }
                Ok::<(), PointFailure>(())
            };
            add(None, qc, reference.sensor)?;
            for (k, patch) in patches.iter().enumerate() {
                add(Some(k), patch.centre, searches[k].sensor)?;
            }
        }
        let Some(chol) = normal.clone().cholesky() else {
            return Err(PointFailure::Singular);
        };
        let dx = chol.solve(&rhs);
        // Apply.
        let mut moved: f64 = 0.0;
        if lay.soft {
            point = GroundM::new(point.x + dx[0], point.y + dx[1], point.z + dx[2]);
        } else {
            point = on_ray(point.z + dx[0]).ok_or(PointFailure::NoRay)?;
        }
        for (k, patch) in patches.iter_mut().enumerate() {
            let base = lay.base(k);
            let old = patch.centre;
            if lay.soft {
                patch.centre = PixelXY::new(old.col + dx[base], old.row + dx[base + 1]);
            } else {
                patch.centre = searches[k]
                    .sensor
                    .ground_to_image(point)
                    .ok_or(PointFailure::NoRay)?;
            }
            let mut j = base + if lay.soft { 2 } else { 0 };
            if lay.affine {
                patch.shape[0][0] += dx[j];
                patch.shape[0][1] += dx[j + 1];
                patch.shape[1][0] += dx[j + 2];
                patch.shape[1][1] += dx[j + 3];
                j += 4;
            } else if let Some(s) = local_shape(reference.sensor, searches[k].sensor, qc, point.z) {
                patch.shape = s;
            }
            patch.r0 += dx[j];
            patch.r1 += dx[j + 1];
            moved = moved.max(patch.centre.dist(old));
            let total = patch.centre.dist(patch.start);
            if total.is_nan() || total > p.max_move_px {
                return Err(PointFailure::Wandered { moved_px: total });
            }
            if !(patch.r1 > 0.2 && patch.r1 < 5.0) {
                return Err(PointFailure::Gain { gain: patch.r1 });
            }
        }
        if !point.z.is_finite() {
            return Err(PointFailure::Singular);
        }
        if moved < p.converged_px {
            converged = true;
            break;
        }
    }
    if !converged {
        return Err(PointFailure::NoConvergence { iterations });
    }
    finish(
        reference, qc, searches, &tpl, &patches, point, p, &lay, iterations,
    )
}

/// Each search patch's centre's movement per metre of height along the reference ray at
/// height `z` (central differences over ±0.5 m), px/m.
fn centre_rates(
    on_ray: &dyn Fn(f64) -> Option<GroundM>,
    searches: &[View<'_>],
    z: f64,
) -> Result<Vec<[f64; 2]>, PointFailure> {
    let dz = 0.5;
    searches
        .iter()
        .map(|s| {
            let a = on_ray(z + dz).and_then(|g| s.sensor.ground_to_image(g));
            let b = on_ray(z - dz).and_then(|g| s.sensor.ground_to_image(g));
            let (a, b) = a.zip(b).ok_or(PointFailure::NoRay)?;
            Ok([(a.col - b.col) / (2.0 * dz), (a.row - b.row) / (2.0 * dz)])
        })
        .collect()
}

/// vᵀ·C·v for a 2-vector and a 2 × 2 covariance.
/// (Never below 0: a covariance a little short of semi-definite must not cut a variance.)
fn quadratic(v: [f64; 2], c: [[f64; 2]; 2]) -> f64 {
    (v[0] * (c[0][0] * v[0] + c[0][1] * v[1]) + v[1] * (c[1][0] * v[0] + c[1][1] * v[1])).max(0.0)
}

/// Adds observation `row` (non-zero only at the point's unknowns and at patch `base`'s) with
/// misclosure `l` and weight `w` to the normal equations.
fn accumulate(
    n: &mut DMatrix<f64>,
    b: &mut DVector<f64>,
    row: &DVector<f64>,
    l: f64,
    w: f64,
    lay: &Layout,
    base: usize,
) {
    // At most 3 + 10 unknowns (see `Layout`): on the stack, as this runs for every grey value
    // of every patch at every iteration.
    let mut nz = [0usize; 16];
    let mut count = 0;
    for i in (0..lay.point).chain(base..base + lay.per) {
        if row[i] != 0.0 {
            nz[count] = i;
            count += 1;
        }
    }
    let nz = &nz[..count];
    for &i in nz {
        let ri = w * row[i];
        b[i] += ri * l;
        for &j in nz {
            n[(i, j)] += ri * row[j];
        }
    }
}

fn accumulate_full(n: &mut DMatrix<f64>, b: &mut DVector<f64>, row: &DVector<f64>, l: f64, w: f64) {
    let nz: Vec<usize> = (0..row.len()).filter(|&i| row[i] != 0.0).collect();
    for &i in &nz {
        let ri = w * row[i];
        b[i] += ri * l;
        for &j in &nz {
            n[(i, j)] += ri * row[j];
        }
    }
}

/// One grey-value observation at the solution: its design row (template slopes), its
/// residual, and the patch's own slope there.
type Observed = (DVector<f64>, f64, [f64; 2]);

/// The converged point's σ's and each ray's figures, from the last linearisation at the
/// solution.
///
/// The solution is the root of Aᵀ(t − f(θ)) = 0, A the design with the template's slopes; a
/// perturbation n of the grey values moves it by δθ = (AᵀJ)⁻¹·Aᵀ·n, J the design with the
/// patches' own slopes (the model's Jacobian, noisy independently of A). So the covariance
/// is the sandwich σ₀²·B⁻¹·N·B⁻ᵀ (B = AᵀJ, N = AᵀA), not σ₀²·N⁻¹, which with noisy slopes
/// is too small by their (signal + noise)/signal power: by half at a slope signal-to-noise
/// of 1. Each observation's influence on a coordinate gᵀθ is hᵢ = gᵀ·B⁻¹·aᵢ; against the
/// residuals' autocovariance ([`crate::hac`]) they give the reported σ.
#[allow(clippy::too_many_arguments)]
fn finish(
    reference: View<'_>,
    qc: PixelXY,
    searches: &[View<'_>],
    tpl: &Template,
    patches: &[Patch],
    point: GroundM,
    p: &AdjustParams,
    lay: &Layout,
    iterations: usize,
) -> Result<Solution, PointFailure> {
    let h = p.half;
    let t = &tpl.values;
    let side = 2 * h + 1;
    let nu = lay.total(patches.len());
    let on_ray = |z: f64| reference.sensor.image_to_ground(qc, z);
    let mut n_mat = DMatrix::<f64>::zeros(nu, nu);
    let mut b_mat = DMatrix::<f64>::zeros(nu, nu);
    // Per patch: each observation's A row, residual, and the patch's slope (for the pointing).
    let mut rows: Vec<Vec<Observed>> = Vec::with_capacity(patches.len());
    let mut buf = Vec::new();
    // Along the reference ray: the hard constraints' design, and the parallax per metre.
    let rates = centre_rates(&on_ray, searches, point.z)?;
    let dcdz = if lay.soft {
        vec![[0.0; 2]; patches.len()]
    } else {
        rates.clone()
    };
    let mut vv = 0.0;
    let mut rays = Vec::with_capacity(patches.len());
    let mut jrow = DVector::<f64>::zeros(nu);
    for (k, patch) in patches.iter().enumerate() {
        sample_patch(searches[k].image, patch, h, &tpl.grad, &mut buf)
            .ok_or(PointFailure::PatchOutside)?;
        let mut these = Vec::with_capacity(t.len());
        let mut rv = 0.0;
        for (ti, smp) in t.iter().zip(&buf) {
            let l = ti - smp.g;
            rv += l * l;
            let mut arow = DVector::<f64>::zeros(nu);
            lay.design(k, &smp.a, dcdz[k], &mut arow);
            lay.design(k, &smp.j, dcdz[k], &mut jrow);
            // Rank-one updates in place (the same sums as adding the outer products).
            n_mat.ger(1.0, &arow, &arow, 1.0);
            b_mat.ger(1.0, &arow, &jrow, 1.0);
            these.push((arow, l, [smp.j[0], smp.j[1]]));
        }
        vv += rv;
        let g: Vec<f64> = buf.iter().map(|b| b.g).collect();
        let f = searches[k]
            .sensor
            .ground_to_image(point)
            .ok_or(PointFailure::NoRay)?;
        rays.push(RayFit {
            photo: patch.photo,
            centre: patch.centre,
            moved_px: patch.centre.dist(patch.start),
            constraint_px: [patch.centre.col - f.col, patch.centre.row - f.row],
            corr: crate::correlation::ncc(t, &g),
            rms: (rv / t.len() as f64).sqrt(),
            gain: patch.r1,
            offset: patch.r0,
            shape: patch.shape,
        });
        rows.push(these);
    }
    let n_grey = t.len() * patches.len();
    let dof = (n_grey as f64 - nu as f64).max(1.0);
    let sigma0_sq = vv / dof;
    // The soft constraints' normal matrix, apart: their observations are not grey values.
    let mut c_mat = DMatrix::<f64>::zeros(nu, nu);
    if let Constraint::Soft { sigma_px } = p.constraint {
        let w = sigma0_sq.max(1e-12) / (sigma_px * sigma_px).max(1e-12);
        let mut add = |k: Option<usize>, s: &dyn Sensor| -> Result<(), PointFailure> {
            let jac = s.partials(point).ok_or(PointFailure::NoRay)?;
            for a in 0..2 {
                let mut row = DVector::<f64>::zeros(nu);
                for (i, jv) in jac[a].iter().enumerate() {
                    row[i] = -jv;
                }
                if let Some(k) = k {
                    row[lay.base(k) + a] = 1.0;
                }
                let wr = w * &row;
                c_mat += &wr * row.transpose();
            }
            Ok(())
        };
        add(None, reference.sensor)?;
        for k in 0..patches.len() {
            add(Some(k), searches[k].sensor)?;
        }
    }
    let b_sym = 0.5 * (&b_mat + b_mat.transpose());
    let b_inv = (&b_mat + &c_mat)
        .try_inverse()
        .ok_or(PointFailure::Singular)?;
    // Half the residual variance is the template's, half the patches' (their noise alike):
    // the template's noise moves the solution through the true slopes (its own noisy slope
    // telescopes out: Σ (nᵢ₊₁ − nᵢ₋₁)·nᵢ sums to the ends), the patches' through the
    // template's noisy slopes. So Cov = σ₀²/2 · B⁻¹ (B̄ + N) B⁻ᵀ, B̄ = (B + Bᵀ)/2 standing for
    // the true slopes' Gram matrix.
    let cov_grey = 0.5 * sigma0_sq * &b_inv * (&b_sym + &n_mat) * b_inv.transpose();
    let cov_constraints = sigma0_sq * &b_inv * &c_mat * b_inv.transpose();
    // X, Y, Z as linear functions of the unknowns: soft, the first three; hard, Z and the
    // reference ray's slope dX/dZ, dY/dZ.
    let slope = {
        let (a, b) = on_ray(point.z + 0.5)
            .zip(on_ray(point.z - 0.5))
            .ok_or(PointFailure::NoRay)?;
        [a.x - b.x, a.y - b.y, 1.0]
    };
    let gvec = |axis: usize| -> DVector<f64> {
        let mut g = DVector::<f64>::zeros(nu);
        if lay.soft {
            g[axis] = 1.0;
        } else {
            g[0] = slope[axis];
        }
        g
    };
    // What the orientations' own uncertainty needs: the reference's pointing covariance,
    // each search photo's pixels per reference pixel at the point's height (Tₖ), and the
    // reference ray's sideways ground displacement per pixel (L).
    let reference_pointing = reference
        .sensor
        .pointing_covariance(point)
        .filter(|c| c.iter().flatten().all(|v| v.is_finite()));
    // Each search photo's pointing covariance, the project's pointing error between photos
    // added (px²).
    let pointing: Vec<[[f64; 2]; 2]> = searches
        .iter()
        .map(|s| {
            let mut c = s
                .sensor
                .pointing_covariance(point)
                .filter(|c| c.iter().flatten().all(|v| v.is_finite()))
                .unwrap_or([[0.0; 2]; 2]);
            c[0][0] += p.orientation_px.powi(2);
            c[1][1] += p.orientation_px.powi(2);
            c
        })
        .collect();
    let transfers: Vec<[[f64; 2]; 2]> = if reference_pointing.is_some() {
        searches
            .iter()
            .map(|s| local_shape(reference.sensor, s.sensor, qc, point.z))
            .collect::<Option<_>>()
            .ok_or(PointFailure::NoRay)?
    } else {
        vec![[[0.0; 2]; 2]; searches.len()]
    };
    let lateral = if reference_pointing.is_none() {
        [[0.0; 2]; 2]
    } else {
        let at = |dc: f64, dr: f64| {
            reference
                .sensor
                .image_to_ground(PixelXY::new(qc.col + dc, qc.row + dr), point.z)
        };
        let (a, b, c, d) = at(0.5, 0.0)
            .zip(at(-0.5, 0.0))
            .zip(at(0.0, 0.5).zip(at(0.0, -0.5)))
            .map(|((a, b), (c, d))| (a, b, c, d))
            .ok_or(PointFailure::NoRay)?;
        [[a.x - b.x, c.x - d.x], [a.y - b.y, c.y - d.y]]
    };
    let mut sigma_formal = [0.0; 3];
    let mut sigma = [0.0; 3];
    let mut sigma_orientation = [0.0; 3];
    let lag = (h / 2).max(1);
    let inside = vec![true; side * side];
    for axis in 0..3 {
        let g = gvec(axis);
        let grey_var = g.dot(&(&cov_grey * &g));
        let constraint_var = g.dot(&(&cov_constraints * &g));
        sigma_formal[axis] = (grey_var + constraint_var).max(0.0).sqrt();
        let hvec = b_inv.transpose() * &g;
        let mut hac = 0.0;
        let mut white = 0.0;
        let mut orientation = 0.0;
        let hvs: Vec<Vec<f64>> = rows
            .iter()
            .map(|these| these.iter().map(|(a, _, _)| a.dot(&hvec)).collect())
            .collect();
        let psis: Vec<Vec<f64>> = rows
            .iter()
            .map(|these| these.iter().map(|(_, l, _)| *l).collect())
            .collect();
        // Every pair of photos, each with itself included: their residuals share the
        // template's noise, whose effect on the point cancels between photos on opposite
        // sides of the reference and adds up between photos on the same side.
        // Each pair's two orders from one pass (the same numbers as two), summed in the
        // order of the pairs.
        let np = rows.len();
        let mut pair = vec![0.0; np * np];
        for k in 0..np {
            for m in k..np {
                let dof = n_grey as f64 / dof;
                if k == m {
                    [pair[k * np + k]] =
                        crate::hac::variance([&hvs[k]], &psis[k], &inside, side, lag, dof);
                } else {
                    ([pair[k * np + m]], [pair[m * np + k]]) = crate::hac::covariance(
                        [&hvs[k]],
                        &psis[k],
                        [&hvs[m]],
                        &psis[m],
                        &inside,
                        side,
                        lag,
                        dof,
                    );
                }
            }
        }
        for v in pair {
            hac += v;
        }
        // Through the reference: Σₖ sₖ·Tₖ (a pointing error of the reference moves every
        // search patch against the model by Tₖ times it).
        let mut through_reference = [0.0; 2];
        for (k, these) in rows.iter().enumerate() {
            let hv = &hvs[k];
            let s2 = psis[k].iter().map(|v| v * v).sum::<f64>() / psis[k].len() as f64;
            white += hv.iter().map(|h| h * h).sum::<f64>() * s2 * n_grey as f64 / dof;
            // A model centre δ off the feature changes each residual by −r1·∇g·δ, and the
            // coordinate by sₖ·δ = −Σ hᵢ·r1·∇gᵢ·δ.
            let s = these.iter().zip(hv).fold([0.0; 2], |acc, ((_, _, d), hi)| {
                [acc[0] - hi * d[0], acc[1] - hi * d[1]]
            });
            orientation += quadratic(s, pointing[k]);
            let t = &transfers[k];
            through_reference[0] += s[0] * t[0][0] + s[1] * t[1][0];
            through_reference[1] += s[0] * t[0][1] + s[1] * t[1][1];
        }
        // The reference's own pointing error e (its model ray through the template's
        // centre meets the feature's true ray only if e = 0): every search patch's model
        // centre is off by −Tₖ·e, and the ray itself lies −L·e aside (L = ∂(X, Y)/∂(col,
        // row) at the point's height; 0 for Z).
        if let Some(c) = reference_pointing {
            let l = if axis < 2 { lateral[axis] } else { [0.0; 2] };
            let w = [
                -(through_reference[0] + l[0]),
                -(through_reference[1] + l[1]),
            ];
            orientation += quadratic(w, c);
        }
        let orientation_var = orientation;
        sigma_orientation[axis] = orientation_var.sqrt();
        // The residuals' correlation (within a patch, and between photos through the
        // template) scales the model's variance by what it adds to white residuals' (never
        // below a quarter: a window too small to estimate it may read near zero).
        let factor = if white > 0.0 {
            (hac / white).max(0.25)
        } else {
            1.0
        };
        sigma[axis] = (factor * grey_var + constraint_var + orientation_var)
            .max(0.0)
            .sqrt();
    }
    let best = rates.iter().map(|d| d[0].hypot(d[1])).fold(0.0, f64::max);
    let m_per_px = 1.0 / best.max(1e-12);
    Ok(Solution {
        ground: point,
        sigma,
        sigma_formal,
        sigma_orientation,
        sigma0: sigma0_sq.sqrt(),
        iterations,
        rays,
        m_per_px,
    })
}
