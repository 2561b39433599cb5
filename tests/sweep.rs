//! Height-sweep matching on two photos rendered by the simulator over the real DEM: heights
//! against the DEM itself.

use rig::coords::PixelXY;
use rig::digitise::ImageF32;
use rig::geometry::FrameSensor;
use rig::matching::methods::sweep::height_sweep::{sweep, SweepParams};
use rig::matching::PmfSet;
use rig::scan::PhotoGrid;
use rig_sim::scene::{jacksboro, AerialPhoto};

fn rigorous(p: &AerialPhoto, grid: PhotoGrid) -> FrameSensor {
    FrameSensor {
        camera: rig::sim_scene::frame_camera(p),
        frame: grid.into(),
        exterior_cov: None,
        radial: Default::default(),
    }
}

/// The photo on `grid`, each pixel the mean of 3×3 samples of the picture.
fn render(p: &AerialPhoto, g: &PhotoGrid) -> ImageF32 {
    let mut img = ImageF32::new(g.width, g.height);
    for r in 0..g.height {
        for c in 0..g.width {
            let mut s = 0.0;
            for j in 0..3 {
                for i in 0..3 {
                    let q = g.photo(PixelXY::new(
                        c as f64 + (i as f64 + 0.5) / 3.0,
                        r as f64 + (j as f64 + 0.5) / 3.0,
                    ));
                    s += p.transmittance([q.x, q.y]);
                }
            }
            img.data[r * g.width + c] = (1000.0 * s / 9.0) as f32;
        }
    }
    img
}

#[test]
fn heights_from_the_sweep_match_the_dem() {
    let d = jacksboro();
    let (a, b) = (
        AerialPhoto::new(d.clone(), 5, 1, 60.0),
        AerialPhoto::new(d.clone(), 5, 2, 60.0),
    );
    let gl = PhotoGrid::covering([42.0, -4.0, 50.0, 4.0], 0.025);
    let gr = PhotoGrid::covering([-56.0, -7.0, -36.0, 7.0], 0.025);
    let (l, r) = (rigorous(&a, gl), rigorous(&b, gr));
    let (li, ri) = (render(&a, &gl), render(&b, &gr));
    let mut hs = Vec::new();
    for j in 0..=8 {
        for i in 0..=8 {
            hs.push(a.ground_point([42.0 + i as f64, -4.0 + j as f64])[2]);
        }
    }
    let lo = hs.iter().cloned().fold(f64::MAX, f64::min) - 30.0;
    let hi = hs.iter().cloned().fold(f64::MIN, f64::max) + 30.0;
    let set = PmfSet::from_sensors(&l, &r, [lo, hi], 3).unwrap();
    let p = SweepParams {
        h_min: lo,
        h_max: hi,
        h_step: 2.0,
        stride: 2,
        ..Default::default()
    };
    let t = std::time::Instant::now();
    let m = sweep(&li, &ri, &set.left_to_right, &p);
    let secs = t.elapsed().as_secs_f64();
    let mut e = Vec::new();
    for j in 0..m.rows {
        for i in 0..m.cols {
            let h = m.h[j * m.cols + i];
            if !h.is_finite() {
                continue;
            }
            let px = m.pixel(i, j);
            let g = set.left_to_ground.eval([px[0], px[1], h as f64]);
            e.push(h as f64 - d.height(g[0], g[1]));
        }
    }
    let n = e.len() as f64;
    let rmse = (e.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
    let mean = e.iter().sum::<f64>() / n;
    let bad = e.iter().filter(|v| v.abs() > 10.0).count();
    eprintln!(
        "{} of {} matched; height error RMSE {rmse:.2} m, mean {mean:+.2} m, {bad} over 10 m; range {lo:.0}–{hi:.0} m; {:.1} M candidates in {secs:.2} s",
        m.matched(),
        m.cols * m.rows,
        m.candidates as f64 / 1e6
    );
    assert!(m.matched() as f64 > 0.9 * (m.cols * m.rows) as f64);
    // Robust core: the errors below 10 m (blunders are the next stage's work).
    let core: Vec<f64> = e.iter().cloned().filter(|v| v.abs() < 10.0).collect();
    let core_rmse = (core.iter().map(|v| v * v).sum::<f64>() / core.len() as f64).sqrt();
    eprintln!("core RMSE {core_rmse:.2} m");
    assert!(
        core_rmse < 1.0,
        "height RMSE {core_rmse} m against a 2 m step"
    );
}
