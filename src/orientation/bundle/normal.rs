//! The normal equations of the bundle and Levenberg–Marquardt on them: each ray linearised
//! (its photo's, its camera's and its point's partials), the points eliminated into the
//! reduced system of photos and cameras (Schur complement, [`crate::orientation::reduced`]),
//! one damped step solved and the points back-substituted (Triggs et al. 2000, §6).

use super::start::{groups, start};
use super::*;

/// The linearised rays of one point and its own normal-equation block.
pub(super) struct PointLin {
    pub(super) v: Matrix3<f64>,
    pub(super) g: Vector3<f64>,
    pub(super) rays: Vec<RayLin>,
    pub(super) cost: f64,
}

pub(super) struct RayLin {
    pub(super) ray: usize,
    pub(super) photo: usize,
    pub(super) a: SMatrix<f64, 2, 6>,
    /// The self-calibrated camera's parameter block and the ray's partials by it (the held
    /// parameters' columns zero).
    pub(super) cal: Option<(usize, SMatrix<f64, 2, 6>)>,
    pub(super) b: SMatrix<f64, 2, 3>,
    pub(super) r: Vector2<f64>,
    /// 1/σ² times the robust weight.
    pub(super) w: f64,
}

impl RayLin {
    /// The parameter blocks the ray observes and its partials by each: its photo's exterior,
    /// and its camera's interior where that is estimated.
    pub(super) fn parts(&self) -> impl Iterator<Item = (usize, &SMatrix<f64, 2, 6>)> {
        std::iter::once((self.photo, &self.a)).chain(self.cal.as_ref().map(|(k, m)| (*k, m)))
    }
}

pub(super) struct Lin {
    pub(super) points: Vec<Option<PointLin>>,
    /// The diagonal blocks of the direct normal equations, photos then cameras.
    pub(super) u: Vec<Matrix6<f64>>,
    /// Each photo's block with its camera's (rows: the camera's parameters).
    pub(super) cross: Vec<Matrix6<f64>>,
    pub(super) g: Vec<Vector6<f64>>,
    pub(super) cost: f64,
}

/// The unknowns: each photo's exterior, each self-calibrated camera's interior, each point.
#[derive(Clone)]
pub(super) struct Params {
    pub(super) cams: Vec<Exterior>,
    pub(super) ints: Vec<Interior>,
    pub(super) pts: Vec<Vector3<f64>>,
}

/// The adjustment's working state.
pub(super) struct State<'a> {
    pub(super) block: &'a Block,
    pub(super) settings: Settings,
    pub(super) x: Params,
    /// Each photo's self-calibrated camera, if any (an index into `block.calibrate`).
    pub(super) group: Vec<Option<usize>>,
    /// Active rays of each adjusted point (empty: the point is not adjusted).
    pub(super) by_point: Vec<Vec<usize>>,
    pub(super) status: Vec<RayStatus>,
    pub(super) robust: bool,
    /// Whether the approximations' priors enter the normal equations (off only to tell what
    /// the rays alone determine, [`calibrated`]).
    pub(super) priors: bool,
    pub(super) reduced: Reduced,
}

impl<'a> State<'a> {
    /// The block checked, at its start values, with its pattern.
    pub(super) fn begin(
        block: &'a Block,
        settings: Settings,
        robust: bool,
    ) -> Result<State<'a>, BundleError> {
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
    pub(super) fn interior(&self, ints: &[Interior], i: usize) -> Interior {
        self.group[i].map_or(self.block.photos[i].interior, |g| ints[g])
    }

    /// Each photo's interior at the current state.
    pub(super) fn interiors(&self) -> Vec<Interior> {
        (0..self.block.photos.len())
            .map(|i| self.interior(&self.x.ints, i))
            .collect()
    }

    pub(super) fn adjusted(&self, j: usize) -> bool {
        let n = self.by_point[j].len();
        match self.block.points[j].role {
            Role::Control { .. } => n >= 1,
            Role::Tie => n >= 2,
            Role::Check { .. } => false,
        }
    }

    /// The parameter blocks of the normal equations: photos, then self-calibrated cameras.
    pub(super) fn blocks(&self) -> usize {
        self.block.photos.len() + self.block.calibrate.len()
    }

    pub(super) fn rebuild_pattern(&mut self) {
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

    pub(super) fn linearise(&self, x: &Params) -> Lin {
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
    pub(super) fn schur(
        &mut self,
        lin: &Lin,
        lambda: f64,
    ) -> (DVector<f64>, Vec<Option<Matrix3<f64>>>) {
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
    pub(super) fn step(&mut self, lin: &Lin, lambda: f64) -> Result<Params, ReducedError> {
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
    pub(super) fn converge(&mut self) -> Result<usize, BundleError> {
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

    pub(super) fn not_converged(&self, iterations: usize, lin: &Lin) -> BundleError {
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
