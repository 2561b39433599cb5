//! The covariance of several photos' resected orientations when their control points share
//! their ground error.
//!
//! Each photo's resection ([`super::resect`]) takes its control points' ground as exact, so its
//! σ0²·N⁻¹ treats every error as the photo's own. A control point's ground error is not: every
//! photo that sees the point fits the same wrong ground, and their orientations move together.
//! Two photos moved together intersect in a model that is shifted and tilted with the control,
//! not one whose heights scatter by the base-to-height ratio; taken as independent, the
//! orientations' share of a height's σ comes out several times too wide (`rig demo`: the true
//! errors were 0.4–0.6 × σ on most seeds).
//!
//! The least-squares resection's linearisation gives, for photo i with design A (2m × 6, mm
//! per parameter) and ground partials B (2m × 3m, mm per m, one 2 × 3 block per point):
//! δpᵢ = Kᵢ(eᵢ − Bᵢ·δG), Kᵢ = (AᵢᵀAᵢ)⁻¹Aᵢᵀ, with eᵢ the photo's measuring errors (σ_img each)
//! and δG the points' ground errors (Σ_G per point). So
//! Cov(δpᵢ, δpⱼ) = δᵢⱼ·σ²_img,ᵢ·(AᵢᵀAᵢ)⁻¹ + Σₖ (KᵢBᵢ)ₖ·Σ_G·(KⱼBⱼ)ₖᵀ over the points k both
//! photos see (the general law of error propagation; Mikhail, Bethel & McGlone 2001,
//! "Introduction to Modern Photogrammetry", §2.7 and App. B).
//! σ²_img comes from the residuals, less what the ground errors put in them:
//! E(vᵀv) = σ²_img·(2m − 6) + tr(R·B·Σ_G·Bᵀ), R = I − A(AᵀA)⁻¹Aᵀ.

use super::frame::{FrameCamera, Interior};
use super::Exterior;
use crate::coords::{GroundM, PhotoMm};
use nalgebra::{Matrix6, SMatrix};

/// 6 × 6, over ω, φ, κ (rad), X0, Y0, Z0 (m).
pub type Cov6 = [[f64; 6]; 6];

/// One resected photo: its camera and the control points it was resected from (their ids,
/// measured photo coordinates and ground).
pub struct Resected<'a> {
    pub interior: Interior,
    pub exterior: Exterior,
    pub points: Vec<(&'a str, PhotoMm, GroundM)>,
}

/// The photos' orientation covariances with the control's ground error shared.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockCovariance {
    /// Each photo's own covariance (measuring and ground errors).
    pub own: Vec<Cov6>,
    /// Between the photos that share a control point.
    pub cross: CrossCovariances,
    /// Each photo's measuring error σ_img, mm, once the ground's share is taken out.
    pub sigma_image_mm: Vec<f64>,
}

impl BlockCovariance {
    /// Cov(δpᵢ, δpⱼ): the photo's own for i = j, `None` for photos that share no point.
    pub fn between(&self, i: usize, j: usize) -> Option<Cov6> {
        if i == j {
            self.own.get(i).copied()
        } else {
            self.cross.between(i, j)
        }
    }
}

/// Cov(δpᵢ, δpⱼ) of the photos i < j whose orientations covary, each pair once.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CrossCovariances(pub Vec<(usize, usize, Cov6)>);

impl CrossCovariances {
    /// Cov(δpᵢ, δpⱼ) for i ≠ j (the stored one's transpose for i > j); `None` where the two
    /// do not covary.
    pub fn between(&self, i: usize, j: usize) -> Option<Cov6> {
        let (a, b) = (i.min(j), i.max(j));
        let c = self.0.iter().find(|(x, y, _)| (*x, *y) == (a, b))?.2;
        Some(if i < j {
            c
        } else {
            std::array::from_fn(|r| std::array::from_fn(|s| c[s][r]))
        })
    }

    /// The same covariances with each photo's index `i` renamed `to[i]` (increasing, so that
    /// i < j stays so).
    pub fn renamed(&self, to: &[usize]) -> CrossCovariances {
        CrossCovariances(
            self.0
                .iter()
                .map(|(i, j, c)| (to[*i], to[*j], *c))
                .collect(),
        )
    }
}

