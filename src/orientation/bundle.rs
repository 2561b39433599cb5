//! The bundle adjustment: every photo's exterior orientation and every tie point's ground
//! position from all the rays at once, by Levenberg–Marquardt on the collinearity equations
//! (Brown 1976, "The bundle adjustment — progress and prospects"; Triggs et al. 2000).
//!
//! - Observations: photo coordinates (mm), each ray with its own σ (a measurement's or a
//!   least-squares match's). Priors: control points' ground (their σ), and the photos'
//!   approximate centres and angles (a flight index map's σ), each a pseudo-observation.
//! - Each iteration the points are eliminated (the Schur complement, [`super::reduced`]) and
//!   the reduced camera system is factored sparse; the points follow by back-substitution.
//! - Robust weights (Huber 1964, k = [`Settings::huber_k`] σ) keep a blunder from pulling the
//!   block while it converges; then data snooping tests each ray (Baarda 1968; with the
//!   a-posteriori σ̂₀, Pope's τ, 1976) with its own redundancy from the full cofactor matrix,
//!   rejects the worst ray of each point over the critical value, and adjusts again — as seed
//!   002 tests each ray of its multiphoto matching.
//! - The result carries σ̂₀²·Q of the orientations (all photos, with their correlations) and
//!   of each point (Förstner & Wrobel 2016, "Photogrammetric Computer Vision", §4.2.6).

use super::collinearity::{linearise, Rotation};
use super::reduced::{Reduced, ReducedError};
use crate::coords::{GroundM, PhotoMm};
use crate::geometry::{intersect, resect, Exterior, FrameCamera, Interior};
use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, SMatrix, Vector2, Vector3, Vector6};
use rayon::prelude::*;

/// How well a photo's approximate orientation is known (a flight index map's, a GNSS's).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Prior {
    pub position_sigma_m: f64,
    pub angles_sigma_rad: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub struct BlockPhoto {
    pub id: String,
    pub interior: Interior,
    /// The pixel's size, mm: residuals are reported in pixels.
    pub pixel_mm: f64,
    /// The approximate orientation, or `None`: found from the control and tie points.
    pub approx: Option<Exterior>,
    /// Its weight in the adjustment, or `None`: a start value only.
    pub prior: Option<Prior>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Role {
    /// Ground known to σ (X, Y, Z; m): a weighted observation of the point.
    Control { ground: GroundM, sigma_m: [f64; 3] },
    /// Ground unknown.
    Tie,
    /// Ground known, never used: intersected afterwards and compared.
    Check { ground: GroundM },
}

#[derive(Debug, Clone, PartialEq)]
pub struct BlockPoint {
    pub id: String,
    pub role: Role,
}

/// One ray: where point `point` appears in photo `photo` (indices into the block's lists).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    pub point: usize,
    pub photo: usize,
    pub xy: PhotoMm,
    pub sigma_mm: f64,
    /// Which variance component its σ belongs to (0: measured in the points file, 1: matched
    /// by the rig), for [`crate::orientation::run`]'s estimate of each.
    pub group: usize,
}

#[derive(Debug, Clone, Default)]
pub struct Block {
    pub photos: Vec<BlockPhoto>,
    pub points: Vec<BlockPoint>,
    pub rays: Vec<Ray>,
    /// Refraction and the Earth's curvature: the rays are corrected to collinearity
    /// ([`crate::geometry::radial`]) with the heights of a first adjustment.
    pub radial: crate::geometry::Radial,
    /// Cameras whose interior is estimated with the block (self-calibration).
    pub calibrate: Vec<SelfCalibration>,
}

/// A camera whose interior the adjustment estimates with the block (Brown 1976's
/// self-calibrating bundle): its photos share one interior, starting from the first photo's,
/// and `free` says which of c, x₀, y₀, k₁, k₂ ([`super::collinearity::INTERIOR`]) move.
#[derive(Debug, Clone, PartialEq)]
pub struct SelfCalibration {
    pub camera: String,
    pub photos: Vec<usize>,
    pub free: [bool; 5],
}

/// A self-calibrated camera: its interior and the σ of c, x₀, y₀, k₁, k₂ (0 where held).
#[derive(Debug, Clone, PartialEq)]
pub struct Calibrated {
    pub camera: String,
    pub interior: Interior,
    pub sigma: [f64; 5],
    pub free: [bool; 5],
}

