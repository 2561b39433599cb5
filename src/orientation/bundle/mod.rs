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

mod cofactors;
mod normal;
mod self_calibration;
mod start;

use super::collinearity::{linearise, Rotation};
use super::reduced::{Reduced, ReducedError};
use crate::coords::{GroundM, PhotoMm};
use crate::geometry::{intersect, resect, Exterior, FrameCamera, Interior};
use cofactors::tested;
use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, SMatrix, Vector2, Vector3, Vector6};
use normal::State;
use rayon::prelude::*;
use self_calibration::{calibrated, undetermined};

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
    #[error("the block cannot determine camera `{camera}`'s interior: with its {parameters} free the adjustment's normal equations are singular (its rays cannot tell them from the photos' orientations); leave some out of [orientation] self_calibration and give the camera's certificate values, or give the photos approximate orientations with their σ")]
    Singular { camera: String, parameters: String },
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
        let tested = tested(&lin, &vinv, &qcc, sigma0);
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
            calibrated(
                block,
                &st.x.ints,
                &qcc,
                rays_only.ok().as_ref(),
                sigma0,
                &lin,
            )?
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
