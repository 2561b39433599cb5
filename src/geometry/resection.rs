//! Space resection: a photo's exterior orientation from ground control points (their ground
//! coordinates and where they appear in the photo), by Gauss–Newton on the collinearity
//! equations, starting from a similarity between the photo and the ground plane.

use super::frame::{Exterior, FrameCamera, Interior};
use crate::coords::{GroundM, PhotoMm};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Resection {
    pub exterior: Exterior,
    /// σ0 of the photo coordinates, mm.
    pub sigma0_mm: f64,
    /// Standard deviations of ω, φ, κ (rad) and X0, Y0, Z0 (m).
    pub sigma: [f64; 6],
    /// Their covariance σ0²·N⁻¹ (rad, m), for propagating the orientation's uncertainty to
    /// where the photo puts a ground point ([`crate::geometry::Sensor::pointing_covariance`]).
    #[serde(default)]
    pub covariance: [[f64; 6]; 6],
    pub residuals_mm: Vec<[f64; 2]>,
    pub iterations: usize,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ResectionError {
    #[error("{0} control points: a resection needs at least 3 (4 or more to check them)")]
    TooFewPoints(usize),
    #[error("the normal equations are singular (control points in a line?)")]
    Singular,
    #[error("no convergence after {0} iterations")]
    NoConvergence(usize),
}

fn exterior(p: &[f64]) -> Exterior {
    Exterior {
        omega: p[0],
        phi: p[1],
        kappa: p[2],
        centre: GroundM::new(p[3], p[4], p[5]),
    }
}

/// Residuals observed − projected of every point (2 per point), mm.
fn residuals(interior: &Interior, p: &[f64], pts: &[(PhotoMm, GroundM)]) -> Option<Vec<f64>> {
    let cam = FrameCamera {
        interior: *interior,
        exterior: exterior(p),
    };
    let mut v = Vec::with_capacity(2 * pts.len());
    for (obs, g) in pts {
        let q = cam.project(*g)?;
        v.push(obs.x - q.x);
        v.push(obs.y - q.y);
    }
    Some(v)
}

/// Near-vertical start: κ and the plan position from a 2-D similarity photo → ground, the
/// height from its scale.
fn start(interior: &Interior, pts: &[(PhotoMm, GroundM)]) -> [f64; 6] {
    let n = pts.len() as f64;
    let (mp, mg) = pts.iter().fold(([0.0; 2], [0.0; 3]), |(a, b), (p, g)| {
        (
            [a[0] + p.x / n, a[1] + p.y / n],
            [b[0] + g.x / n, b[1] + g.y / n, b[2] + g.z / n],
        )
    });
    // Ground = s·R(θ)·photo + t, as complex numbers: (a + ib) = Σ conj(p)·g / Σ |p|².
    let (mut sa, mut sb, mut sp) = (0.0, 0.0, 0.0);
    for (p, g) in pts {
        let (px, py) = (p.x - mp[0], p.y - mp[1]);
        let (gx, gy) = (g.x - mg[0], g.y - mg[1]);
        sa += px * gx + py * gy;
        sb += px * gy - py * gx;
        sp += px * px + py * py;
    }
    let (a, b) = (sa / sp.max(1e-12), sb / sp.max(1e-12));
    let scale = a.hypot(b); // m per mm
    let kappa = b.atan2(a);
    let pp = interior.principal_point;
    let (dx, dy) = (pp.x - mp[0], pp.y - mp[1]);
    [
        0.0,
        0.0,
        kappa,
        mg[0] + a * dx - b * dy,
        mg[1] + b * dx + a * dy,
        mg[2] + scale * interior.focal_mm,
    ]
}

pub fn resect(
    interior: &Interior,
    pts: &[(PhotoMm, GroundM)],
) -> Result<Resection, ResectionError> {
    if pts.len() < 3 {
        return Err(ResectionError::TooFewPoints(pts.len()));
    }
    let mut p = start(interior, pts);
    let steps = [1e-6, 1e-6, 1e-6, 1e-3, 1e-3, 1e-3];
    let max_iter = 30;
    for it in 1..=max_iter {
        let v0 = residuals(interior, &p, pts).ok_or(ResectionError::Singular)?;
        let mut j = DMatrix::zeros(v0.len(), 6);
        for k in 0..6 {
            let mut q = p;
            q[k] += steps[k];
            let v1 = residuals(interior, &q, pts).ok_or(ResectionError::Singular)?;
            for i in 0..v0.len() {
                // ∂(projected)/∂p = −∂v/∂p.
                j[(i, k)] = (v0[i] - v1[i]) / steps[k];
            }
        }
        let n = j.transpose() * &j;
        let ninv = n.clone().try_inverse().ok_or(ResectionError::Singular)?;
        let dp = &ninv * (j.transpose() * DVector::from_vec(v0.clone()));
        for k in 0..6 {
            p[k] += dp[k];
        }
        let small = (0..3).all(|k| dp[k].abs() < 1e-9) && (3..6).all(|k| dp[k].abs() < 1e-5);
        if small {
            let v = residuals(interior, &p, pts).ok_or(ResectionError::Singular)?;
            let red = (v.len() as f64 - 6.0).max(1.0);
            let s0 = (v.iter().map(|x| x * x).sum::<f64>() / red).sqrt();
            let sigma = std::array::from_fn(|k| s0 * ninv[(k, k)].sqrt());
            let covariance =
                std::array::from_fn(|i| std::array::from_fn(|k| s0 * s0 * ninv[(i, k)]));
            return Ok(Resection {
                exterior: exterior(&p),
                sigma0_mm: s0,
                sigma,
                covariance,
                residuals_mm: v.chunks(2).map(|c| [c[0], c[1]]).collect(),
                iterations: it,
            });
        }
    }
    Err(ResectionError::NoConvergence(max_iter))
}