/// Per point: ∂(photo x, y)/∂(ω, φ, κ, X0, Y0, Z0) and ∂(photo x, y)/∂(X, Y, Z) (mm per
/// rad, per m), by central differences (the exterior's over [`Exterior::STEPS`], the
/// ground's over 1 cm).
type PointPartials = (SMatrix<f64, 2, 6>, SMatrix<f64, 2, 3>);

fn partials(interior: &Interior, e: &Exterior, g: GroundM) -> Option<PointPartials> {
    let project = |e: Exterior, g: GroundM| {
        FrameCamera {
            interior: *interior,
            exterior: e,
        }
        .project(g)
    };
    let mut a = SMatrix::<f64, 2, 6>::zeros();
    for (k, h) in Exterior::STEPS.iter().enumerate() {
        let (p, q) = (project(e.nudged(k, *h), g)?, project(e.nudged(k, -*h), g)?);
        a[(0, k)] = (p.x - q.x) / (2.0 * h);
        a[(1, k)] = (p.y - q.y) / (2.0 * h);
    }
    let mut b = SMatrix::<f64, 2, 3>::zeros();
    for k in 0..3 {
        let at = |s: f64| {
            let mut p = [g.x, g.y, g.z];
            p[k] += s;
            project(*e, GroundM::new(p[0], p[1], p[2]))
        };
        let (p, q) = (at(0.01)?, at(-0.01)?);
        b[(0, k)] = (p.x - q.x) / 0.02;
        b[(1, k)] = (p.y - q.y) / 0.02;
    }
    Some((a, b))
}

fn to_array(m: &Matrix6<f64>) -> Cov6 {
    std::array::from_fn(|r| std::array::from_fn(|s| m[(r, s)]))
}

