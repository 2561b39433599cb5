//! A block with known truth, for the tests and the benchmark: strips of vertical photos (±1°)
//! over a rolling surface, tie points scattered on the ground and seen by every photo whose
//! frame holds them, control points on a grid, rays with Gaussian noise, approximations off
//! by their stated σ. The truth is the generator's, not the adjustment's.

use super::bundle::{Block, BlockPhoto, BlockPoint, Prior, Ray, Role};
use crate::coords::{GroundM, PhotoMm};
use crate::geometry::{Exterior, FrameCamera, Interior};

/// What to make.
#[derive(Debug, Clone, Copy)]
pub struct Spec {
    pub strips: usize,
    pub per_strip: usize,
    /// Tie rays per photo, about.
    pub rays_per_photo: usize,
    /// Control points on a grid of this many a side (≥ 2).
    pub control_side: usize,
    pub noise_px: f64,
    pub position_sigma_m: f64,
    pub angles_sigma_deg: f64,
    pub seed: u64,
}

/// The block and its truth: each photo's exterior, each point's ground.
pub struct Synthetic {
    pub block: Block,
    pub exteriors: Vec<Exterior>,
    pub ground: Vec<GroundM>,
}

/// Normal deviates from a seed (xorshift64*, Box–Muller): no crate, reproducible.
struct Gauss(u64);

