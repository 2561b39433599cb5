//! `covariance.csv`: the oriented photos' covariance as the adjustment found it, correlated
//! between photos, for the elevation model's σ.
//!
//! A block's orientations do not err independently: photos tied by common points move
//! together, and two photos that move together intersect a model that is shifted or tilted,
//! not one whose heights scatter. The height's σ then needs Cov(δpᵢ, δpⱼ) of the photos that
//! see the same ground ([`crate::matching::accuracy::orientation_error`]); each photo's `sigma`
//! key alone would take them as independent.
//!
//! The file holds the 6 × 6 blocks of σ̂₀²·Q (ω, φ, κ in rad, X₀, Y₀, Z₀ in m: the order of
//! [`crate::geometry::FrameSensor::exterior_cov`]) of each photo with itself and of each pair
//! of photos whose footprints overlap (the only pairs a model's node can see together), one
//! line per row of a block:
//!
//! ```text
//! photo_a,photo_b,row,omega_rad,phi_rad,kappa_rad,x0_m,y0_m,z0_m
//! 1,1,omega_rad,3.4e-8,…
//! ```
//!
//! Row `r` of block (a, b) is Cov(parameter r of a, each parameter of b).

use crate::geometry::control_covariance::{Cov6, CrossCovariances};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

pub const FILE: &str = "covariance.csv";
const PARAMETERS: [&str; 6] = ["omega_rad", "phi_rad", "kappa_rad", "x0_m", "y0_m", "z0_m"];
const HEADER: &str = "photo_a,photo_b,row,omega_rad,phi_rad,kappa_rad,x0_m,y0_m,z0_m";

/// The file's text: each photo's own block, then the blocks of `pairs` (i < j), from
/// `between(i, j)`.
pub fn text(
    ids: &[String],
    pairs: &[(usize, usize)],
    between: &dyn Fn(usize, usize) -> Cov6,
) -> String {
    let mut s = String::from(HEADER);
    s.push('\n');
    let blocks = (0..ids.len()).map(|i| (i, i)).chain(pairs.iter().copied());
    for (i, j) in blocks {
        let c = between(i, j);
        for (r, row) in c.iter().enumerate() {
            let _ = write!(s, "{},{},{}", ids[i], ids[j], PARAMETERS[r]);
            for v in row {
                let _ = write!(s, ",{v:e}");
            }
            s.push('\n');
        }
    }
    s
}

/// What [`read`] gives: each photo's own covariance (`None` for a photo the file leaves out)
/// and the cross covariances of the pairs it holds.
#[derive(Debug, Clone, PartialEq)]
pub struct Covariances {
    pub own: Vec<Option<Cov6>>,
    pub cross: CrossCovariances,
}

/// Largest variance taken, rad² or m² (a σ of 10⁶ m is no orientation).
const MAX_VARIANCE: f64 = 1e12;

