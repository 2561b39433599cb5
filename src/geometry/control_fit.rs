//! A given sensor model corrected by ground control points: what a line scanner's ephemeris
//! and attitude, or a vendor's RPCs, leave off by tens of metres, the control points take out.
//!
//! - **Line scanner** (seed 004's "rigorous solution", Kratky: the orbit and attitude adjusted
//!   to control): offsets of the position (X, Y, Z, m), of the attitude (roll, pitch, yaw,
//!   rad) and rates of the attitude (rad/s), nine unknowns by Gauss–Newton on the pixels'
//!   residuals. With a narrow field of view a shift of the position and a turn of the attitude
//!   move the image almost alike, so each unknown also carries an a-priori standard deviation
//!   ([`OrbitPrior`]), a pseudo-observation of zero: the adjustment takes the control points'
//!   word where they decide and the prior's where they cannot.
//! - **RPC**: a shift of the image coordinates (the bias compensation of Fraser and Hanley,
//!   2003), the mean of the control points' residuals, applied to LINE_OFF and SAMP_OFF.

use super::pushbroom::Pushbroom;
use super::rpc::RpcSensor;
use super::Sensor;
use crate::coords::{GroundM, PixelXY};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// The fewest control points a correction takes.
pub const MIN_POINTS_ORBIT: usize = 3;
pub const MIN_POINTS_RPC: usize = 1;
/// Gauss–Newton iterations at the most, and the last step (px of image motion) that counts
/// as converged.
const MAX_ITERATIONS: usize = 20;
const CONVERGED_PX: f64 = 1e-6;

/// A-priori standard deviations of the orbit's corrections (the ephemeris' and attitude
/// sensors' accuracy). Defaults as a SPOT-era ephemeris: 50 m in position, 1e-4 rad (about
/// 80 m on the ground from 830 km) in attitude, 1e-6 rad/s in its drift.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OrbitPrior {
    pub position_m: f64,
    pub attitude_rad: f64,
    pub attitude_rate: f64,
}

impl Default for OrbitPrior {
    fn default() -> Self {
        OrbitPrior {
            position_m: 50.0,
            attitude_rad: 1e-4,
            attitude_rate: 1e-6,
        }
    }
}

/// Names of the orbit's nine corrections, in the order of [`ControlFit::parameters`].
pub const ORBIT_PARAMETERS: [&str; 9] = [
    "X (m)",
    "Y (m)",
    "Z (m)",
    "roll (rad)",
    "pitch (rad)",
    "yaw (rad)",
    "roll rate (rad/s)",
    "pitch rate (rad/s)",
    "yaw rate (rad/s)",
];

/// The outcome of a correction: each unknown with its standard deviation, and the control
/// points' residuals before and after.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ControlFit {
    /// "orbit and attitude" or "RPC image shift".
    pub kind: String,
    pub points: usize,
    /// (name, value, σ).
    pub parameters: Vec<(String, f64, f64)>,
    /// RMS of the control points' pixel residuals (both axes together) before and after.
    pub rms_before_px: f64,
    pub rms_after_px: f64,
    /// Each control point's residual (measured − projected), col and row, px, after.
    pub residuals_px: Vec<[f64; 2]>,
    pub iterations: usize,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ControlFitError {
    #[error("{got} control points; the correction needs at least {need}")]
    TooFew { got: usize, need: usize },
    #[error("control point {index} ({ground:?}) does not project into the model's image")]
    OffImage { index: usize, ground: GroundM },
    #[error("a control point's coordinates are not finite numbers")]
    NotFinite,
    #[error("the normal equations are singular")]
    Singular,
    #[error("no convergence in {MAX_ITERATIONS} iterations (last step {last_px:.3e} px)")]
    NoConvergence { last_px: f64 },
}

fn check_points(points: &[(PixelXY, GroundM)], need: usize) -> Result<(), ControlFitError> {
    if points.len() < need {
        return Err(ControlFitError::TooFew {
            got: points.len(),
            need,
        });
    }
    let finite = points
        .iter()
        .all(|(q, g)| [q.col, q.row, g.x, g.y, g.z].iter().all(|v| v.is_finite()));
    if finite {
        Ok(())
    } else {
        Err(ControlFitError::NotFinite)
    }
}

/// Measured − projected for every point, `None` for a point off the model.
fn residuals(
    s: &dyn Sensor,
    points: &[(PixelXY, GroundM)],
) -> Result<Vec<[f64; 2]>, ControlFitError> {
    points
        .iter()
        .enumerate()
        .map(|(index, (q, g))| {
            let p = s
                .ground_to_image(*g)
                .ok_or(ControlFitError::OffImage { index, ground: *g })?;
            Ok([q.col - p.col, q.row - p.row])
        })
        .collect()
}

/// A control point's σ as given, or 1 px where it is not a positive number.
fn measured(sigma_px: f64) -> f64 {
    if sigma_px.is_finite() && sigma_px > 0.0 {
        sigma_px
    } else {
        1.0
    }
}

fn rms(r: &[[f64; 2]]) -> f64 {
    (r.iter().map(|v| v[0] * v[0] + v[1] * v[1]).sum::<f64>() / (2 * r.len()).max(1) as f64).sqrt()
}

