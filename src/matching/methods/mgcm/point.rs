//! One point with its blunder tests per ray (seed 002: "the quality test is applied for each
//! ray of each point separately"): the rays whose patch leaves its photo are left out before
//! the adjustment; after it, a ray that correlates poorly, or whose own unconstrained match
//! lies away from where the common object point puts it (data snooping: the free match's
//! shift from the constrained centre against its covariance), is dropped and the point solved
//! again with the rest, as long as the reference and one search photo remain. Rejected rays
//! are kept with their reasons.

use crate::coords::PixelXY;
use crate::matching::methods::mgcm::adjust::{
    mean_sd, sample_patch, solve, template, AdjustParams, Patch, PointFailure, Sample, Template,
};
use crate::matching::methods::mgcm::adjust::{Solution, View};
use nalgebra::{Matrix4, Vector4};
use serde::{Deserialize, Serialize};

/// Thresholds of the per-ray tests.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RayTests {
    /// A ray whose patch correlates below this with the template is a blunder.
    pub min_corr: f64,
    /// Data snooping: a ray whose free match lies further than this many standard deviations
    /// (√ of the χ² with 2 degrees of freedom) from its constrained centre is a blunder. 4 is
    /// a false alarm rate of 3·10⁻⁴ per ray.
    pub snoop: f64,
    /// The free match's shift is refused above this, px (a different patch nearby).
    pub max_free_px: f64,
}

impl Default for RayTests {
    fn default() -> Self {
        RayTests {
            min_corr: 0.6,
            snoop: 4.0,
            max_free_px: 1.5,
        }
    }
}

/// Why a ray was left out of a point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, thiserror::Error)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum RayRejection {
    #[error("the patch leaves the photo")]
    Outside,
    #[error("correlation {corr:.2} below the threshold")]
    Correlation { corr: f64 },
    #[error(
        "its free match lies {w:.1} σ ({shift_px:.2} px) from where the other rays put the point"
    )]
    Snooped { w: f64, shift_px: f64 },
    #[error("the point could be solved only without it ({cause})")]
    Spoils { cause: PointFailure },
}

/// A rejected ray: its photo (index into the caller's views) and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Rejected {
    pub photo: usize,
    pub reason: RayRejection,
}

/// What became of one point: its solution, or why there is none, and the rays left out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PointResult {
    /// The template's pixel in the reference photo (integer, corner-origin index).
    pub pixel: (usize, usize),
    pub solution: Result<Solution, PointFailure>,
    pub rejected: Vec<Rejected>,
    /// The snooping statistic of each ray kept (same order as the solution's rays).
    pub snoop_w: Vec<f64>,
}