/// The block's covariances for control points with ground σ `sigma_xy_m` (X and Y) and
/// `sigma_z_m`; `None` for a photo with fewer than 4 points (no redundancy to split) or a
/// singular design.
pub fn block_covariance(
    photos: &[Resected],
    sigma_xy_m: f64,
    sigma_z_m: f64,
) -> Option<BlockCovariance> {
    let sg = SMatrix::<f64, 3, 3>::from_diagonal(&nalgebra::Vector3::new(
        sigma_xy_m * sigma_xy_m,
        sigma_xy_m * sigma_xy_m,
        sigma_z_m * sigma_z_m,
    ));
    // Per photo: (AᵀA)⁻¹, σ²_img, and per point id −Kᵢ's columns times Bₖ (6 × 3).
    type Sens<'s> = Vec<(&'s str, SMatrix<f64, 6, 3>)>;
    let mut per: Vec<(Matrix6<f64>, f64, Sens)> = Vec::with_capacity(photos.len());
    for ph in photos {
        let m = ph.points.len();
        if m < 4 {
            return None;
        }
        let parts: Vec<PointPartials> = ph
            .points
            .iter()
            .map(|(_, _, g)| partials(&ph.interior, &ph.exterior, *g))
            .collect::<Option<_>>()?;
        let n: Matrix6<f64> = parts.iter().map(|(a, _)| a.transpose() * a).sum();
        let ni = n.try_inverse()?;
        // Residuals at the solution.
        let cam = FrameCamera {
            interior: ph.interior,
            exterior: ph.exterior,
        };
        let mut vv = 0.0;
        for (_, obs, g) in &ph.points {
            let q = cam.project(*g)?;
            vv += (obs.x - q.x).powi(2) + (obs.y - q.y).powi(2);
        }
        // tr(R·B·Σ_G·Bᵀ) = Σₖ tr(Mₖ) − Σₖ tr(Aₖ N⁻¹ Aₖᵀ Mₖ), Mₖ = Bₖ Σ_G Bₖᵀ.
        let ground_in_residuals: f64 = parts
            .iter()
            .map(|(a, b)| {
                let mk = b * sg * b.transpose();
                mk.trace() - (a * ni * a.transpose() * mk).trace()
            })
            .sum();
        let red = (2 * m - 6) as f64;
        let s2 = ((vv - ground_in_residuals) / red).max(0.0);
        let sens = ph
            .points
            .iter()
            .zip(&parts)
            .map(|((id, _, _), (a, b))| (*id, -(ni * a.transpose() * b)))
            .collect();
        per.push((ni, s2, sens));
    }
    let share = |i: usize, j: usize| -> Matrix6<f64> {
        let mut c = Matrix6::zeros();
        for (id, si) in &per[i].2 {
            for (jd, sj) in &per[j].2 {
                if id == jd {
                    c += si * sg * sj.transpose();
                }
            }
        }
        c
    };
    let own = (0..per.len())
        .map(|i| to_array(&(per[i].0 * per[i].1 + share(i, i))))
        .collect();
    let mut cross = CrossCovariances::default();
    for i in 0..per.len() {
        for j in i + 1..per.len() {
            let shared = per[i]
                .2
                .iter()
                .any(|(a, _)| per[j].2.iter().any(|(b, _)| a == b));
            if shared {
                cross.0.push((i, j, to_array(&share(i, j))));
            }
        }
    }
    Some(BlockCovariance {
        own,
        cross,
        sigma_image_mm: per.iter().map(|p| p.1.sqrt()).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::resect;

    /// A small LCG with Box–Muller normals: the test's own draws.
    struct Draws(u64);
    impl Draws {
        fn uniform(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }
        fn normal(&mut self) -> f64 {
            let (u, v) = (self.uniform(), self.uniform());
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        }
    }

    /// The closed form against a second method: Monte Carlo over the same design. Two photos
    /// 60 % overlapping see nine shared control points; each draw disturbs the points' ground
    /// (0.5 m) and the photo measurements (5 µm), resects both photos again and keeps how
    /// their orientations moved. The sample covariances, own and between the photos, match
    /// the predicted ones; the prediction also knows σ_img from each draw's residuals.
    #[test]
    fn shared_ground_errors_move_the_photos_together_as_predicted() {
        let interior = Interior {
            focal_mm: 153.0,
            principal_point: PhotoMm::new(0.0, 0.0),
            lens: crate::geometry::Lens::NONE,
        };
        let ext = |x0: f64| Exterior {
            omega: 0.01,
            phi: -0.005,
            kappa: 0.02,
            centre: GroundM::new(x0, 0.0, 1500.0),
        };
        let truth = [ext(-400.0), ext(400.0)];
        let ground: Vec<GroundM> = (0..9)
            .map(|k| {
                let (i, j) = ((k % 3) as f64 - 1.0, (k / 3) as f64 - 1.0);
                GroundM::new(350.0 * i, 700.0 * j, 40.0 * (i * j + i))
            })
            .collect();
        let ids: Vec<String> = (0..9).map(|k| format!("g{k}")).collect();
        let (s_g, s_img) = (0.5, 0.005);
        let mut d = Draws(7);
        let draws = 1500;
        let mut dp = vec![[[0.0; 6]; 2]; draws];
        let mut predicted: Option<BlockCovariance> = None;
        for draw in dp.iter_mut() {
            let noisy: Vec<GroundM> = ground
                .iter()
                .map(|g| {
                    GroundM::new(
                        g.x + s_g * d.normal(),
                        g.y + s_g * d.normal(),
                        g.z + s_g * d.normal(),
                    )
                })
                .collect();
            let mut resected = Vec::new();
            for (i, t) in truth.iter().enumerate() {
                let cam = FrameCamera {
                    interior,
                    exterior: *t,
                };
                let pts: Vec<(PhotoMm, GroundM)> = ground
                    .iter()
                    .zip(&noisy)
                    .map(|(g, n)| {
                        let q = cam.project(*g).unwrap();
                        (
                            PhotoMm::new(q.x + s_img * d.normal(), q.y + s_img * d.normal()),
                            *n,
                        )
                    })
                    .collect();
                let r = resect(&interior, &pts).unwrap();
                let e = r.exterior;
                let got = [e.omega, e.phi, e.kappa, e.centre.x, e.centre.y, e.centre.z];
                let want = [t.omega, t.phi, t.kappa, t.centre.x, t.centre.y, t.centre.z];
                for k in 0..6 {
                    draw[i][k] = got[k] - want[k];
                }
                resected.push(Resected {
                    interior,
                    exterior: e,
                    points: ids
                        .iter()
                        .zip(&pts)
                        .map(|(id, (q, g))| (id.as_str(), *q, *g))
                        .collect(),
                });
            }
            if predicted.is_none() {
                predicted = block_covariance(&resected, s_g, s_g);
            }
        }
        let p = predicted.unwrap();
        let sample = |i: usize, j: usize, a: usize, b: usize| {
            dp.iter().map(|x| x[i][a] * x[j][b]).sum::<f64>() / draws as f64
        };
        // The heights' and the tilts' parts: Z0 with itself and across, φ across, X0 with φ.
        for (i, j, a, b) in [
            (0, 0, 5, 5),
            (1, 1, 5, 5),
            (0, 1, 5, 5),
            (0, 1, 1, 1),
            (0, 1, 3, 1),
            (0, 0, 0, 0),
            (0, 1, 4, 0),
        ] {
            let want = p.between(i, j).unwrap()[a][b];
            let scale = (p.own[i][a][a] * p.own[j][b][b]).sqrt();
            let got = sample(i, j, a, b);
            // 1500 draws: a sample covariance's standard error is about scale/√1500 ≈ 0.03.
            assert!(
                (got - want).abs() < 0.12 * scale,
                "Cov(photo {i} param {a}, photo {j} param {b}): sample {got:.3e}, predicted {want:.3e} (scale {scale:.3e})"
            );
        }
        // What it is for: the height intersected from the two resected photos at a point
        // between the controls. Its error is wᵢᵀδpᵢ summed over the photos (w = ∂Z/∂p by
        // differences of the intersection); the shared ground makes its variance far smaller
        // than the photos taken as independent say, and the sample agrees with the former.
        let g = GroundM::new(60.0, 150.0, 20.0);
        let z_of = |e: [Exterior; 2]| {
            let rays: Vec<(FrameCamera, PhotoMm)> = (0..2)
                .map(|i| {
                    let q = FrameCamera {
                        interior,
                        exterior: truth[i],
                    }
                    .project(g)
                    .unwrap();
                    (
                        FrameCamera {
                            interior,
                            exterior: e[i],
                        },
                        q,
                    )
                })
                .collect();
            crate::geometry::intersect(&rays).unwrap().point.z
        };
        let moved = |i: usize, x: &[f64; 6]| {
            let mut e = truth;
            for (k, by) in x.iter().enumerate() {
                e[i] = e[i].nudged(k, *by);
            }
            e
        };
        let w: [[f64; 6]; 2] = std::array::from_fn(|i| {
            std::array::from_fn(|k| {
                let h = if k < 3 { 1e-6 } else { 1e-3 };
                let mut x = [0.0; 6];
                x[k] = h;
                let up = z_of(moved(i, &x));
                x[k] = -h;
                (up - z_of(moved(i, &x))) / (2.0 * h)
            })
        });
        let quad = |c: &Cov6, a: &[f64; 6], b: &[f64; 6]| {
            (0..6)
                .map(|r| (0..6).map(|s| a[r] * c[r][s] * b[s]).sum::<f64>())
                .sum::<f64>()
        };
        let independent = quad(&p.own[0], &w[0], &w[0]) + quad(&p.own[1], &w[1], &w[1]);
        let joint = independent + 2.0 * quad(&p.between(0, 1).unwrap(), &w[0], &w[1]);
        let sample_z = dp
            .iter()
            .map(|x| {
                let mut e = truth;
                for (i, ei) in e.iter_mut().enumerate() {
                    *ei = moved(i, &x[i])[i];
                }
                (z_of(e) - g.z).powi(2)
            })
            .sum::<f64>()
            / draws as f64;
        assert!(
            (sample_z / joint - 1.0).abs() < 0.15,
            "σ_Z sample {:.3} m, predicted {:.3} m",
            sample_z.sqrt(),
            joint.sqrt()
        );
        assert!(
            independent > 2.0 * joint,
            "independent {:.3} m vs joint {:.3} m",
            independent.sqrt(),
            joint.sqrt()
        );
        // σ_img from one draw's residuals, once the ground's share is out: near 5 µm.
        for s in &p.sigma_image_mm {
            assert!(*s < 0.012, "σ_img {s} mm");
        }
    }

    #[test]
    fn too_few_points_give_no_split() {
        let interior = Interior {
            focal_mm: 100.0,
            principal_point: PhotoMm::new(0.0, 0.0),
            lens: crate::geometry::Lens::NONE,
        };
        let r = Resected {
            interior,
            exterior: Exterior {
                omega: 0.0,
                phi: 0.0,
                kappa: 0.0,
                centre: GroundM::new(0.0, 0.0, 1000.0),
            },
            points: vec![("a", PhotoMm::new(0.0, 0.0), GroundM::new(0.0, 0.0, 0.0)); 3],
        };
        assert_eq!(block_covariance(&[r], 0.1, 0.1), None);
    }
}
