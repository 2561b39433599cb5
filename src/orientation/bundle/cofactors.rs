//! The adjusted unknowns' cofactors from the reduced system's inverse: each point's own and
//! its cross cofactors with the parameter blocks it observes, and each ray's J·Q·Jᵀ (for its
//! redundancy number and data snooping).

use super::normal::{Lin, PointLin, RayLin};
use super::*;

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

/// A tested ray: its index, residual (mm), normalised residuals and redundancy number.
pub(super) type TestedRay = (usize, [f64; 2], Option<[f64; 2]>, f64);

/// Each adjusted point's rays tested (Baarda's normalised residual with σ̂₀ = `sigma0`, Pope's τ,
/// and the redundancy number, from the ray's Q_vv = Q_ll − J·Q·Jᵀ) and its cofactor Q_pp.
pub(super) fn tested(
    lin: &Lin,
    vinv: &[Option<Matrix3<f64>>],
    qcc: &DMatrix<f64>,
    sigma0: f64,
) -> Vec<(usize, Vec<TestedRay>, Matrix3<f64>)> {
    lin.points
        .par_iter()
        .enumerate()
        .filter_map(|(j, p)| {
            let (p, vi) = (p.as_ref()?, vinv[j].as_ref()?);
            let (qpp, pc) = point_cofactor(p, vi, qcc);
            let rays = p
                .rays
                .iter()
                .map(|r| {
                    let jqj = ray_cofactor(r, &qpp, &pc, qcc);
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
        .collect()
}