/// The template's own match into one photo with the shape fixed: shift (2) and radiometry
/// (2), from `start`; returns the shift and its 2 × 2 covariance (the sandwich of the
/// template's and the patch's slopes, widened by the residuals' autocovariance, as in the
/// adjustment).
fn free_match(
    view: View<'_>,
    tpl: &Template,
    start: PixelXY,
    shape: [[f64; 2]; 2],
    gain: (f64, f64),
    half: usize,
) -> Option<([f64; 2], [[f64; 2]; 2])> {
    let mut p = Patch {
        photo: 0,
        centre: start,
        start,
        shape,
        r0: gain.0,
        r1: gain.1,
    };
    let t = &tpl.values;
    let mut buf = Vec::new();
    for _ in 0..10 {
        sample_patch(view.image, &p, half, &tpl.grad, &mut buf)?;
        let (n, _, b) = normals(t, &buf);
        let d = n.cholesky()?.solve(&b);
        p.centre = PixelXY::new(p.centre.col + d[0], p.centre.row + d[1]);
        p.r0 += d[2];
        p.r1 += d[3];
        if p.centre.dist(start) > 4.0 || p.r1 <= 0.0 {
            return None;
        }
        if d[0].hypot(d[1]) < 1e-3 {
            break;
        }
    }
    sample_patch(view.image, &p, half, &tpl.grad, &mut buf)?;
    let (n, bj, _) = normals(t, &buf);
    let bi = bj.try_inverse()?;
    let side = 2 * half + 1;
    let v: Vec<f64> = t.iter().zip(&buf).map(|(ti, smp)| ti - smp.g).collect();
    let dof = (v.len() as f64 - 4.0).max(1.0);
    let s0 = v.iter().map(|x| x * x).sum::<f64>() / dof;
    let cov = s0 * bi * n * bi.transpose();
    let infl = |a: usize| -> Vec<f64> {
        let hv = bi.transpose().column(a).into_owned();
        buf.iter()
            .map(|smp| Vector4::new(smp.a[0], smp.a[1], smp.a[6], smp.a[7]).dot(&hv))
            .collect()
    };
    let (h0, h1) = (infl(0), infl(1));
    let inside = vec![true; v.len()];
    let [a, b] = crate::hac::variance(
        [&h0, &h1],
        &v,
        &inside,
        side,
        (half / 2).max(1),
        v.len() as f64 / dof,
    );
    let scale = [
        (a / cov[(0, 0)].max(1e-30)).max(1.0),
        (b / cov[(1, 1)].max(1e-30)).max(1.0),
    ];
    let f = (scale[0] * scale[1]).sqrt();
    let cov = [
        [cov[(0, 0)] * f, cov[(0, 1)] * f],
        [cov[(1, 0)] * f, cov[(1, 1)] * f],
    ];
    Some(([p.centre.col - start.col, p.centre.row - start.row], cov))
}

/// AᵀA, AᵀJ and Aᵀl of the free match (shift, r0, r1).
fn normals(t: &[f64], buf: &[Sample]) -> (Matrix4<f64>, Matrix4<f64>, Vector4<f64>) {
    let mut n = Matrix4::zeros();
    let mut bj = Matrix4::zeros();
    let mut b = Vector4::zeros();
    for (ti, smp) in t.iter().zip(buf) {
        let a = Vector4::new(smp.a[0], smp.a[1], smp.a[6], smp.a[7]);
        let j = Vector4::new(smp.j[0], smp.j[1], smp.j[6], smp.j[7]);
        n += a * a.transpose();
        bj += a * j.transpose();
        b += a * (ti - smp.g);
    }
    (n, bj, b)
}

/// The snooping statistic: √(Δᵀ Σ⁻¹ Δ).
fn mahalanobis(d: [f64; 2], c: [[f64; 2]; 2]) -> f64 {
    let det = c[0][0] * c[1][1] - c[0][1] * c[1][0];
    if det <= 0.0 {
        return f64::INFINITY;
    }
    let q = (c[1][1] * d[0] * d[0] - 2.0 * c[0][1] * d[0] * d[1] + c[0][0] * d[1] * d[1]) / det;
    q.max(0.0).sqrt()
}