/// `model` with corrections `c` (position, attitude, attitude rate) added to its
/// polynomials' constant and linear terms.
fn corrected(model: &Pushbroom, c: &[f64]) -> Pushbroom {
    let mut m = *model;
    for a in 0..3 {
        m.position[a][0] += c[a];
        m.attitude[a][0] += c[3 + a];
        m.attitude[a][1] += c[6 + a];
    }
    m
}

/// Corrects a line scanner's orbit and attitude to control points (pixel, ground), each
/// measured to `sigma_px`; the priors hold what the points cannot decide.
pub fn correct_orbit(
    model: &Pushbroom,
    points: &[(PixelXY, GroundM)],
    sigma_px: f64,
    prior: OrbitPrior,
) -> Result<(Pushbroom, ControlFit), ControlFitError> {
    check_points(points, MIN_POINTS_ORBIT)?;
    let sigma_px = measured(sigma_px);
    let before = rms(&residuals(model, points)?);
    let priors = [
        prior.position_m,
        prior.position_m,
        prior.position_m,
        prior.attitude_rad,
        prior.attitude_rad,
        prior.attitude_rad,
        prior.attitude_rate,
        prior.attitude_rate,
        prior.attitude_rate,
    ];
    // Numerical partials: steps that move the image by about a hundredth of a pixel.
    let steps = [0.1, 0.1, 0.1, 1e-7, 1e-7, 1e-7, 1e-8, 1e-8, 1e-8];
    let n = ORBIT_PARAMETERS.len();
    let mut c = vec![0.0; n];
    let mut last = f64::INFINITY;
    for iteration in 1..=MAX_ITERATIONS {
        let m = corrected(model, &c);
        let r = residuals(&m, points)?;
        let mut a = DMatrix::<f64>::zeros(2 * points.len(), n);
        for k in 0..n {
            let (mut up, mut down) = (c.clone(), c.clone());
            up[k] += steps[k];
            down[k] -= steps[k];
            let (mu, md) = (corrected(model, &up), corrected(model, &down));
            for (i, (_, g)) in points.iter().enumerate() {
                let (Some(pu), Some(pd)) = (mu.ground_to_image(*g), md.ground_to_image(*g)) else {
                    return Err(ControlFitError::OffImage {
                        index: i,
                        ground: *g,
                    });
                };
                a[(2 * i, k)] = (pu.col - pd.col) / (2.0 * steps[k]);
                a[(2 * i + 1, k)] = (pu.row - pd.row) / (2.0 * steps[k]);
            }
        }
        let l = DVector::from_iterator(2 * points.len(), r.iter().flat_map(|v| [v[0], v[1]]));
        let w = 1.0 / (sigma_px * sigma_px);
        let mut nm = a.transpose() * &a * w;
        let mut b = a.transpose() * &l * w;
        // Priors: each correction observed as zero with its σ.
        for k in 0..n {
            let pw = 1.0 / (priors[k] * priors[k]);
            nm[(k, k)] += pw;
            b[k] -= pw * c[k];
        }
        let chol = nm.clone().cholesky().ok_or(ControlFitError::Singular)?;
        let dx = chol.solve(&b);
        for k in 0..n {
            c[k] += dx[k];
        }
        // How far the step moved the image at the control points.
        last = (&a * &dx).amax();
        if last < CONVERGED_PX {
            let m = corrected(model, &c);
            let r = residuals(&m, points)?;
            let cov = chol.inverse();
            let parameters = ORBIT_PARAMETERS
                .iter()
                .enumerate()
                .map(|(k, name)| (name.to_string(), c[k], cov[(k, k)].sqrt()))
                .collect();
            return Ok((
                m,
                ControlFit {
                    kind: "orbit and attitude".into(),
                    points: points.len(),
                    parameters,
                    rms_before_px: before,
                    rms_after_px: rms(&r),
                    residuals_px: r,
                    iterations: iteration,
                },
            ));
        }
    }
    Err(ControlFitError::NoConvergence { last_px: last })
}

/// Shifts an RPC sensor's image coordinates by the control points' mean residual (Fraser and
/// Hanley's bias compensation), each point measured to `sigma_px`.
pub fn correct_rpc_shift(
    sensor: &RpcSensor,
    points: &[(PixelXY, GroundM)],
    sigma_px: f64,
) -> Result<(RpcSensor, ControlFit), ControlFitError> {
    check_points(points, MIN_POINTS_RPC)?;
    let r = residuals(sensor, points)?;
    let n = r.len() as f64;
    let shift = [
        r.iter().map(|v| v[0]).sum::<f64>() / n,
        r.iter().map(|v| v[1]).sum::<f64>() / n,
    ];
    let mut s = sensor.clone();
    s.rpc.samp_off += shift[0];
    s.rpc.line_off += shift[1];
    let after = residuals(&s, points)?;
    let sigma = measured(sigma_px) / n.sqrt();
    Ok((
        s,
        ControlFit {
            kind: "RPC image shift".into(),
            points: points.len(),
            parameters: vec![
                ("column shift (px)".into(), shift[0], sigma),
                ("row shift (px)".into(), shift[1], sigma),
            ],
            rms_before_px: rms(&r),
            rms_after_px: rms(&after),
            residuals_px: after,
            iterations: 1,
        },
    ))
}

#[cfg(test)]
mod tests;