impl Gauss {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

pub const FOCAL_MM: f64 = 153.0;
pub const PIXEL_MM: f64 = 0.02;
pub const HALF_FRAME_MM: f64 = 115.0;
const FLYING_M: f64 = 1500.0;

fn terrain(x: f64, y: f64) -> f64 {
    120.0 * (x / 900.0).sin() * (y / 1300.0).cos() + 60.0 * (x / 310.0 + y / 470.0).sin()
}

/// How the block is flown: the camera that took the rays and the one the block is given,
/// whether every other strip is flown back (κ = 180°), and the relief (× the rolling
/// surface's ±180 m).
#[derive(Debug, Clone, Copy)]
pub struct Flight {
    pub truth: Interior,
    pub given: Interior,
    pub alternate: bool,
    pub relief: f64,
}

impl Flight {
    /// The metric camera as given, all strips one way, the rolling surface.
    pub fn metric() -> Flight {
        let interior = Interior {
            focal_mm: FOCAL_MM,
            principal_point: PhotoMm::new(0.0, 0.0),
            lens: crate::geometry::Lens::NONE,
        };
        Flight {
            truth: interior,
            given: interior,
            alternate: false,
            relief: 1.0,
        }
    }
}

pub fn make(s: Spec) -> Synthetic {
    make_flown(s, Flight::metric())
}

pub fn make_flown(s: Spec, f: Flight) -> Synthetic {
    let mut g = Gauss(s.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let interior = f.truth;
    let terrain = |x: f64, y: f64| f.relief * terrain(x, y);
    let side_m = 2.0 * HALF_FRAME_MM * FLYING_M / FOCAL_MM;
    let (base, gap) = (0.4 * side_m, 0.7 * side_m);
    let mut block = Block::default();
    let mut exteriors = Vec::new();
    for st in 0..s.strips {
        let kappa = if f.alternate && st % 2 == 1 {
            180.0
        } else {
            0.0
        };
        for k in 0..s.per_strip {
            let e = Exterior::from_degrees(
                g.normal(),
                g.normal(),
                kappa + g.normal(),
                GroundM::new(
                    k as f64 * base,
                    st as f64 * gap,
                    FLYING_M + 5.0 * g.normal(),
                ),
            );
            let approx = Exterior::from_degrees(
                0.0,
                0.0,
                kappa,
                GroundM::new(
                    e.centre.x + s.position_sigma_m * g.normal(),
                    e.centre.y + s.position_sigma_m * g.normal(),
                    e.centre.z + s.position_sigma_m * g.normal(),
                ),
            );
            block.photos.push(BlockPhoto {
                id: format!("{}-{}", st + 1, k + 1),
                interior: f.given,
                pixel_mm: PIXEL_MM,
                approx: Some(approx),
                prior: Some(Prior {
                    position_sigma_m: s.position_sigma_m,
                    angles_sigma_rad: s.angles_sigma_deg.to_radians(),
                }),
            });
            exteriors.push(e);
        }
    }
    let (x1, y1) = ((s.per_strip - 1) as f64 * base, (s.strips - 1) as f64 * gap);
    let mut ground = Vec::new();
    let sigma_mm = s.noise_px * PIXEL_MM;
    let add = |block: &mut Block,
               ground: &mut Vec<GroundM>,
               g: &mut Gauss,
               p: GroundM,
               role: Role,
               id: String| {
        let j = block.points.len();
        let mut rays = Vec::new();
        for (i, e) in exteriors.iter().enumerate() {
            let cam = FrameCamera {
                interior,
                exterior: *e,
            };
            if let Some(q) = cam.project(p) {
                if q.x.abs() < HALF_FRAME_MM && q.y.abs() < HALF_FRAME_MM {
                    rays.push(Ray {
                        point: j,
                        photo: i,
                        xy: PhotoMm::new(q.x + sigma_mm * g.normal(), q.y + sigma_mm * g.normal()),
                        sigma_mm,
                        group: 0,
                    });
                }
            }
        }
        if rays.len() >= 2 || !matches!(role, Role::Tie) {
            block.points.push(BlockPoint { id, role });
            block.rays.extend(rays);
            ground.push(p);
        }
    };
    let n = s.control_side.max(2);
    for a in 0..n {
        for b in 0..n {
            let (x, y) = (
                x1 * a as f64 / (n - 1) as f64,
                y1 * b as f64 / (n - 1) as f64,
            );
            let p = GroundM::new(x, y, terrain(x, y));
            add(
                &mut block,
                &mut ground,
                &mut g,
                p,
                Role::Control {
                    ground: p,
                    sigma_m: [0.05, 0.05, 0.05],
                },
                format!("G{a}{b}"),
            );
        }
    }
    // Tie points over the block's area; each is seen by about four photos.
    let count = s.rays_per_photo * exteriors.len() / 4;
    let pad = 0.4 * side_m;
    for t in 0..count {
        let x = -pad + (x1 + 2.0 * pad) * g.uniform();
        let y = -pad + (y1 + 2.0 * pad) * g.uniform();
        let p = GroundM::new(x, y, terrain(x, y));
        add(
            &mut block,
            &mut ground,
            &mut g,
            p,
            Role::Tie,
            format!("T{t}"),
        );
    }
    Synthetic {
        block,
        exteriors,
        ground,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::orientation::bundle::{adjust, BundleError, Settings};

    fn spec() -> Spec {
        Spec {
            strips: 3,
            per_strip: 5,
            rays_per_photo: 120,
            control_side: 2,
            noise_px: 0.3,
            position_sigma_m: 30.0,
            angles_sigma_deg: 3.0,
            seed: 4,
        }
    }

    /// From approximations 30 m and 3° off, the adjustment finds the generator's orientations
    /// within their own σ: the normalised errors of all 90 parameters have an RMS near 1
    /// (σ that can be trusted), σ̂₀ near 1, and no ray is rejected on clean data (at most the
    /// test's 0.1 % false alarms).
    #[test]
    fn a_synthetic_block_is_recovered_within_its_sigma() {
        let s = make(spec());
        let a = adjust(&s.block, Settings::default()).unwrap();
        assert!((a.sigma0 - 1.0).abs() < 0.1, "σ̂₀ {}", a.sigma0);
        let mut z2 = 0.0;
        for (i, t) in s.exteriors.iter().enumerate() {
            let e = a.exteriors[i];
            let d = [
                e.omega - t.omega,
                e.phi - t.phi,
                e.kappa - t.kappa,
                e.centre.x - t.centre.x,
                e.centre.y - t.centre.y,
                e.centre.z - t.centre.z,
            ];
            let sd = a.sigma(i);
            for k in 0..6 {
                z2 += (d[k] / sd[k]).powi(2);
            }
        }
        let rms = (z2 / (6.0 * s.exteriors.len() as f64)).sqrt();
        assert!(
            (0.6..1.5).contains(&rms),
            "RMS(error/σ) of the orientations {rms}"
        );
        assert!(
            a.rejected <= s.block.rays.len() / 200,
            "{} rejected",
            a.rejected
        );
        // Tie points within their σ too.
        let mut z2 = 0.0;
        let mut n = 0;
        for (j, p) in a.points.iter().enumerate() {
            let (Some(p), Role::Tie) = (p, s.block.points[j].role) else {
                continue;
            };
            let d = [
                p.ground.x - s.ground[j].x,
                p.ground.y - s.ground[j].y,
                p.ground.z - s.ground[j].z,
            ];
            for k in 0..3 {
                z2 += d[k] * d[k] / p.cov[(k, k)];
                n += 1;
            }
        }
        let rms = (z2 / n as f64).sqrt();
        assert!(
            (0.7..1.3).contains(&rms),
            "RMS(error/σ) of the tie points {rms}"
        );
    }

    /// RMS(error/σ) of the tie points' heights.
    fn heights_error(s: &Synthetic, a: &crate::orientation::Adjusted) -> f64 {
        let (mut z2, mut n) = (0.0, 0);
        for (j, p) in a.points.iter().enumerate() {
            let (Some(p), Role::Tie) = (p, s.block.points[j].role) else {
                continue;
            };
            z2 += (p.ground.z - s.ground[j].z).powi(2) / p.cov[(2, 2)];
            n += 1;
        }
        (z2 / n as f64).sqrt()
    }

    /// Rays that a curved Earth and the air displaced (each moved by the displacements of
    /// [`crate::geometry::radial`] at the truth's heights; 0.05 px of noise, so that the
    /// displacements of up to 0.5 px stand out): adjusted with the block's `radial` on, the
    /// tie points' heights err as those of the same block undisplaced (RMS(error/σ) within
    /// 0.15; below 1 here: the control's stated 5 cm exceeds its true error, none); taken as
    /// collinear, more than twice as much.
    #[test]
    fn refraction_and_curvature_are_taken_out_of_the_rays() {
        let mut s = make(Spec {
            noise_px: 0.05,
            control_side: 3,
            ..spec()
        });
        let reference = heights_error(&s, &adjust(&s.block, Settings::default()).unwrap());
        let radial = crate::geometry::Radial {
            refraction: true,
            earth_curvature: true,
        };
        for r in &mut s.block.rays {
            let i = s.block.photos[r.photo].interior;
            let seen = crate::geometry::radial::Seen::of(
                &i,
                s.exteriors[r.photo].centre.z,
                s.ground[r.point].z,
            );
            r.xy = radial.distort(r.xy, &seen);
        }
        let plain = heights_error(&s, &adjust(&s.block, Settings::default()).unwrap());
        s.block.radial = radial;
        let taken_out = heights_error(&s, &adjust(&s.block, Settings::default()).unwrap());
        println!("tie points' heights: RMS(error/σ) {reference:.2} undisplaced, {plain:.2} as collinear, {taken_out:.2} corrected");
        assert!(
            (taken_out - reference).abs() < 0.15,
            "corrected {taken_out:.2}, undisplaced {reference:.2}"
        );
        assert!(plain > 2.0 * reference, "as collinear: {plain:.2}");
    }

    /// A blunder of 20 px in one ray of a four-ray point is found by data snooping and
    /// removed; the orientations stay within 3σ of the truth.
    #[test]
    fn a_blunder_is_rejected_by_data_snooping() {
        let mut s = make(spec());
        let j = (0..s.block.points.len())
            .find(|&j| {
                s.block.rays.iter().filter(|r| r.point == j).count() >= 4
                    && matches!(s.block.points[j].role, Role::Tie)
            })
            .unwrap();
        let k = s.block.rays.iter().position(|r| r.point == j).unwrap();
        s.block.rays[k].xy.x += 20.0 * PIXEL_MM;
        let a = adjust(&s.block, Settings::default()).unwrap();
        assert_eq!(
            a.rays[k].status,
            crate::orientation::bundle::RayStatus::Rejected
        );
        for (i, t) in s.exteriors.iter().enumerate() {
            let sd = a.sigma(i);
            assert!(
                (a.exteriors[i].centre.x - t.centre.x).abs() < 4.0 * sd[3],
                "photo {i}"
            );
        }
    }

    /// The datum and the block's connections are checked before anything is adjusted.
    #[test]
    fn bad_blocks_are_refused_with_their_cause() {
        let s = make(spec());
        // Two control points only.
        let mut b = s.block.clone();
        let keep: Vec<usize> = (0..b.points.len())
            .filter(|&j| matches!(b.points[j].role, Role::Control { .. }))
            .skip(2)
            .collect();
        for j in keep {
            b.points[j].role = Role::Tie;
        }
        assert_eq!(
            adjust(&b, Settings::default()).unwrap_err(),
            BundleError::TooFewControl { found: 2 }
        );
        // A photo whose rays are all removed.
        let mut b = s.block.clone();
        b.rays.retain(|r| r.photo != 7);
        match adjust(&b, Settings::default()).unwrap_err() {
            BundleError::Unconnected { id, .. } => assert_eq!(id, "2-3"),
            e => panic!("{e}"),
        }
        // Control in a line.
        let mut b = s.block.clone();
        for p in &mut b.points {
            if let Role::Control { ground, .. } = &mut p.role {
                ground.y = 0.0;
            }
        }
        assert!(matches!(
            adjust(&b, Settings::default()).unwrap_err(),
            BundleError::ControlInLine { .. }
        ));
    }

    /// The film camera of a self-calibration test: 0.3 mm longer, its principal point 20 µm
    /// off, and radial distortion of 1.6 px at the frame's edge; the block is given the
    /// nominal metric camera.
    fn flown(alternate: bool, relief: f64) -> Flight {
        let mut f = Flight::metric();
        f.truth.focal_mm += 0.3;
        f.truth.principal_point = PhotoMm::new(0.015, -0.02);
        f.truth.lens = crate::geometry::Lens {
            k1: 5e-4,
            k2: -2e-4,
        };
        f.alternate = alternate;
        f.relief = relief;
        f
    }

    fn calibrating(b: &mut Block, free: [bool; 5]) {
        b.calibrate = vec![crate::orientation::bundle::SelfCalibration {
            camera: "film".into(),
            photos: (0..b.photos.len()).collect(),
            free,
        }];
    }

    /// Tie points' RMS(error/σ) in height against the generator's ground.
    fn heights_normalised(s: &Synthetic, a: &crate::orientation::bundle::Adjusted) -> f64 {
        let (mut z2, mut n) = (0.0, 0);
        for (j, p) in a.points.iter().enumerate() {
            let (Some(p), Role::Tie) = (p, s.block.points[j].role) else {
                continue;
            };
            z2 += ((p.ground.z - s.ground[j].z) / p.cov[(2, 2)].sqrt()).powi(2);
            n += 1;
        }
        (z2 / n as f64).sqrt()
    }

    /// A block taken with another camera than the one it is given (focal length, principal
    /// point, k₁, k₂; strips flown both ways over relief of ±0.12 × the flying height): as
    /// given, its tie points err in height by 5 × their σ and σ̂₀ shows it; self-calibrated,
    /// each of the five parameters is found within 3.5 σ of the generator's, the heights
    /// within their σ again, and σ̂₀ near 1.
    #[test]
    fn self_calibration_recovers_the_camera_within_its_sigma() {
        let mut sp = spec();
        sp.rays_per_photo = 300;
        let f = flown(true, 1.0);
        let s = make_flown(sp, f);
        let plain = adjust(&s.block, Settings::default()).unwrap();
        let before = heights_normalised(&s, &plain);
        let mut b = s.block.clone();
        calibrating(&mut b, [true; 5]);
        let a = adjust(&b, Settings::default()).unwrap();
        let c = &a.calibrated[0];
        let (truth, got) = (f.truth.parameters(), c.interior.parameters());
        for k in 0..5 {
            let z = (got[k] - truth[k]) / c.sigma[k];
            assert!(
                z.abs() < 3.5 && c.sigma[k] > 0.0,
                "{}: {} vs {} (σ {}): {z:.2} σ",
                crate::orientation::collinearity::INTERIOR[k],
                got[k],
                truth[k],
                c.sigma[k]
            );
        }
        let after = heights_normalised(&s, &a);
        eprintln!(
            "σ̂₀ {:.3} → {:.3}; heights' RMS(error/σ) {before:.2} → {after:.2}; σ {:?}",
            plain.sigma0, a.sigma0, c.sigma
        );
        assert!(before > 2.0, "the given camera's errors show: {before}");
        assert!((0.6..1.5).contains(&after), "{after}");
        assert!((a.sigma0 - 1.0).abs() < 0.1, "σ̂₀ {}", a.sigma0);
        assert!(a.interiors.iter().all(|i| *i == c.interior));
    }

    /// Over flat ground with vertical photos the focal length trades one for one with the
    /// flying height: only the approximations' σ of the height hold it, and the adjustment
    /// refuses to estimate it, saying why; with the principal point too. (The principal point
    /// alone is held weakly by the perspective's second-order terms: σ some 40 µm here.)
    #[test]
    fn an_undeterminable_camera_parameter_is_refused() {
        let s = make_flown(spec(), flown(false, 0.0));
        for (free, name) in [
            ([true, false, false, false, false], "focal length"),
            ([true, true, true, false, false], "focal length"),
        ] {
            let mut b = s.block.clone();
            calibrating(&mut b, free);
            match adjust(&b, Settings::default()) {
                Err(e @ BundleError::NotDeterminable { parameter, .. }) => {
                    assert!(parameter.starts_with(name), "{e}");
                    let text = e.to_string();
                    assert!(
                        text.contains("self_calibration") && text.contains("`film`"),
                        "{text}"
                    );
                }
                Err(e) => panic!("{name}: {e}"),
                Ok(a) => panic!("{name} estimated: {:?}", a.calibrated),
            }
        }
        // The distortion alone is determined by the rays out to the corners, flat or not.
        let mut b = s.block.clone();
        calibrating(&mut b, [false, false, false, true, true]);
        let a = adjust(&b, Settings::default()).unwrap();
        assert!((a.calibrated[0].interior.lens.k1 - 5e-4).abs() < 4.0 * a.calibrated[0].sigma[3]);
    }
}