/// Matches the point at integer pixel `q0` of `reference` into the `searches` that see it,
/// from height `z0`, testing every ray and re-solving without the worst failed one.
pub fn match_point(
    reference: View<'_>,
    q0: (usize, usize),
    searches: &[View<'_>],
    z0: f64,
    p: &AdjustParams,
    tests: &RayTests,
) -> PointResult {
    let mut rejected = Vec::new();
    let fail = |cause, rejected| PointResult {
        pixel: q0,
        solution: Err(cause),
        rejected,
        snoop_w: Vec::new(),
    };
    let t = match template(reference.image, q0.0, q0.1, p.half) {
        Ok(t) => t,
        Err(e) => return fail(e, rejected),
    };
    if mean_sd(&t.values).1 <= 0.0 {
        return fail(PointFailure::Flat, rejected);
    }
    let qc = PixelXY::new(q0.0 as f64 + 0.5, q0.1 as f64 + 0.5);
    let Some(g0) = reference.sensor.image_to_ground(qc, z0) else {
        return fail(PointFailure::NoRay, rejected);
    };
    // Rays whose patch (with its reach) stays inside their photo.
    let margin = (p.half as f64) * 1.5 + p.max_move_px + 2.0;
    let mut active: Vec<usize> = Vec::new();
    for (k, s) in searches.iter().enumerate() {
        let (w, h) = (s.image.image.width as f64, s.image.image.height as f64);
        match s.sensor.ground_to_image(g0) {
            Some(q)
                if q.col > margin && q.row > margin && q.col < w - margin && q.row < h - margin =>
            {
                active.push(k)
            }
            _ => rejected.push(Rejected {
                photo: k,
                reason: RayRejection::Outside,
            }),
        }
    }
    loop {
        if active.is_empty() {
            return fail(PointFailure::TooFewRays, rejected);
        }
        let views: Vec<View> = active.iter().map(|&k| searches[k]).collect();
        let sol = match solve(reference, q0, &views, z0, p) {
            Ok(s) => s,
            Err(cause) if active.len() > 1 => {
                // One ray may spoil the lot: the best solution without one of them.
                let mut best: Option<(usize, Solution)> = None;
                for drop in 0..active.len() {
                    let v: Vec<View> = active
                        .iter()
                        .enumerate()
                        .filter(|&(i, _)| i != drop)
                        .map(|(_, &k)| searches[k])
                        .collect();
                    if let Ok(s) = solve(reference, q0, &v, z0, p) {
                        if best.as_ref().is_none_or(|(_, b)| s.sigma0 < b.sigma0) {
                            best = Some((drop, s));
                        }
                    }
                }
                match best {
                    Some((drop, _)) => {
                        rejected.push(Rejected {
                            photo: active[drop],
                            reason: RayRejection::Spoils { cause },
                        });
                        active.remove(drop);
                        continue;
                    }
                    None => return fail(cause, rejected),
                }
            }
            Err(cause) => return fail(cause, rejected),
        };
        // The tests: the worst correlation first, then the largest snooping statistic.
        let mut worst: Option<(usize, RayRejection)> = None;
        let low = sol
            .rays
            .iter()
            .enumerate()
            .filter(|(_, r)| r.corr.is_nan() || r.corr < tests.min_corr)
            .min_by(|a, b| a.1.corr.total_cmp(&b.1.corr));
        if let Some((i, r)) = low {
            worst = Some((i, RayRejection::Correlation { corr: r.corr }));
        }
        let mut ws = Vec::with_capacity(sol.rays.len());
        for (i, r) in sol.rays.iter().enumerate() {
            let w = match free_match(views[i], &t, r.centre, r.shape, (r.offset, r.gain), p.half) {
                Some((d, c)) if d[0].hypot(d[1]) <= tests.max_free_px => {
                    (mahalanobis(d, c), d[0].hypot(d[1]))
                }
                Some((d, _)) => (f64::INFINITY, d[0].hypot(d[1])),
                // No free match (a straight edge leaves the shift along it undetermined):
                // untestable, not a blunder.
                None => (f64::NAN, f64::NAN),
            };
            ws.push(w);
        }
        if worst.is_none() {
            let big = ws
                .iter()
                .enumerate()
                .filter(|(_, w)| w.0 > tests.snoop)
                .max_by(|a, b| a.1 .0.total_cmp(&b.1 .0));
            if let Some((i, &(w, shift_px))) = big {
                worst = Some((i, RayRejection::Snooped { w, shift_px }));
            }
        }
        match worst {
            None => {
                return PointResult {
                    pixel: q0,
                    solution: Ok(Solution {
                        rays: sol
                            .rays
                            .into_iter()
                            .map(|mut r| {
                                r.photo = active[r.photo];
                                r
                            })
                            .collect(),
                        ..sol
                    }),
                    rejected,
                    snoop_w: ws.into_iter().map(|w| w.0).collect(),
                }
            }
            Some((i, reason)) => {
                rejected.push(Rejected {
                    photo: active[i],
                    reason,
                });
                if active.len() == 1 {
                    return fail(PointFailure::TooFewRays, rejected);
                }
                active.remove(i);
            }
        }
    }
}
