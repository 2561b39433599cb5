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
    /// σ̂₀²·Q of every photo's ω, φ, κ, X₀, Y₀, Z₀ (rad, m), 6n × 6n.
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
    b: SMatrix<f64, 2, 3>,
    r: Vector2<f64>,
    /// 1/σ² times the robust weight.
    w: f64,
}

struct Lin {
    points: Vec<Option<PointLin>>,
    u: Vec<Matrix6<f64>>,
    g: Vec<Vector6<f64>>,
    cost: f64,
}

/// The adjustment's working state.
struct State<'a> {
    block: &'a Block,
    settings: Settings,
    cams: Vec<Exterior>,
    pts: Vec<Vector3<f64>>,
    /// Active rays of each adjusted point (empty: the point is not adjusted).
    by_point: Vec<Vec<usize>>,
    status: Vec<RayStatus>,
    robust: bool,
    reduced: Reduced,
}

impl<'a> State<'a> {
    /// The block checked, at its start values, with its pattern.
    fn begin(block: &'a Block, settings: Settings, robust: bool) -> Result<State<'a>, BundleError> {
        let (cams, pts, status, by_point) = start(block)?;
        let mut st = State {
            block,
            settings,
            cams,
            pts,
            by_point,
            status,
            robust,
            reduced: Reduced::new(0, []),
        };
        st.rebuild_pattern();
        Ok(st)
    }

    fn adjusted(&self, j: usize) -> bool {
        let n = self.by_point[j].len();
        match self.block.points[j].role {
            Role::Control { .. } => n >= 1,
            Role::Tie => n >= 2,
            Role::Check { .. } => false,
        }
    }

    fn rebuild_pattern(&mut self) {
        let n = self.block.photos.len();
        let mut pairs = Vec::new();
        for j in 0..self.by_point.len() {
            if !self.adjusted(j) {
                continue;
            }
            let rs = &self.by_point[j];
            for a in 0..rs.len() {
                for b in 0..a {
                    pairs.push((self.block.rays[rs[a]].photo, self.block.rays[rs[b]].photo));
                }
            }
        }
        self.reduced = Reduced::new(n, pairs);
    }

    fn linearise(&self, cams: &[Exterior], pts: &[Vector3<f64>]) -> Lin {
        let rots: Vec<Rotation> = cams.iter().map(Rotation::of).collect();
        let k = self.settings.huber_k;
        let robust = self.robust;
        let block = self.block;
        let points: Vec<Option<PointLin>> = (0..pts.len())
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
                    let ph = &block.photos[ray.photo];
                    let pp = ph.interior.principal_point;
                    let Some(l) = linearise(
                        ph.interior.focal_mm,
                        [pp.x, pp.y],
                        &cams[ray.photo],
                        &rots[ray.photo],
                        pts[j],
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
                    rays.push(RayLin {
                        ray: ri,
                        photo: ray.photo,
                        a: l.d_exterior,
                        b: l.d_ground,
                        r,
                        w,
                    });
                }
                if let Role::Control { ground, sigma_m } = block.points[j].role {
                    let d = Vector3::new(ground.x, ground.y, ground.z) - pts[j];
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
        let n = block.photos.len();
        let mut u = vec![Matrix6::zeros(); n];
        let mut gc = vec![Vector6::zeros(); n];
        let mut cost = 0.0;
        for p in points.iter().flatten() {
            cost += p.cost;
            for r in &p.rays {
                u[r.photo] += r.a.transpose() * r.w * r.a;
                gc[r.photo] += r.a.transpose() * (r.w * r.r);
            }
        }
        for (i, ph) in block.photos.iter().enumerate() {
            let (Some(pr), Some(ap)) = (ph.prior, ph.approx) else {
                continue;
            };
            let d = vec_of(&ap) - vec_of(&cams[i]);
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
            g: gc,
            cost,
        }
    }

    /// Builds S (damped by λ) into `self.reduced` and its right side.
    fn schur(&mut self, lin: &Lin, lambda: f64) -> (DVector<f64>, Vec<Option<Matrix3<f64>>>) {
        let n = self.block.photos.len();
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
                let mut rhs = vec![Vector6::<f64>::zeros(); n];
                for &j in js {
                    let (Some(p), Some(vi)) = (&lin.points[j], &vinv[j]) else {
                        continue;
                    };
                    let ws: Vec<SMatrix<f64, 6, 3>> =
                        p.rays.iter().map(|r| r.a.transpose() * r.w * r.b).collect();
                    let wv: Vec<SMatrix<f64, 6, 3>> = ws.iter().map(|w| w * vi).collect();
                    for (a, ra) in p.rays.iter().enumerate() {
                        rhs[ra.photo] -= wv[a] * p.g;
                        for (b, rb) in p.rays.iter().enumerate().take(a + 1) {
                            let (hi, lo, m) = if ra.photo >= rb.photo {
                                (ra.photo, rb.photo, wv[a] * ws[b].transpose())
                            } else {
                                (rb.photo, ra.photo, wv[b] * ws[a].transpose())
                            };
                            let s = reduced.slot(hi, lo).expect("the pattern has every pair");
                            if a == b || hi != lo {
                                blocks[s] -= m;
                            } else {
                                // Two rays of one point in the same photo: both orders.
                                blocks[s] -= m + m.transpose();
                            }
                        }
                    }
                }
                (blocks, rhs)
            })
            .reduce(
                || (vec![Matrix6::zeros(); slots], vec![Vector6::zeros(); n]),
                |(mut a, mut ra), (b, rb)| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    ra.iter_mut().zip(&rb).for_each(|(x, y)| *x += y);
                    (a, ra)
                },
            );
        self.reduced.blocks = blocks;
        let mut r = DVector::zeros(6 * n);
        for i in 0..n {
            let s = self.reduced.slot(i, i).unwrap();
            self.reduced.blocks[s] += damp6(&lin.u[i]);
            let v = lin.g[i] + rhs[i];
            r.fixed_rows_mut::<6>(6 * i).copy_from(&v);
        }
        (r, vinv)
    }

    /// One Gauss–Newton step at damping λ: the new cameras and points.
    fn step(
        &mut self,
        lin: &Lin,
        lambda: f64,
    ) -> Result<(Vec<Exterior>, Vec<Vector3<f64>>), ReducedError> {
        let (rhs, vinv) = self.schur(lin, lambda);
        let dc = self.reduced.solve(&rhs)?;
        let cams: Vec<Exterior> = self
            .cams
            .iter()
            .enumerate()
            .map(|(i, e)| exterior_from(&(vec_of(e) + dc.fixed_rows::<6>(6 * i))))
            .collect();
        let pts: Vec<Vector3<f64>> = lin
            .points
            .par_iter()
            .zip(&vinv)
            .zip(&self.pts)
            .map(|((p, vi), x)| match (p, vi) {
                (Some(p), Some(vi)) => {
                    let mut g = p.g;
                    for r in &p.rays {
                        let w = r.a.transpose() * r.w * r.b;
                        g -= w.transpose() * dc.fixed_rows::<6>(6 * r.photo);
                    }
                    x + vi * g
                }
                _ => *x,
            })
            .collect();
        Ok((cams, pts))
    }

    /// Levenberg–Marquardt to convergence from the current state; the iterations taken.
    fn converge(&mut self) -> Result<usize, BundleError> {
        let mut lambda = 1e-3;
        let mut lin = self.linearise(&self.cams, &self.pts);
        for it in 1..=self.settings.max_iterations {
            let mut accepted = false;
            for _ in 0..12 {
                let (cams, pts) = match self.step(&lin, lambda) {
                    Ok(s) => s,
                    Err(ReducedError::NotPositive) if lambda < 1e8 => {
                        lambda *= 10.0;
                        continue;
                    }
                    Err(e) => return Err(e.into()),
                };
                let next = self.linearise(&cams, &pts);
                if next.cost <= lin.cost {
                    let gain = lin.cost - next.cost;
                    let change = gain / lin.cost.max(1e-300);
                    let noise = 1e-3 * lin.cost.sqrt().max(1.0);
                    tracing::debug!(it, cost = next.cost, change, lambda, "bundle step");
                    self.cams = cams;
                    self.pts = pts;
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

/// The point's cofactor Q_pp (3 × 3) and its cross cofactors Q_pc with each of its photos,
/// given the cameras' Q_cc (Triggs et al. 2000, §6.1: the eliminated points' covariance).
fn point_cofactor(
    p: &PointLin,
    vi: &Matrix3<f64>,
    qcc: &DMatrix<f64>,
) -> (Matrix3<f64>, Vec<(usize, SMatrix<f64, 3, 6>)>) {
    let ys: Vec<(usize, SMatrix<f64, 3, 6>)> = p
        .rays
        .iter()
        .map(|r| (r.photo, vi * (r.a.transpose() * r.w * r.b).transpose()))
        .collect();
    let q =
        |i: usize, k: usize| -> Matrix6<f64> { qcc.fixed_view::<6, 6>(6 * i, 6 * k).into_owned() };
    let mut photos: Vec<usize> = ys.iter().map(|y| y.0).collect();
    photos.sort_unstable();
    photos.dedup();
    // Q_pc(j, i) = −Σ_a Y_a·Q_cc(i_a, i) for each photo i of the point.
    let pc: Vec<(usize, SMatrix<f64, 3, 6>)> = photos
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
        let lin = st.linearise(&st.cams, &st.pts);
        let (_, vinv) = st.schur(&lin, 0.0);
        let qcc = st.reduced.inverse()?;
        let unknowns = 6 * block.photos.len()
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
                        let qcp = pc
                            .iter()
                            .find(|(i, _)| *i == r.photo)
                            .unwrap()
                            .1
                            .transpose();
                        let qii = qcc
                            .fixed_view::<6, 6>(6 * r.photo, 6 * r.photo)
                            .into_owned();
                        let jqj = r.a * qii * r.a.transpose()
                            + r.a * qcp * r.b.transpose()
                            + r.b * qcp.transpose() * r.a.transpose()
                            + r.b * qpp * r.b.transpose();
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
                ground: GroundM::new(st.pts[*j].x, st.pts[*j].y, st.pts[*j].z),
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
            if let Some((g, cov)) = intersect_fixed(block, &st.cams, ks) {
                points[j] = Some(AdjustedPoint {
                    ground: g,
                    cov,
                    rays: ks.len(),
                });
                st.pts[j] = Vector3::new(g.x, g.y, g.z);
            }
        }
        for (k, r) in block.rays.iter().enumerate() {
            if matches!(results[k].status, RayStatus::Used) {
                continue;
            }
            let ph = &block.photos[r.photo];
            let p = st.pts[r.point];
            if let Some(q) = camera(ph, st.cams[r.photo]).project(GroundM::new(p.x, p.y, p.z)) {
                results[k].residual_mm = [r.xy.x - q.x, r.xy.y - q.y];
            }
        }
        return Ok(Adjusted {
            exteriors: st.cams.clone(),
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
    cams: &[Exterior],
    ks: &[usize],
) -> Option<(GroundM, Matrix3<f64>)> {
    if ks.len() < 2 {
        return None;
    }
    let rays: Vec<_> = ks
        .iter()
        .map(|&k| {
            let r = &block.rays[k];
            (camera(&block.photos[r.photo], cams[r.photo]), r.xy)
        })
        .collect();
    let mut x = intersect_of(&rays)?;
    let mut n = Matrix3::zeros();
    for _ in 0..10 {
        n = Matrix3::zeros();
        let mut g = Vector3::zeros();
        for &k in ks {
            let r = &block.rays[k];
            let ph = &block.photos[r.photo];
            let pp = ph.interior.principal_point;
            let e = &cams[r.photo];
            let l = linearise(ph.interior.focal_mm, [pp.x, pp.y], e, &Rotation::of(e), x)?;
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
    let lin = st.linearise(&st.cams, &st.pts);
    st.schur(&lin, 0.0);
    Ok(st.reduced)
}