/// Reads `path` for the photos `ids` (the project's, in its order), every number checked with
/// its line: finite, the variances ≥ 0 and at most 10¹², each photo's own block symmetric
/// with a positive semi-definite diagonal, every block whole (six rows).
pub fn read(path: &Path, ids: &[String]) -> Result<Covariances, String> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let at = |n: usize, m: String| format!("{}, line {n}: {m}", path.display());
    let index: HashMap<&str, usize> = ids
        .iter()
        .enumerate()
        .map(|(k, s)| (s.as_str(), k))
        .collect();
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, h)) if h.trim() == HEADER => {}
        _ => {
            return Err(at(
                1,
                format!("the header must be `{HEADER}` (the file `rig orient` writes)"),
            ))
        }
    }
    let mut blocks: HashMap<(usize, usize), (Cov6, [bool; 6])> = HashMap::new();
    for (n, line) in lines {
        let n = n + 1;
        if line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() != 9 {
            return Err(at(n, format!("{} fields, 9 expected ({HEADER})", f.len())));
        }
        let photo = |s: &str| {
            index
                .get(s)
                .copied()
                .ok_or_else(|| at(n, format!("photo `{s}` is not one of the project's")))
        };
        let (a, b) = (photo(f[0])?, photo(f[1])?);
        let r = PARAMETERS.iter().position(|p| *p == f[2]).ok_or_else(|| {
            at(
                n,
                format!("row `{}`: one of {}", f[2], PARAMETERS.join(", ")),
            )
        })?;
        let mut row = [0.0; 6];
        for (k, v) in row.iter_mut().enumerate() {
            *v = f[3 + k]
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite() && v.abs() <= MAX_VARIANCE)
                .ok_or_else(|| {
                    at(
                        n,
                        format!(
                            "{} `{}`: a finite number within ±1e12",
                            PARAMETERS[k],
                            f[3 + k]
                        ),
                    )
                })?;
        }
        // Stored with a ≤ b in the project's order (b's block transposed otherwise).
        let (key, transpose) = if a <= b {
            ((a, b), false)
        } else {
            ((b, a), true)
        };
        let e = blocks.entry(key).or_insert(([[0.0; 6]; 6], [false; 6]));
        if transpose {
            for (k, v) in row.iter().enumerate() {
                e.0[k][r] = *v;
            }
        } else {
            e.0[r] = row;
        }
        if e.1[r] {
            return Err(at(
                n,
                format!("block {} × {} row {} given twice", f[0], f[1], f[2]),
            ));
        }
        e.1[r] = true;
    }
    let mut own = vec![None; ids.len()];
    let mut cross = Vec::new();
    let mut keys: Vec<_> = blocks.keys().copied().collect();
    keys.sort();
    for (a, b) in keys {
        let (c, seen) = blocks[&(a, b)];
        let name = format!("{}: block {} × {}", path.display(), ids[a], ids[b]);
        if !seen.iter().all(|s| *s) {
            return Err(format!(
                "{name} lacks rows (six per block: {})",
                PARAMETERS.join(", ")
            ));
        }
        if a == b {
            for k in 0..6 {
                if c[k][k] < 0.0 {
                    return Err(format!(
                        "{name}: variance of {} {} < 0",
                        PARAMETERS[k], c[k][k]
                    ));
                }
                for l in 0..k {
                    let tol = 1e-6 * (c[k][k] * c[l][l]).sqrt() + 1e-300;
                    if (c[k][l] - c[l][k]).abs() > tol {
                        return Err(format!(
                            "{name}: not symmetric ({} × {} {:e}, {} × {} {:e})",
                            PARAMETERS[k],
                            PARAMETERS[l],
                            c[k][l],
                            PARAMETERS[l],
                            PARAMETERS[k],
                            c[l][k]
                        ));
                    }
                    if c[k][l] * c[k][l] > c[k][k] * c[l][l] * (1.0 + 1e-6) {
                        return Err(format!(
                            "{name}: covariance of {} and {} exceeds their σ's product (a correlation above 1)",
                            PARAMETERS[k], PARAMETERS[l]
                        ));
                    }
                }
            }
            own[a] = Some(c);
        } else {
            cross.push((a, b, c));
        }
    }
    for &(a, b, _) in &cross {
        if own[a].is_none() || own[b].is_none() {
            return Err(format!(
                "{}: photos {} and {} covary but the file gives no block of {} with itself",
                path.display(),
                ids[a],
                ids[b],
                if own[a].is_none() { &ids[a] } else { &ids[b] }
            ));
        }
    }
    Ok(Covariances {
        own,
        cross: CrossCovariances(cross),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cov(seed: f64) -> Cov6 {
        // A symmetric positive definite block: LLᵀ of a lower triangle.
        let l: [[f64; 6]; 6] = std::array::from_fn(|r| {
            std::array::from_fn(|c| {
                if c <= r {
                    1e-3 * (seed + (r * 7 + c) as f64).sin() + if r == c { 0.01 } else { 0.0 }
                } else {
                    0.0
                }
            })
        });
        std::array::from_fn(|r| std::array::from_fn(|c| (0..6).map(|k| l[r][k] * l[c][k]).sum()))
    }

    /// What is written reads back block for block (cross blocks either way round).
    #[test]
    fn blocks_read_back_as_written() {
        let ids: Vec<String> = ["a", "b", "c"].iter().map(|s| s.to_string()).collect();
        let own = [cov(1.0), cov(2.0), cov(3.0)];
        let x01 = cov(4.0).map(|r| r.map(|v| 0.5 * v + 1e-5));
        let between = |i: usize, j: usize| if i == j { own[i] } else { x01 };
        let t = text(&ids, &[(0, 1)], &between);
        let dir = std::env::temp_dir().join(format!("rig-cov-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join(FILE);
        std::fs::write(&f, &t).unwrap();
        let c = read(&f, &ids).unwrap();
        for k in 0..3 {
            let got = c.own[k].unwrap();
            for r in 0..6 {
                for s in 0..6 {
                    assert!(
                        (got[r][s] - own[k][r][s]).abs() <= 1e-12 * own[k][r][s].abs().max(1e-300)
                    );
                }
            }
        }
        let got = c.cross.between(0, 1).unwrap();
        let back = c.cross.between(1, 0).unwrap();
        for r in 0..6 {
            for s in 0..6 {
                assert!((got[r][s] - x01[r][s]).abs() <= 1e-12 * x01[r][s].abs());
                assert_eq!(back[s][r], got[r][s]);
            }
        }
        assert!(c.cross.between(0, 2).is_none());
        // Bad files are refused with the line and the cause.
        let bad = |s: String, want: &str| {
            std::fs::write(&f, s).unwrap();
            let e = read(&f, &ids).unwrap_err();
            assert!(e.contains(want), "{e} lacks {want}");
        };
        bad(t.replacen("photo_a", "photo", 1), "header");
        bad(t.replacen("\na,a,", "\nz,a,", 1), "`z` is not one of");
        bad(
            t.replacen("\na,a,omega_rad,", "\na,a,omega,", 1),
            "row `omega`",
        );
        let first_value = t
            .lines()
            .nth(1)
            .unwrap()
            .split(',')
            .nth(3)
            .unwrap()
            .to_string();
        bad(t.replacen(&first_value, "NaN", 1), "finite");
        bad(
            t.replacen(&first_value, &format!("-{first_value}"), 1),
            "< 0",
        );
        let dropped: String = t
            .lines()
            .filter(|l| !l.starts_with("b,b,z0_m"))
            .map(|l| format!("{l}\n"))
            .collect();
        bad(dropped, "lacks rows");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The block's covariance carried into a height: over 120 blocks that differ only in
    /// their noise (and their truth's angles), the height intersected at one ground point from
    /// the pairs 1 × 2 and 2 × 3 of the adjusted orientations (the image points exact, so that
    /// the orientations' error is all there is) errs by the σ that the covariance, with its
    /// blocks between photos, gives it (the sweep's [`height_sigma`] and pointing
    /// covariances): RMS(error/σ) within 0.8–1.25. The photos' own blocks alone give a σ
    /// that is not the error's.
    #[test]
    fn a_heights_sigma_from_the_blocks_covariance_is_its_error_over_repeated_blocks() {
        use crate::coords::GroundM;
        use crate::geometry::sensor::propagate_between;
        use crate::geometry::{intersect, FrameCamera, FrameSensor};
        use crate::matching::accuracy::orientation_error::height_sigma;
        use crate::matching::block::photo::centred_grid;
        use crate::orientation::bundle::{adjust, Settings};
        use crate::orientation::synthetic::{make, Spec, HALF_FRAME_MM, PIXEL_MM};
        let side = (2.0 * HALF_FRAME_MM / PIXEL_MM).round() as usize;
        let (mut with, mut alone, mut n) = (0.0, 0.0, 0usize);
        for seed in 0..120 {
            let s = make(Spec {
                strips: 2,
                per_strip: 4,
                rays_per_photo: 40,
                control_side: 2,
                noise_px: 0.5,
                position_sigma_m: 20.0,
                angles_sigma_deg: 2.0,
                seed: 1000 + seed,
            });
            let a = adjust(&s.block, Settings::default()).unwrap();
            // The ground under photo 2 (between 1 and 3).
            let c = s.exteriors[1].centre;
            let g = s
                .ground
                .iter()
                .min_by(|p, q| {
                    let d = |p: &GroundM| (p.x - c.x).powi(2) + (p.y - c.y).powi(2);
                    d(p).total_cmp(&d(q))
                })
                .copied()
                .unwrap();
            let cam = |i: usize, e| FrameCamera {
                interior: s.block.photos[i].interior,
                exterior: e,
            };
            let z = |i: usize, j: usize| {
                let rays: Vec<_> = [i, j]
                    .iter()
                    .map(|&k| {
                        (
                            cam(k, a.exteriors[k]),
                            cam(k, s.exteriors[k]).project(g).unwrap(),
                        )
                    })
                    .collect();
                intersect(&rays).unwrap().point.z
            };
            let err = 0.5 * (z(0, 1) + z(1, 2)) - g.z;
            let sensors: Vec<FrameSensor> = (0..3)
                .map(|k| FrameSensor {
                    camera: cam(k, a.exteriors[k]),
                    frame: centred_grid(side, side, PIXEL_MM).into(),
                    exterior_cov: Some(a.between(k, k)),
                    radial: Default::default(),
                })
                .collect();
            let pairs = [(0, 1), (1, 2)];
            let cross = |i: usize, j: usize| {
                let (ji, jj) = (
                    sensors[i].exterior_partials(g)?,
                    sensors[j].exterior_partials(g)?,
                );
                Some(propagate_between(&ji, &a.between(i, j), &jj))
            };
            let sigma = height_sigma(&sensors, &pairs, g, &cross).unwrap();
            let sigma_alone = height_sigma(&sensors, &pairs, g, &|_, _| None).unwrap();
            with += (err / sigma).powi(2);
            alone += (err / sigma_alone).powi(2);
            n += 1;
        }
        let (with, alone) = ((with / n as f64).sqrt(), (alone / n as f64).sqrt());
        println!("RMS(error/σ) over {n} blocks: {with:.3} with the blocks between photos, {alone:.3} with each photo's alone");
        assert!((0.8..=1.25).contains(&with), "RMS(error/σ) {with:.3}");
        assert!(
            (alone - with).abs() > 0.1 * with,
            "the photos' blocks alone give {alone:.3}, as the correlated {with:.3}: the test shows nothing"
        );
    }
}
