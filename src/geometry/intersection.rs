//! Space intersection: the object point nearest (in the least-squares sense) to the rays of
//! two or more photos, with each photo's reprojection residual.

use super::frame::FrameCamera;
use crate::coords::{GroundM, PhotoMm};
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Intersection {
    pub point: GroundM,
    /// Observed − projected photo coordinates, mm, per ray.
    pub residuals_mm: Vec<[f64; 2]>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum IntersectionError {
    #[error("{0} rays: an intersection needs two or more")]
    TooFewRays(usize),
    #[error("the rays are parallel")]
    Parallel,
}

/// Minimises the sum of squared distances to the rays: Σ(I − ddᵀ)·X = Σ(I − ddᵀ)·O.
pub fn intersect(rays: &[(FrameCamera, PhotoMm)]) -> Result<Intersection, IntersectionError> {
    if rays.len() < 2 {
        return Err(IntersectionError::TooFewRays(rays.len()));
    }
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for (cam, p) in rays {
        let (o, d) = cam.ray(*p);
        let m = Matrix3::identity() - d * d.transpose();
        a += m;
        b += m * o;
    }
    if a.determinant().abs() < 1e-12 {
        return Err(IntersectionError::Parallel);
    }
    let x = a.try_inverse().ok_or(IntersectionError::Parallel)? * b;
    let point = GroundM::new(x.x, x.y, x.z);
    let residuals_mm = rays
        .iter()
        .map(|(cam, p)| {
            cam.project(point)
                .map(|q| [p.x - q.x, p.y - q.y])
                .unwrap_or([f64::NAN; 2])
        })
        .collect();
    Ok(Intersection {
        point,
        residuals_mm,
    })
}
