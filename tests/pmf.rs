//! Polynomial mapping functions derived from the rigorous model of two simulated photos
//! (seed 004 §4), checked against that model at points it was not fitted to.

use rig::coords::GroundM;
use rig::coords::PixelXY;
use rig::geometry::{FrameSensor, Sensor};
use rig::matching::PmfSet;
use rig::scan::PhotoGrid;
use rig_sim::scene::{jacksboro, AerialPhoto};

fn rigorous(p: &AerialPhoto, area: [f64; 4]) -> FrameSensor {
    FrameSensor {
        camera: rig::sim_scene::frame_camera(p),
        frame: PhotoGrid::covering(area, 0.025).into(),
        exterior_cov: None,
        radial: Default::default(),
    }
}

/// Photo 1 of seed 5's block, and the areas of photos 1 and 2 that see the same ground.
fn pair() -> (AerialPhoto, FrameSensor, FrameSensor) {
    let d = jacksboro();
    let (a, b) = (
        AerialPhoto::new(d.clone(), 5, 1, 1.0),
        AerialPhoto::new(d, 5, 2, 1.0),
    );
    let l = rigorous(&a, [36.0, -10.0, 56.0, 10.0]);
    let r = rigorous(&b, [-58.0, -12.0, -34.0, 12.0]);
    (a, l, r)
}

#[test]
fn derived_mappings_reproduce_the_rigorous_model() {
    let (a, l, r) = pair();
    // The terrain under the left area, with a margin.
    let mut hs = Vec::new();
    for j in 0..=10 {
        for i in 0..=10 {
            hs.push(a.ground_point([36.0 + 2.0 * i as f64, -10.0 + 2.0 * j as f64])[2]);
        }
    }
    let lo = hs.iter().cloned().fold(f64::MAX, f64::min) - 20.0;
    let hi = hs.iter().cloned().fold(f64::MIN, f64::max) + 20.0;
    let set = PmfSet::from_sensors(&l, &r, [lo, hi], 3).unwrap();
    for f in &set.report {
        eprintln!(
            "{:28} {:2} terms  GCP RMSE {:.5}  CP RMSE {:.5} {}",
            f.name, f.terms, f.gcp_rmse, f.cp_rmse, f.units
        );
    }
    let mut rng = rig_sim::rng::Rng::new(3);
    let (mut e_img, mut e_gnd, mut e_h): (f64, f64, f64) = (0.0, 0.0, 0.0);
    for _ in 0..200 {
        let px = [
            rng.uniform() * l.frame.width as f64,
            rng.uniform() * l.frame.height as f64,
        ];
        let h = lo + (hi - lo) * rng.uniform();
        let g = l.image_to_ground(PixelXY::new(px[0], px[1]), h).unwrap();
        let q = r.ground_to_image(g).map(|q| [q.col, q.row]).unwrap();
        let m = set.left_to_right.eval([px[0], px[1], h]);
        e_img = e_img.max((m[0] - q[0]).hypot(m[1] - q[1]));
        let gg = set.left_to_ground.eval([px[0], px[1], h]);
        e_gnd = e_gnd.max((gg[0] - g.x).hypot(gg[1] - g.y));
        let back = set.ground_to_right.eval([g.x, g.y, h]);
        e_img = e_img.max((back[0] - q[0]).hypot(back[1] - q[1]));
        e_h = e_h.max((set.height.eval([px[0], px[1], q[0]]) - h).abs());
    }
    eprintln!("worst: image {e_img:.4} px, ground {e_gnd:.3} m, height from triplet {e_h:.3} m");
    // 0.01 px is 0.25 µm on the film; 0.1 m is 2.4 µm at the photo scale.
    assert!(e_img < 0.01, "image→image {e_img} px");
    assert!(e_gnd < 0.1, "image→ground {e_gnd} m");
    // x″ moves 1 px (25 µm) for about 1.7 × 42 500 × 25 µm ≈ 1.8 m of height.
    assert!(e_h < 0.1, "height {e_h} m");
}

#[test]
fn mappings_from_noisy_control_points_reach_the_measuring_noise() {
    // Seed 000's situation: control and check points measured in both photos (0.3 px) and
    // on the ground (0.5 m), terms chosen from the full second order by the check points.
    let (a, l, r) = pair();
    let mut rng = rig_sim::rng::Rng::new(8);
    let mut pts = Vec::new();
    for k in 0..70 {
        let px = [
            rng.uniform() * l.frame.width as f64,
            rng.uniform() * l.frame.height as f64,
        ];
        let photo = l.frame.photo(rig::coords::PixelXY::new(px[0], px[1]));
        let g = a.ground_point([photo.x, photo.y]);
        let g = GroundM::new(g[0], g[1], g[2]);
        let q = r.ground_to_image(g).map(|q| [q.col, q.row]).unwrap();
        let n = |rng: &mut rig_sim::rng::Rng, s: f64| s * rng.normal();
        pts.push(rig::matching::StereoPoint {
            id: format!("p{k}"),
            left: [px[0] + n(&mut rng, 0.3), px[1] + n(&mut rng, 0.3)],
            right: [q[0] + n(&mut rng, 0.3), q[1] + n(&mut rng, 0.3)],
            ground: GroundM::new(
                g.x + n(&mut rng, 0.5),
                g.y + n(&mut rng, 0.5),
                g.z + n(&mut rng, 0.5),
            ),
        });
    }
    let (gcps, cps) = pts.split_at(30);
    let set = PmfSet::from_points(2, gcps, cps).unwrap();
    for f in &set.report {
        eprintln!(
            "{:28} {:2} terms  GCP RMSE {:.3}  CP RMSE {:.3} {}",
            f.name, f.terms, f.gcp_rmse, f.cp_rmse, f.units
        );
    }
    let row = |n: &str| set.report.iter().find(|f| f.name == n).unwrap().cp_rmse;
    // Two photos' noise (0.3 px each) plus the ground's (0.5 m ≈ 0.5 px): about 0.6 px.
    assert!(row("left→right x") < 0.9 && row("left→right y") < 0.9);
    assert!(row("left→ground x") < 1.5 && row("left→ground y") < 1.5);
}
