//! Photo geometry against the simulator's own collinearity and ray–terrain intersection (a
//! separate implementation): projection, space intersection, space resection.

use rig::coords::{GroundM, PhotoMm};
use rig::geometry::{intersect, resect, FrameCamera};
use rig_sim::scene::{jacksboro, AerialPhoto};

fn camera(p: &AerialPhoto) -> FrameCamera {
    rig::sim_scene::frame_camera(p)
}

fn photos() -> (AerialPhoto, AerialPhoto) {
    let d = jacksboro();
    (
        AerialPhoto::new(d.clone(), 9, 1, 1.0),
        AerialPhoto::new(d, 9, 2, 1.0),
    )
}

#[test]
fn projection_agrees_with_the_simulator_and_rays_return_to_their_point() {
    let (a, _) = photos();
    let cam = camera(&a);
    for q in [[0.0, 0.0], [80.0, -60.0], [-100.0, 95.0], [12.5, 3.25]] {
        let g = a.ground_point(q);
        let p = cam.project(GroundM::new(g[0], g[1], g[2])).unwrap();
        assert!(
            (p.x - q[0]).abs() < 1e-6 && (p.y - q[1]).abs() < 1e-6,
            "{q:?} → {p:?}"
        );
        let back = cam.at_height(p, g[2]);
        assert!((back.x - g[0]).abs() < 1e-4 && (back.y - g[1]).abs() < 1e-4);
    }
}

#[test]
fn two_rays_meet_at_the_terrain_point() {
    let (a, b) = photos();
    let (ca, cb) = (camera(&a), camera(&b));
    let mut worst: f64 = 0.0;
    for q in [[40.0, 0.0], [60.0, -80.0], [20.0, 90.0], [85.0, 30.0]] {
        let g = a.ground_point(q);
        let g = GroundM::new(g[0], g[1], g[2]);
        let pb = cb.project(g).unwrap();
        let r = intersect(&[(ca, PhotoMm::new(q[0], q[1])), (cb, pb)]).unwrap();
        let e = ((r.point.x - g.x).powi(2) + (r.point.y - g.y).powi(2) + (r.point.z - g.z).powi(2))
            .sqrt();
        worst = worst.max(e);
    }
    assert!(worst < 1e-3, "{worst} m");
    // A 5 µm error in one photo's x moves the point by about the parallax's height factor:
    // Z error ≈ (H/B)·(scale)·5 µm ≈ 1.7 · 42 500 · 5 µm ≈ 0.35 m.
    let g = a.ground_point([40.0, 0.0]);
    let g = GroundM::new(g[0], g[1], g[2]);
    let pb = cb.project(g).unwrap();
    let r = intersect(&[(ca, PhotoMm::new(40.005, 0.0)), (cb, pb)]).unwrap();
    let dz = (r.point.z - g.z).abs();
    assert!((0.15..0.8).contains(&dz), "dz {dz}");
}

#[test]
fn resection_recovers_the_orientation_from_noisy_control() {
    let (a, _) = photos();
    let cam = camera(&a);
    let mut rng = rig_sim::rng::Rng::new(4);
    let mut pts = Vec::new();
    for j in 0..4 {
        for i in 0..4 {
            let q = [-90.0 + 60.0 * i as f64, -90.0 + 60.0 * j as f64];
            let g = a.ground_point(q);
            // 3 µm measuring noise on the photo, 0.3 m on the ground.
            pts.push((
                PhotoMm::new(q[0] + 0.003 * rng.normal(), q[1] + 0.003 * rng.normal()),
                GroundM::new(
                    g[0] + 0.3 * rng.normal(),
                    g[1] + 0.3 * rng.normal(),
                    g[2] + 0.3 * rng.normal(),
                ),
            ));
        }
    }
    let r = resect(&cam.interior, &pts).unwrap();
    let (t, e) = (cam.exterior, r.exterior);
    let d = [
        (e.centre.x - t.centre.x).abs(),
        (e.centre.y - t.centre.y).abs(),
        (e.centre.z - t.centre.z).abs(),
    ];
    eprintln!(
        "resection: ΔX0 {:.2} ΔY0 {:.2} ΔZ0 {:.2} m, Δω {:.4}° Δφ {:.4}° Δκ {:.4}°, σ0 {:.4} mm, {} iterations",
        d[0], d[1], d[2],
        (e.omega - t.omega).to_degrees(),
        (e.phi - t.phi).to_degrees(),
        (e.kappa - t.kappa).to_degrees(),
        r.sigma0_mm,
        r.iterations
    );
    // Within three of its own standard deviations (and a metre, whatever they say).
    for k in 0..3 {
        assert!(
            d[k] < (3.0 * r.sigma[3 + k]).max(1.0),
            "axis {k}: {} m",
            d[k]
        );
    }
    assert!((e.kappa - t.kappa).abs() < (3.0 * r.sigma[2]).max(1e-4));
    assert!(r.sigma0_mm < 0.01);
}