#[derive(Debug, Clone, Copy)]
pub struct Settings {
    pub max_iterations: usize,
    /// Huber's threshold, in σ of the ray.
    pub huber_k: f64,
    /// Data snooping's critical value of the normalised residual (3.29: α = 0.1 %, two-sided).
    pub critical: f64,
    /// At most this many rounds of rejection and re-adjustment.
    pub snooping_rounds: usize,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            max_iterations: 100,
            huber_k: 3.0,
            critical: 3.29,
            snooping_rounds: 8,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum RayStatus {
    /// In the adjustment.
    Used,
    /// Removed by data snooping.
    Rejected,
    /// A check point's ray: never in the adjustment.
    Check,
    /// Its point has too few rays to be adjusted (a tie point seen once).
    Unused,
}

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RayResult {
    /// Observed − adjusted, mm.
    pub residual_mm: [f64; 2],
    /// The normalised residuals (x, y), where the ray's redundancy lets it be tested.
    pub w: Option<[f64; 2]>,
    /// The ray's redundancy number (mean of x and y): its share of the block's redundancy.
    pub redundancy: f64,
    pub status: RayStatus,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdjustedPoint {
    pub ground: GroundM,
    /// σ̂₀²·Q of X, Y, Z (m²), the orientations' share included.
    pub cov: Matrix3<f64>,
    pub rays: usize,
}

#[derive(Debug, Clone)]
pub struct Adjusted {
    pub exteriors: Vec<Exterior>,
    /// Each photo's interior: the block's, or its camera's as self-calibrated.
    pub interiors: Vec<Interior>,
    pub calibrated: Vec<Calibrated>,
    /// σ̂₀²·Q of every photo's ω, φ, κ, X₀, Y₀, Z₀ (rad, m), then of each self-calibrated
    /// camera's c, x₀, y₀, k₁, k₂ and an unused sixth: 6(n + cameras) square.
    pub covariance: DMatrix<f64>,
    /// Each point's adjusted ground (tie and control), or the check point's intersection;
    /// `None` where it has too few rays.
    pub points: Vec<Option<AdjustedPoint>>,
    pub rays: Vec<RayResult>,
    /// σ̂₀: the rays' and priors' weighted residuals against their redundancy (1 when the
    /// stated σ are right).
    pub sigma0: f64,
    pub redundancy: f64,
    pub iterations: usize,
    /// Rays rejected by data snooping.
    pub rejected: usize,
}

impl Adjusted {
    /// Each photo's adjusted camera.
    pub fn cameras(&self) -> Vec<FrameCamera> {
        self.interiors
            .iter()
            .zip(&self.exteriors)
            .map(|(i, e)| FrameCamera {
                interior: *i,
                exterior: *e,
            })
            .collect()
    }

    /// σ of photo `i`'s six parameters (rad, m).
    pub fn sigma(&self, i: usize) -> [f64; 6] {
        std::array::from_fn(|k| self.covariance[(6 * i + k, 6 * i + k)].max(0.0).sqrt())
    }

    /// Cov of photos i and k (6 × 6).
    pub fn between(&self, i: usize, k: usize) -> [[f64; 6]; 6] {
        std::array::from_fn(|r| std::array::from_fn(|c| self.covariance[(6 * i + r, 6 * k + c)]))
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum BundleError {
    #[error("{found} control point(s) seen in the photos: the block's datum needs at least 3, not in a line (add gcp lines to the points file)")]
    TooFewControl { found: usize },
    #[error("the control points lie nearly in a line ({ids}): they cannot fix the block's tilt across it; add one off the line")]
    ControlInLine { ids: String },
    #[error("photo `{id}` shares no tie point with the rest of the block ({with}): measure or match points in its overlaps, or leave it out")]
    Unconnected { id: String, with: String },
    #[error("photo `{id}` has no approximate orientation and cannot be resected: it sees {points} control or intersected points (4 needed); give it `position` and `angles_deg`")]
    NoStart { id: String, points: usize },
    #[error("the adjustment did not converge in {iterations} iterations; held back most by photos {photos} and points {points}")]
    NotConverged {
        iterations: usize,
        photos: String,
        points: String,
    },
    #[error("{0}")]
    Reduced(#[from] ReducedError),
    #[error("ray {ray}: {what}")]
    BadRay { ray: usize, what: String },
    #[error("self-calibration of camera `{camera}`: {what}")]
    Calibration { camera: String, what: String },
    #[error("the block cannot determine camera `{camera}`'s {parameter}: its rays leave it free to move the photos' edge ({radius_mm:.0} mm out) by {effect_um:.1} µm (1 σ; a ray's σ is {ray_um:.1} µm), and only the approximations' σ hold it; {advice}; or leave `{key}` out of [orientation] self_calibration and give the camera's certificate value")]
    NotDeterminable {
        camera: String,
        parameter: &'static str,
        key: &'static str,
        radius_mm: f64,
        effect_um: f64,
        ray_um: f64,
        advice: &'static str,
    },
}

/// The exterior whose ω, φ, κ, X₀, Y₀, Z₀ are `v` (the order of the normal equations).
fn exterior_from(v: &Vector6<f64>) -> Exterior {
    Exterior {
        omega: v[0],
        phi: v[1],
        kappa: v[2],
        centre: GroundM::new(v[3], v[4], v[5]),
    }
}

fn vec_of(e: &Exterior) -> Vector6<f64> {
    Vector6::new(e.omega, e.phi, e.kappa, e.centre.x, e.centre.y, e.centre.z)
}

fn wrap(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

/// The rays' least-squares intersection ([`crate::geometry::intersect`]) as a vector.
fn intersect_of(rays: &[(FrameCamera, PhotoMm)]) -> Option<Vector3<f64>> {
    let g = intersect(rays).ok()?.point;
    Some(Vector3::new(g.x, g.y, g.z))
}

fn camera(p: &BlockPhoto, e: Exterior) -> FrameCamera {
    FrameCamera {
        interior: p.interior,
        exterior: e,
    }
}

impl Block {
    /// Each photo's camera with `exteriors` (in the photos' order).
    pub fn cameras(&self, exteriors: &[Exterior]) -> Vec<FrameCamera> {
        self.photos
            .iter()
            .zip(exteriors)
            .map(|(p, e)| camera(p, *e))
            .collect()
    }
}

/// Start values: each photo's exterior, each point's ground, each ray's status, each point's
/// rays in the adjustment.
type Start = (
    Vec<Exterior>,
    Vec<Vector3<f64>>,
    Vec<RayStatus>,
    Vec<Vec<usize>>,
);

/// A tested ray: its index, residual (mm), normalised residuals and redundancy number.
type TestedRay = (usize, [f64; 2], Option<[f64; 2]>, f64);

/// The linearised rays of one point and its own normal-equation block.
struct PointLin {
    v: Matrix3<f64>,
    g: Vector3<f64>,
    rays: Vec<RayLin>,
    cost: f64,
}

struct RayLin {
    ray: usize,
    photo: usize,
    a: SMatrix<f64, 2, 6>,
    /// The self-calibrated camera's parameter block and the ray's partials by it (the held
    /// parameters' columns zero).
    cal: Option<(usize, SMatrix<f64, 2, 6>)>,
    b: SMatrix<f64, 2, 3>,
    r: Vector2<f64>,
    /// 1/σ² times the robust weight.
    w: f64,
}

impl RayLin {
    /// The parameter blocks the ray observes and its partials by each: its photo's exterior,
    /// and its camera's interior where that is estimated.
    fn parts(&self) -> impl Iterator<Item = (usize, &SMatrix<f64, 2, 6>)> {
        std::iter::once((self.photo, &self.a)).chain(self.cal.as_ref().map(|(k, m)| (*k, m)))
    }
}

struct Lin {
    points: Vec<Option<PointLin>>,
    /// The diagonal blocks of the direct normal equations, photos then cameras.
    u: Vec<Matrix6<f64>>,
    /// Each photo's block with its camera's (rows: the camera's parameters).
    cross: Vec<Matrix6<f64>>,
    g: Vec<Vector6<f64>>,
    cost: f64,
}

/// The unknowns: each photo's exterior, each self-calibrated camera's interior, each point.
#[derive(Clone)]
struct Params {
    cams: Vec<Exterior>,
    ints: Vec<Interior>,
    pts: Vec<Vector3<f64>>,
}

/// The adjustment's working state.
struct State<'a> {
    block: &'a Block,
    settings: Settings,
    x: Params,
    /// Each photo's self-calibrated camera, if any (an index into `block.calibrate`).
    group: Vec<Option<usize>>,
    /// Active rays of each adjusted point (empty: the point is not adjusted).
    by_point: Vec<Vec<usize>>,
    status: Vec<RayStatus>,
    robust: bool,
    /// Whether the approximations' priors enter the normal equations (off only to tell what
    /// the rays alone determine, [`calibrated`]).
    priors: bool,
    reduced: Reduced,
}

/// Each photo's self-calibrated camera, the cameras checked.
fn groups(block: &Block) -> Result<Vec<Option<usize>>, BundleError> {
    let mut group = vec![None; block.photos.len()];
    for (g, c) in block.calibrate.iter().enumerate() {
        let bad = |what: String| BundleError::Calibration {
            camera: c.camera.clone(),
            what,
        };
        if c.photos.is_empty() || !c.free.iter().any(|f| *f) {
            return Err(bad("no photos or no parameter to estimate".into()));
        }
        for &i in &c.photos {
            if i >= block.photos.len() || group[i].is_some() {
                return Err(bad(format!("photo index {i} not in the block or in two cameras")));
            }
            if block.photos[i].interior != block.photos[c.photos[0]].interior {
                return Err(bad(format!(
                    "photo `{}` has another interior than `{}`: one camera, one interior",
                    block.photos[i].id,
                    block.photos[c.photos[0]].id
                )));
            }
            group[i] = Some(g);
        }
    }
    Ok(group)
}

impl<'a> State<'a> {
    /// The block checked, at its start values, with its pattern.
    fn begin(block: &'a Block, settings: Settings, robust: bool) -> Result<State<'a>, BundleError> {
        let group = groups(block)?;
        let (cams, pts, status, by_point) = start(block)?;
        let ints = block
            .calibrate
            .iter()
            .map(|c| block.photos[c.photos[0]].interior)
            .collect();
        let mut st = State {
            block,
            settings,
            x: Params { cams, ints, pts },
            group,
            by_point,
            status,
            robust,
            priors: true,
            reduced: Reduced::new(0, []),
        };
        st.rebuild_pattern();
        Ok(st)
    }

    /// Photo `i`'s interior with the cameras' interiors `ints`.
    fn interior(&self, ints: &[Interior], i: usize) -> Interior {
        self.group[i].map_or(self.block.photos[i].interior, |g| ints[g])
    }

    /// Each photo's interior at the current state.
    fn interiors(&self) -> Vec<Interior> {
        (0..self.block.photos.len())
            .map(|i| self.interior(&self.x.ints, i))
            .collect()
    }

    fn adjusted(&self, j: usize) -> bool {
        let n = self.by_point[j].len();
        match self.block.points[j].role {
            Role::Control { .. } => n >= 1,
            Role::Tie => n >= 2,
            Role::Check { .. } => false,
        }
    }

    /// The parameter blocks of the normal equations: photos, then self-calibrated cameras.
    fn blocks(&self) -> usize {
        self.block.photos.len() + self.block.calibrate.len()
    }

    fn rebuild_pattern(&mut self) {
        let n = self.block.photos.len();
        let mut pairs = Vec::new();
        for j in 0..self.by_point.len() {
            if !self.adjusted(j) {
                continue;
            }
            let parts: Vec<usize> = self.by_point[j]
                .iter()
                .flat_map(|&k| {
                    let i = self.block.rays[k].photo;
                    std::iter::once(i).chain(self.group[i].map(|g| n + g))
                })
                .collect();
            for a in 0..parts.len() {
                for b in 0..a {
                    pairs.push((parts[a], parts[b]));
                }
            }
        }
        for (i, g) in self.group.iter().enumerate() {
            if let Some(g) = g {
                pairs.push((n + g, i));
            }
        }
        self.reduced = Reduced::new(self.blocks(), pairs);
    }

    fn linearise(&self, x: &Params) -> Lin {
        let rots: Vec<Rotation> = x.cams.iter().map(Rotation::of).collect();
        let ints: Vec<Interior> = (0..self.block.photos.len())
            .map(|i| self.interior(&x.ints, i))
            .collect();
        let k = self.settings.huber_k;
        let robust = self.robust;
        let block = self.block;
        let n = block.photos.len();
        let points: Vec<Option<PointLin>> = (0..x.pts.len())
            .into_par_iter()
            .map(|j| {
                if !self.adjusted(j) {
                    return None;
                }
                let mut v = Matrix3::zeros();
                let mut g = Vector3::zeros();
                let mut cost = 0.0;
                let mut rays = Vec::with_capacity(self.by_point[j].len());
                for &ri in &self.by_point[j] {
                    let ray = &block.rays[ri];
                    let Some(l) = linearise(
                        &ints[ray.photo],
                        &x.cams[ray.photo],
                        &rots[ray.photo],
                        x.pts[j],
                    ) else {
                        // Behind the camera: a large, constant penalty (the step is refused).
                        cost += 1e12;
                        continue;
                    };
                    let r = Vector2::new(ray.xy.x, ray.xy.y) - l.xy;
                    let s = r.norm() / ray.sigma_mm;
                    let (rho, wr) = if robust && s > k {
                        (2.0 * k * s - k * k, k / s)
                    } else {
                        (s * s, 1.0)
                    };
                    cost += rho;
                    let w = wr / (ray.sigma_mm * ray.sigma_mm);
                    v += l.d_ground.transpose() * w * l.d_ground;
                    g += l.d_ground.transpose() * (w * r);
                    let cal = self.group[ray.photo].map(|gi| {
                        let mut m = l.d_interior;
                        for (c, free) in block.calibrate[gi].free.iter().enumerate() {
                            if !free {
                                m.column_mut(c).fill(0.0);
                            }
                        }
                        m.column_mut(5).fill(0.0);
                        (n + gi, m)
                    });
                    rays.push(RayLin {
                        ray: ri,
                        photo: ray.photo,
                        a: l.d_exterior,
                        cal,
                        b: l.d_ground,
                        r,
                        w,
                    });
                }
                if let Role::Control { ground, sigma_m } = block.points[j].role {
                    let d = Vector3::new(ground.x, ground.y, ground.z) - x.pts[j];
                    for c in 0..3 {
                        let wc = 1.0 / (sigma_m[c] * sigma_m[c]);
                        v[(c, c)] += wc;
                        g[c] += wc * d[c];
                        cost += wc * d[c] * d[c];
                    }
                }
                Some(PointLin { v, g, rays, cost })
            })
            .collect();
        let mut u = vec![Matrix6::zeros(); self.blocks()];
        let mut gc = vec![Vector6::zeros(); self.blocks()];
        let mut cross = vec![Matrix6::zeros(); n];
        let mut cost = 0.0;
        for p in points.iter().flatten() {
            cost += p.cost;
            for r in &p.rays {
                for (b, m) in r.parts() {
                    u[b] += m.transpose() * r.w * m;
                    gc[b] += m.transpose() * (r.w * r.r);
                }
                if let Some((_, m)) = &r.cal {
                    cross[r.photo] += m.transpose() * r.w * r.a;
                }
            }
        }
        for (i, ph) in block.photos.iter().enumerate() {
            let (Some(pr), Some(ap), true) = (ph.prior, ph.approx, self.priors) else {
                continue;
            };
            let d = vec_of(&ap) - vec_of(&x.cams[i]);
            for c in 0..6 {
                let (s, dc) = if c < 3 {
                    (pr.angles_sigma_rad, wrap(d[c]))
                } else {
                    (pr.position_sigma_m, d[c])
                };
                let wc = 1.0 / (s * s);
                u[i][(c, c)] += wc;
                gc[i][c] += wc * dc;
                cost += wc * dc * dc;
            }
        }
        Lin {
            points,
            u,
            cross,
            g: gc,
            cost,
        }
    }

    /// Builds S (damped by λ) into `self.reduced` and its right side.
    fn schur(&mut self, lin: &Lin, lambda: f64) -> (DVector<f64>, Vec<Option<Matrix3<f64>>>) {
        let n = self.block.photos.len();
        let nb = self.blocks();
        let damp6 = |m: &Matrix6<f64>| {
            let mut m = *m;
            for c in 0..6 {
                m[(c, c)] *= 1.0 + lambda;
            }
            m
        };
        let vinv: Vec<Option<Matrix3<f64>>> = lin
            .points
            .par_iter()
            .map(|p| {
                let p = p.as_ref()?;
                let mut v = p.v;
                for c in 0..3 {
                    v[(c, c)] *= 1.0 + lambda;
                }
                v.try_inverse()
            })
            .collect();
        let reduced = &self.reduced;
        let slots = reduced.len();
        let chunk = (lin.points.len() / (4 * rayon::current_num_threads())).max(256);
        let idx: Vec<usize> = (0..lin.points.len()).collect();
        let (blocks, rhs) = idx
            .par_chunks(chunk)
            .map(|js| {
                let mut blocks = vec![Matrix6::<f64>::zeros(); slots];
                let mut rhs = vec![Vector6::<f64>::zeros(); nb];
                for &j in js {
                    let (Some(p), Some(vi)) = (&lin.points[j], &vinv[j]) else {
                        continue;
                    };
                    // W = Jᵀ·w·B of each part of each ray, and W·V⁻¹.
                    let ws: Vec<(usize, SMatrix<f64, 6, 3>)> = p
                        .rays
                        .iter()
                        .flat_map(|r| r.parts().map(move |(k, m)| (k, m.transpose() * r.w * r.b)))
                        .collect();
                    let wv: Vec<SMatrix<f64, 6, 3>> = ws.iter().map(|w| w.1 * vi).collect();
                    for (a, (ka, _)) in ws.iter().enumerate() {
                        rhs[*ka] -= wv[a] * p.g;
                        for (b, (kb, wb)) in ws.iter().enumerate().take(a + 1) {
                            let (hi, lo, m) = if ka >= kb {
                                (*ka, *kb, wv[a] * wb.transpose())
                            } else {
                                (*kb, *ka, wv[b] * ws[a].1.transpose())
                            };
                            let s = reduced.slot(hi, lo).expect("the pattern has every pair");
                            if a == b || hi != lo {
                                blocks[s] -= m;
                            } else {
                                // Two parts of one point in the same block: both orders.
                                blocks[s] -= m + m.transpose();
                            }
                        }
                    }
                }
                (blocks, rhs)
            })
            .reduce(
                || (vec![Matrix6::zeros(); slots], vec![Vector6::zeros(); nb]),
                |(mut a, mut ra), (b, rb)| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    ra.iter_mut().zip(&rb).for_each(|(x, y)| *x += y);
                    (a, ra)
                },
            );
        self.reduced.blocks = blocks;
        let mut r = DVector::zeros(6 * nb);
        for i in 0..nb {
            let s = self.reduced.slot(i, i).unwrap();
            self.reduced.blocks[s] += damp6(&lin.u[i]);
            if i >= n {
                // A held parameter: its row and column are zero; a one keeps S definite.
                let free = self.block.calibrate[i - n].free;
                for c in 0..6 {
                    if c == 5 || !free[c] {
                        self.reduced.blocks[s][(c, c)] = 1.0;
                    }
                }
            }
            let v = lin.g[i] + rhs[i];
            r.fixed_rows_mut::<6>(6 * i).copy_from(&v);
        }
        for (i, g) in self.group.iter().enumerate() {
            if let Some(g) = g {
                let s = self.reduced.slot(n + g, i).unwrap();
                self.reduced.blocks[s] += lin.cross[i];
            }
        }
        (r, vinv)
    }

    /// One Gauss–Newton step at damping λ: the new unknowns.
    fn step(&mut self, lin: &Lin, lambda: f64) -> Result<Params, ReducedError> {
        let n = self.block.photos.len();
        let (rhs, vinv) = self.schur(lin, lambda);
        let dc = self.reduced.solve(&rhs)?;
        let cams: Vec<Exterior> = self
            .x
            .cams
            .iter()
            .enumerate()
            .map(|(i, e)| exterior_from(&(vec_of(e) + dc.fixed_rows::<6>(6 * i))))
            .collect();
        let ints: Vec<Interior> = self
            .x
            .ints
            .iter()
            .enumerate()
            .map(|(g, int)| {
                let d = dc.fixed_rows::<6>(6 * (n + g));
                let mut int = *int;
                int.focal_mm += d[0];
                int.principal_point.x += d[1];
                int.principal_point.y += d[2];
                int.lens.k1 += d[3];
                int.lens.k2 += d[4];
                int
            })
            .collect();
        let pts: Vec<Vector3<f64>> = lin
            .points
            .par_iter()
            .zip(&vinv)
            .zip(&self.x.pts)
            .map(|((p, vi), x)| match (p, vi) {
                (Some(p), Some(vi)) => {
                    let mut g = p.g;
                    for r in &p.rays {
                        for (k, m) in r.parts() {
                            let w = m.transpose() * r.w * r.b;
                            g -= w.transpose() * dc.fixed_rows::<6>(6 * k);
                        }
                    }
                    x + vi * g
                }
                _ => *x,
            })
            .collect();
        Ok(Params { cams, ints, pts })
    }

    /// Levenberg–Marquardt to convergence from the current state; the iterations taken.
    fn converge(&mut self) -> Result<usize, BundleError> {
        let mut lambda = 1e-3;
        let mut lin = self.linearise(&self.x);
        for it in 1..=self.settings.max_iterations {
            let mut accepted = false;
            for _ in 0..12 {
                let x = match self.step(&lin, lambda) {
                    Ok(s) => s,
                    Err(ReducedError::NotPositive) if lambda < 1e8 => {
                        lambda *= 10.0;
                        continue;
                    }
                    Err(e) => return Err(e.into()),
                };
                let next = self.linearise(&x);
                if next.cost <= lin.cost {
                    let gain = lin.cost - next.cost;
                    let change = gain / lin.cost.max(1e-300);
                    let noise = 1e-3 * lin.cost.sqrt().max(1.0);
                    tracing::debug!(it, cost = next.cost, change, lambda, "bundle step");
                    self.x = x;
                    lin = next;
                    lambda = (lambda / 4.0).max(1e-12);
                    accepted = true;
                    // Converged when the cost no longer moves: relatively (Ceres's function
                    // tolerance ÷ 10), or by less than 10⁻³ of √cost, a thousandth of the spread
                    // of a χ² of that size (√(2·redundancy)). Huber's linear arm can creep on
                    // for hundreds of steps, a blunder's point drifting 10⁻⁵ of the cost a step;
                    // snooping then removes the blunder.
                    if change < 1e-7 || gain < noise {
                        return Ok(it);
                    }
                    break;
                }
                lambda *= 6.0;
            }
            // No step lowers the cost even as short as a step down the gradient at λ > 10⁶:
            // a minimum, to rounding. (Below that, the next iteration damps further.)
            if !accepted && lambda > 1e6 {
                return Ok(it);
            }
        }
        Err(self.not_converged(self.settings.max_iterations, &lin))
    }

    fn not_converged(&self, iterations: usize, lin: &Lin) -> BundleError {
        let n = self.block.photos.len();
        let mut photo_sum = vec![(0.0, 0usize); n];
        let mut point_rms: Vec<(f64, usize)> = Vec::new();
        for (j, p) in lin.points.iter().enumerate() {
            let Some(p) = p else { continue };
            let mut s = 0.0;
            for r in &p.rays {
                let px = r.r.norm() / self.block.photos[r.photo].pixel_mm;
                photo_sum[r.photo].0 += px * px;
                photo_sum[r.photo].1 += 1;
                s += px * px;
            }
            point_rms.push(((s / p.rays.len().max(1) as f64).sqrt(), j));
        }
        let mut photos: Vec<(f64, usize)> = photo_sum
            .iter()
            .enumerate()
            .map(|(i, (s, c))| ((s / (*c).max(1) as f64).sqrt(), i))
            .collect();
        photos.sort_by(|a, b| b.0.total_cmp(&a.0));
        point_rms.sort_by(|a, b| b.0.total_cmp(&a.0));
        let name = |v: &[(f64, usize)], f: &dyn Fn(usize) -> String| {
            v.iter()
                .take(3)
                .map(|(r, i)| format!("{} ({r:.1} px)", f(*i)))
                .collect::<Vec<_>>()
                .join(", ")
        };
        BundleError::NotConverged {
            iterations,
            photos: name(&photos, &|i| format!("`{}`", self.block.photos[i].id)),
            points: name(&point_rms, &|j| format!("`{}`", self.block.points[j].id)),
        }
    }
}

/// Checks the block and finds start values: the approximate orientations, photos without one
/// resected from control and already intersected points, tie points intersected.
fn start(block: &Block) -> Result<Start, BundleError> {
    let np = block.photos.len();
    for (k, r) in block.rays.iter().enumerate() {
        if r.photo >= np || r.point >= block.points.len() {
            return Err(BundleError::BadRay {
                ray: k,
                what: "names a photo or point not in the block".into(),
            });
        }
        if !(r.sigma_mm.is_finite() && r.sigma_mm > 0.0 && r.xy.x.is_finite() && r.xy.y.is_finite())
        {
            return Err(BundleError::BadRay {
                ray: k,
                what: format!(
                    "σ {} mm or its coordinates not a positive finite number",
                    r.sigma_mm
                ),
            });
        }
    }
    let status: Vec<RayStatus> = block
        .rays
        .iter()
        .map(|r| match block.points[r.point].role {
            Role::Check { .. } => RayStatus::Check,
            _ => RayStatus::Used,
        })
        .collect();
    // The datum: three control points or more, seen, not in a line.
    let mut seen = vec![0usize; block.points.len()];
    for (r, s) in block.rays.iter().zip(&status) {
        if *s == RayStatus::Used {
            seen[r.point] += 1;
        }
    }
    let control: Vec<(String, GroundM)> = block
        .points
        .iter()
        .enumerate()
        .filter_map(|(j, p)| match p.role {
            Role::Control { ground, .. } if seen[j] > 0 => Some((p.id.clone(), ground)),
            _ => None,
        })
        .collect();
    if control.len() < 3 {
        return Err(BundleError::TooFewControl {
            found: control.len(),
        });
    }
    let n = control.len() as f64;
    let (mx, my) = control
        .iter()
        .fold((0.0, 0.0), |a, (_, g)| (a.0 + g.x / n, a.1 + g.y / n));
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for (_, g) in &control {
        sxx += (g.x - mx).powi(2);
        sxy += (g.x - mx) * (g.y - my);
        syy += (g.y - my).powi(2);
    }
    let tr = sxx + syy;
    let det = sxx * syy - sxy * sxy;
    let small = 0.5 * tr - (0.25 * tr * tr - det).max(0.0).sqrt();
    if small < 1e-4 * tr {
        return Err(BundleError::ControlInLine {
            ids: control
                .iter()
                .map(|c| c.0.as_str())
                .collect::<Vec<_>>()
                .join(", "),
        });
    }
    // Connectivity: every photo reached from the first through shared points.
    let mut parent: Vec<usize> = (0..np).collect();
    fn root(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    let mut first_photo = vec![usize::MAX; block.points.len()];
    for (r, s) in block.rays.iter().zip(&status) {
        if *s != RayStatus::Used {
            continue;
        }
        let f = first_photo[r.point];
        if f == usize::MAX {
            first_photo[r.point] = r.photo;
        } else {
            let (a, b) = (root(&mut parent, f), root(&mut parent, r.photo));
            parent[a] = b;
        }
    }
    let mut size = vec![0usize; np];
    for i in 0..np {
        let r = root(&mut parent, i);
        size[r] += 1;
    }
    let main = (0..np).max_by_key(|&i| size[i]).unwrap_or(0);
    for i in 0..np {
        if root(&mut parent, i) != main && np > 1 {
            let with = (0..np)
                .filter(|&k| root(&mut parent, k) == root(&mut parent, i) && k != i)
                .map(|k| format!("`{}`", block.photos[k].id))
                .collect::<Vec<_>>();
            return Err(BundleError::Unconnected {
                id: block.photos[i].id.clone(),
                with: if with.is_empty() {
                    "it stands alone".into()
                } else {
                    format!("it is tied only to {}", with.join(", "))
                },
            });
        }
    }
    // Start values.
    let mut cams: Vec<Option<Exterior>> = block.photos.iter().map(|p| p.approx).collect();
    let mut pts: Vec<Option<Vector3<f64>>> = block
        .points
        .iter()
        .map(|p| match p.role {
            Role::Control { ground, .. } => Some(Vector3::new(ground.x, ground.y, ground.z)),
            _ => None,
        })
        .collect();
    let mut by_point: Vec<Vec<usize>> = vec![Vec::new(); block.points.len()];
    for (k, (r, s)) in block.rays.iter().zip(&status).enumerate() {
        if *s == RayStatus::Used {
            by_point[r.point].push(k);
        }
    }
    loop {
        // Tie points from the photos with a start.
        for j in 0..block.points.len() {
            if pts[j].is_some() || block.points[j].role != Role::Tie {
                continue;
            }
            let rays: Vec<_> = by_point[j]
                .iter()
                .filter_map(|&k| {
                    let r = &block.rays[k];
                    Some((camera(&block.photos[r.photo], cams[r.photo]?), r.xy))
                })
                .collect();
            if rays.len() >= 2 {
                pts[j] = intersect_of(&rays);
            }
        }
        let missing: Vec<usize> = (0..np).filter(|&i| cams[i].is_none()).collect();
        if missing.is_empty() {
            break;
        }
        let mut progress = false;
        let mut worst = (String::new(), 0usize);
        for &i in &missing {
            let obs: Vec<(PhotoMm, GroundM)> = block
                .rays
                .iter()
                .zip(&status)
                .filter(|(r, s)| r.photo == i && **s == RayStatus::Used)
                .filter_map(|(r, _)| {
                    let p = pts[r.point]?;
                    Some((r.xy, GroundM::new(p.x, p.y, p.z)))
                })
                .collect();
            if obs.len() >= 4 {
                if let Ok(r) = resect(&block.photos[i].interior, &obs) {
                    cams[i] = Some(r.exterior);
                    progress = true;
                    continue;
                }
            }
            worst = (block.photos[i].id.clone(), obs.len());
        }
        if !progress {
            return Err(BundleError::NoStart {
                id: worst.0,
                points: worst.1,
            });
        }
    }
    let cams: Vec<Exterior> = cams
        .into_iter()
        .map(|c| c.expect("every photo has a start"))
        .collect();
    // Tie points still without a start (rays from photos found late) and check points: at
    // the block's mean height under the first photo; the adjustment moves them.
    let pts = pts
        .into_iter()
        .enumerate()
        .map(|(j, p)| {
            p.unwrap_or_else(|| {
                let rays: Vec<_> = by_point[j]
                    .iter()
                    .map(|&k| {
                        let r = &block.rays[k];
                        (camera(&block.photos[r.photo], cams[r.photo]), r.xy)
                    })
                    .collect();
                intersect_of(&rays)
                    .unwrap_or_else(|| Vector3::new(cams[0].centre.x, cams[0].centre.y, 0.0))
            })
        })
        .collect();
    Ok((cams, pts, status, by_point))
}

/// The point's cofactor Q_pp (3 × 3) and its cross cofactors Q_pc with each parameter block
/// it observes (photos, self-calibrated cameras), given the blocks' Q_cc (Triggs et al. 2000,
/// §6.1: the eliminated points' covariance).
fn point_cofactor(
    p: &PointLin,
    vi: &Matrix3<f64>,
    qcc: &DMatrix<f64>,
) -> (Matrix3<f64>, Vec<(usize, SMatrix<f64, 3, 6>)>) {
    let ys: Vec<(usize, SMatrix<f64, 3, 6>)> = p
        .rays
        .iter()
        .flat_map(|r| {
            r.parts()
                .map(move |(k, m)| (k, vi * (m.transpose() * r.w * r.b).transpose()))
        })
        .collect();
    let q =
        |i: usize, k: usize| -> Matrix6<f64> { qcc.fixed_view::<6, 6>(6 * i, 6 * k).into_owned() };
    let mut blocks: Vec<usize> = ys.iter().map(|y| y.0).collect();
    blocks.sort_unstable();
    blocks.dedup();
    // Q_pc(j, i) = −Σ_a Y_a·Q_cc(i_a, i) for each block i of the point.
    let pc: Vec<(usize, SMatrix<f64, 3, 6>)> = blocks
        .iter()
        .map(|&i| {
            let mut m = SMatrix::<f64, 3, 6>::zeros();
            for (ia, y) in &ys {
                m -= y * q(*ia, i);
            }
            (i, m)
        })
        .collect();
    // Q_pp = V⁻¹ − Σ_a Y_a·Q_cp(i_a, j) = V⁻¹ + Σ_a Σ_b Y_a Q_cc(i_a, i_b) Y_bᵀ.
    let mut qpp = *vi;
    for (ia, y) in &ys {
        let pci = pc.iter().find(|(i, _)| i == ia).unwrap().1;
        qpp -= y * pci.transpose();
    }
    (qpp, pc)
}

/// J·Q·Jᵀ of one ray (2 × 2): its parts' and its point's cofactors, with their correlations.
fn ray_cofactor(
    r: &RayLin,
    qpp: &Matrix3<f64>,
    pc: &[(usize, SMatrix<f64, 3, 6>)],
    qcc: &DMatrix<f64>,
) -> SMatrix<f64, 2, 2> {
    let mut jqj = r.b * qpp * r.b.transpose();
    for (ka, ma) in r.parts() {
        let qcp = pc.iter().find(|(i, _)| *i == ka).unwrap().1.transpose();
        let t = ma * qcp * r.b.transpose();
        jqj += t + t.transpose();
        for (kb, mb) in r.parts() {
            jqj += ma * qcc.fixed_view::<6, 6>(6 * ka, 6 * kb) * mb.transpose();
        }
    }
    jqj
}

/// Adjusts the block: see the module's documentation.
pub fn adjust(block: &Block, settings: Settings) -> Result<Adjusted, BundleError> {
    if !block.radial.any() {
        return adjust_collinear(block, settings);
    }
    // The displacements change by some 10⁻⁴ of themselves per metre of height: the first
    // adjustment's camera and point heights are good to far below that.
    let first = adjust_collinear(block, settings)?;
    adjust_collinear(&corrected(block, &first), settings)
}

/// `block` with each ray moved to where collinearity puts it: its refraction and curvature
/// ([`crate::geometry::Radial::undistort`]) taken out with the heights of `at` (the point's,
/// or the mean of the adjusted points' for a point without one).
pub fn corrected(block: &Block, at: &Adjusted) -> Block {
    let zs: Vec<f64> = at.points.iter().flatten().map(|p| p.ground.z).collect();
    let mean = zs.iter().sum::<f64>() / zs.len().max(1) as f64;
    let mut b = block.clone();
    for r in &mut b.rays {
        let ph = &block.photos[r.photo];
        let z = at.points[r.point].as_ref().map_or(mean, |p| p.ground.z);
        let seen =
            crate::geometry::radial::Seen::of(&ph.interior, at.exteriors[r.photo].centre.z, z);
        r.xy = block.radial.undistort(r.xy, &seen);
    }
    b.radial = crate::geometry::Radial::default();
    b
}

/// The adjustment of rays that follow collinearity.
fn adjust_collinear(block: &Block, settings: Settings) -> Result<Adjusted, BundleError> {
    let mut st = State::begin(block, settings, true)?;
    let mut iterations = st.converge()?;
    let mut rejected = 0;
    let mut round = 0;
    loop {
        // The final solution's cofactors, undamped, with the robust weights of the last
        // iteration.
        let lin = st.linearise(&st.x);
        let (_, vinv) = st.schur(&lin, 0.0);
        let qcc = st.reduced.inverse().map_err(|e| undetermined(block, e))?;
        let free: usize = block
            .calibrate
            .iter()
            .map(|c| c.free.iter().filter(|f| **f).count())
            .sum();
        let unknowns = 6 * block.photos.len()
            + free
            + 3 * (0..block.points.len()).filter(|&j| st.adjusted(j)).count();
        let mut observations = 0usize;
        for (j, p) in lin.points.iter().enumerate() {
            let Some(p) = p else { continue };
            observations += 2 * p.rays.len();
            if let Role::Control { .. } = block.points[j].role {
                observations += 3;
            }
        }
        observations += 6 * block
            .photos
            .iter()
            .filter(|p| p.prior.is_some() && p.approx.is_some())
            .count();
        let redundancy = observations as f64 - unknowns as f64;
        let sigma0 = if redundancy > 0.0 {
            (lin.cost / redundancy).sqrt()
        } else {
            1.0
        };
        // Each ray's normalised residual.
        let mut results: Vec<RayResult> = block
            .rays
            .iter()
            .zip(&st.status)
            .map(|(_, s)| RayResult {
                residual_mm: [0.0; 2],
                w: None,
                redundancy: 0.0,
                status: *s,
            })
            .collect();
        let mut points: Vec<Option<AdjustedPoint>> = vec![None; block.points.len()];
        let tested: Vec<(usize, Vec<TestedRay>, Matrix3<f64>)> = lin
            .points
            .par_iter()
            .enumerate()
            .filter_map(|(j, p)| {
                let (p, vi) = (p.as_ref()?, vinv[j].as_ref()?);
                let (qpp, pc) = point_cofactor(p, vi, &qcc);
                let rays = p
                    .rays
                    .iter()
                    .map(|r| {
                        let jqj = ray_cofactor(r, &qpp, &pc, &qcc);
                        let qvv = [1.0 / r.w - jqj[(0, 0)], 1.0 / r.w - jqj[(1, 1)]];
                        let red = 0.5 * (qvv[0] + qvv[1]) * r.w;
                        let w = (qvv[0] > 1e-6 / r.w && qvv[1] > 1e-6 / r.w).then(|| {
                            [
                                r.r.x / (sigma0 * qvv[0].sqrt()),
                                r.r.y / (sigma0 * qvv[1].sqrt()),
                            ]
                        });
                        (r.ray, [r.r.x, r.r.y], w, red)
                    })
                    .collect();
                Some((j, rays, qpp))
            })
            .collect();
        let mut worst_per_point: Vec<(usize, f64)> = Vec::new();
        for (j, rays, qpp) in &tested {
            points[*j] = Some(AdjustedPoint {
                ground: GroundM::new(st.x.pts[*j].x, st.x.pts[*j].y, st.x.pts[*j].z),
                cov: qpp * sigma0 * sigma0,
                rays: rays.len(),
            });
            let mut worst: Option<(usize, f64)> = None;
            for (k, res, w, red) in rays {
                results[*k].residual_mm = *res;
                results[*k].w = *w;
                results[*k].redundancy = *red;
                if let Some(w) = w {
                    let m = w[0].abs().max(w[1].abs());
                    if m > settings.critical && worst.is_none_or(|(_, b)| m > b) {
                        worst = Some((*k, m));
                    }
                }
            }
            worst_per_point.extend(worst);
        }
        if !worst_per_point.is_empty() && round < settings.snooping_rounds {
            round += 1;
            for (k, _) in &worst_per_point {
                st.status[*k] = RayStatus::Rejected;
                let j = block.rays[*k].point;
                st.by_point[j].retain(|r| r != k);
                rejected += 1;
            }
            st.rebuild_pattern();
            iterations += st.converge()?;
            continue;
        }
        // The rejected and check rays' residuals against the adjusted block; check points
        // intersected from their rays.
        let interiors = st.interiors();
        let cameras: Vec<FrameCamera> = interiors
            .iter()
            .zip(&st.x.cams)
            .map(|(i, e)| FrameCamera {
                interior: *i,
                exterior: *e,
            })
            .collect();
        // Each check point's rays, gathered in one pass.
        let mut check_rays: Vec<Vec<usize>> = vec![Vec::new(); block.points.len()];
        for (k, r) in block.rays.iter().enumerate() {
            if results[k].status == RayStatus::Used && !st.adjusted(r.point) {
                results[k].status = RayStatus::Unused;
            }
            if results[k].status == RayStatus::Check {
                check_rays[r.point].push(k);
            }
        }
        for (j, ks) in check_rays.iter().enumerate() {
            if let Some((g, cov)) = intersect_fixed(block, &cameras, ks) {
                points[j] = Some(AdjustedPoint {
                    ground: g,
                    cov,
                    rays: ks.len(),
                });
                st.x.pts[j] = Vector3::new(g.x, g.y, g.z);
            }
        }
        for (k, r) in block.rays.iter().enumerate() {
            if matches!(results[k].status, RayStatus::Used) {
                continue;
            }
            let p = st.x.pts[r.point];
            if let Some(q) = cameras[r.photo].project(GroundM::new(p.x, p.y, p.z)) {
                results[k].residual_mm = [r.xy.x - q.x, r.xy.y - q.y];
            }
        }
        let calibrated = if block.calibrate.is_empty() {
            Vec::new()
        } else {
            // What the rays determine without the approximations' priors.
            st.priors = false;
            let lin = st.linearise(&st.x);
            st.schur(&lin, 0.0);
            let rays_only = st.reduced.inverse();
            st.priors = true;
            calibrated(block, &st.x.ints, &qcc, rays_only.ok().as_ref(), sigma0, &lin)?
        };
        return Ok(Adjusted {
            exteriors: st.x.cams.clone(),
            interiors,
            calibrated,
            covariance: qcc * (sigma0 * sigma0),
            points,
            rays: results,
            sigma0,
            redundancy,
            iterations,
            rejected,
        });
    }
}

/// Where an adjustment's normal equations are singular with cameras to calibrate: the block
/// cannot tell their parameters from the exteriors (said for the first camera's first free
/// parameter; [`calibrated`] names the weakest where the solve goes through).
fn undetermined(block: &Block, e: ReducedError) -> BundleError {
    match block.calibrate.first() {
        Some(c) => {
            let k = c.free.iter().position(|f| *f).unwrap_or(0);
            let (parameter, key, advice) = PARAMETERS[k];
            BundleError::NotDeterminable {
                camera: c.camera.clone(),
                parameter,
                key,
                radius_mm: 0.0,
                effect_um: f64::INFINITY,
                ray_um: 0.0,
                advice,
            }
        }
        None => e.into(),
    }
}

/// Each interior parameter's name, its `self_calibration` key and what a block needs to
/// determine it.
const PARAMETERS: [(&str, &str, &str); 5] = [
    ("focal length", "focal", "it needs relief over a good share of the flying height, or convergent photos, with control in height spread over the block"),
    ("principal point x", "principal_point", "it needs photos turned against each other (cross strips, κ differing by 90° or more) or convergent photos"),
    ("principal point y", "principal_point", "it needs photos turned against each other (cross strips, κ differing by 90° or more) or convergent photos"),
    ("radial distortion k1", "k1", "it needs tie points out to the photos' edges and corners in many photos (60 % overlap, cross strips)"),
    ("radial distortion k2", "k2", "it needs tie points out to the photos' edges and corners in many photos (60 % overlap, cross strips)"),
];

/// The self-calibrated cameras with their σ, each parameter tested. A parameter is determined
/// by the block when the rays fix it: its σ without the approximations' priors
/// (`rays_only`, `None` where those normal equations are singular) is at most twice its σ
/// with them (else the flight index map's σ of the flying height, say, is what holds the focal
/// length), and one σ of it moves a point at the rays' outermost radius by at most 100 rays'
/// σ. Otherwise the adjustment is refused, naming the parameter. Effects at radius r
/// (ρ = r/c): c: r·σ/c; x₀, y₀: σ; k₁: r·ρ²·σ; k₂: r·ρ⁴·σ ([`crate::geometry::lens`]).
fn calibrated(
    block: &Block,
    ints: &[Interior],
    qcc: &DMatrix<f64>,
    rays_only: Option<&DMatrix<f64>>,
    sigma0: f64,
    lin: &Lin,
) -> Result<Vec<Calibrated>, BundleError> {
    let n = block.photos.len();
    let mut out = Vec::new();
    for (g, c) in block.calibrate.iter().enumerate() {
        let int = ints[g];
        let pp = int.principal_point;
        let mut radius: f64 = 0.0;
        let mut sigmas = Vec::new();
        for p in lin.points.iter().flatten() {
            for r in &p.rays {
                if c.photos.contains(&r.photo) {
                    let ray = &block.rays[r.ray];
                    radius = radius.max((ray.xy.x - pp.x).hypot(ray.xy.y - pp.y));
                    sigmas.push(ray.sigma_mm);
                }
            }
        }
        sigmas.sort_by(f64::total_cmp);
        let ray_sigma = sigmas.get(sigmas.len() / 2).copied().unwrap_or(0.0) * sigma0;
        let rho2 = (radius / int.focal_mm).powi(2);
        let sigma: [f64; 5] = std::array::from_fn(|k| {
            let v = qcc[(6 * (n + g) + k, 6 * (n + g) + k)];
            if c.free[k] {
                v.max(0.0).sqrt() * sigma0
            } else {
                0.0
            }
        });
        for k in 0..5 {
            if !c.free[k] {
                continue;
            }
            let at_edge = match k {
                0 => radius / int.focal_mm,
                1 | 2 => 1.0,
                3 => radius * rho2,
                _ => radius * rho2 * rho2,
            };
            let effect = sigma[k] * at_edge;
            let i = 6 * (n + g) + k;
            let alone = rays_only.map_or(f64::INFINITY, |q| q[(i, i)].max(0.0).sqrt() * sigma0);
            if !(alone <= 2.0 * sigma[k] && effect <= 100.0 * ray_sigma) {
                let effect = alone.max(sigma[k]) * at_edge;
                let (parameter, key, advice) = PARAMETERS[k];
                return Err(BundleError::NotDeterminable {
                    camera: c.camera.clone(),
                    parameter,
                    key,
                    radius_mm: radius,
                    effect_um: 1e3 * effect,
                    ray_um: 1e3 * ray_sigma,
                    advice,
                });
            }
        }
        out.push(Calibrated {
            camera: c.camera.clone(),
            interior: int,
            sigma,
            free: c.free,
        });
    }
    Ok(out)
}

/// A point intersected from rays `ks` with the cameras held fixed (Gauss–Newton from the
/// rays' nearest point), with its covariance from the rays' σ alone.
pub fn intersect_fixed(
    block: &Block,
    cameras: &[FrameCamera],
    ks: &[usize],
) -> Option<(GroundM, Matrix3<f64>)> {
    if ks.len() < 2 {
        return None;
    }
    let rays: Vec<_> = ks
        .iter()
        .map(|&k| {
            let r = &block.rays[k];
            (cameras[r.photo], r.xy)
        })
        .collect();
    let mut x = intersect_of(&rays)?;
    let mut n = Matrix3::zeros();
    for _ in 0..10 {
        n = Matrix3::zeros();
        let mut g = Vector3::zeros();
        for &k in ks {
            let r = &block.rays[k];
            let c = &cameras[r.photo];
            let e = &c.exterior;
            let l = linearise(&c.interior, e, &Rotation::of(e), x)?;
            let res = Vector2::new(r.xy.x, r.xy.y) - l.xy;
            let w = 1.0 / (r.sigma_mm * r.sigma_mm);
            n += l.d_ground.transpose() * w * l.d_ground;
            g += l.d_ground.transpose() * (w * res);
        }
        let d = n.try_inverse()? * g;
        x += d;
        if d.norm() < 1e-6 {
            break;
        }
    }
    Some((GroundM::new(x.x, x.y, x.z), n.try_inverse()?))
}

/// The reduced camera system S of `block` at its start values (undamped): what each iteration
/// factors, for the benchmark's sparse and dense solves side by side.
pub fn reduced_at_start(block: &Block) -> Result<Reduced, BundleError> {
    let mut st = State::begin(block, Settings::default(), false)?;
    let lin = st.linearise(&st.x);
    st.schur(&lin, 0.0);
    Ok(st.reduced)
}
