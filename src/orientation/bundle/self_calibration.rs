//! The self-calibrated cameras' parameters tested for whether the block determines them, with
//! their σ.

use super::normal::Lin;
use super::*;

/// Where an adjustment's normal equations are singular with cameras to calibrate: the block
/// cannot tell their parameters from the exteriors ([`calibrated`] names the weakest one
/// where the solve goes through).
pub(super) fn undetermined(block: &Block, e: ReducedError) -> BundleError {
    match block.calibrate.first() {
        Some(c) => BundleError::Singular {
            camera: c.camera.clone(),
            parameters: PARAMETERS
                .iter()
                .zip(c.free)
                .filter(|(_, f)| *f)
                .map(|(p, _)| p.0)
                .collect::<Vec<_>>()
                .join(", "),
        },
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
pub(super) fn calibrated(
    block: &Block,
    ints: &[Interior],
    qcc: &DMatrix<f64>,
    rays_only: Option<&DMatrix<f64>>,
    sigma0: f64,
    lin: &Lin,
) -> Result<Vec<Calibrated>, BundleError> {
    let n = block.photos.len();
    // Each camera's outermost ray radius and its rays' σ, in one pass over the rays.
    let mut radius = vec![0.0f64; block.calibrate.len()];
    let mut sigmas: Vec<Vec<f64>> = vec![Vec::new(); block.calibrate.len()];
    for r in lin.points.iter().flatten().flat_map(|p| &p.rays) {
        let Some((k, _)) = r.cal else { continue };
        let (g, ray) = (k - n, &block.rays[r.ray]);
        let pp = ints[g].principal_point;
        radius[g] = radius[g].max((ray.xy.x - pp.x).hypot(ray.xy.y - pp.y));
        sigmas[g].push(ray.sigma_mm);
    }
    let mut out = Vec::new();
    for (g, c) in block.calibrate.iter().enumerate() {
        let int = ints[g];
        let (radius, sigmas) = (radius[g], &mut sigmas[g]);
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
