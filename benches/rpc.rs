//! RPC evaluation against the rigorous line-scanner model it was fitted to (issue 20): points
//! per second of ground → image through (a) the rigorous model (Newton on the scan plane,
//! about four iterations of two attitude and orbit evaluations each), (b) the RPC00B polynomials
//! alone on WGS 84 coordinates, and (c) the RPC sensor as the matchers use it (the project's
//! UTM converted to WGS 84 by proj4rs, then the polynomials). Reported as points per second and
//! as ratios to the rigorous model, measured in the same run.
//!
//! `cargo bench --bench rpc`

use rig::coords::PixelXY;
use rig::geometry::rpc::{fit_rpc, FitGrid};
use rig::geometry::{Crs, Geographic, Pushbroom, RpcSensor, Sensor};
use std::hint::black_box;
use std::time::Instant;

fn view() -> Pushbroom {
    let tilt = 20f64.to_radians();
    Pushbroom {
        columns: 6000,
        lines: 6000,
        line_period_s: 10.0 / 6600.0,
        focal_px: 83_000.0,
        principal_col: 3000.0,
        tilt_across: tilt,
        tilt_along: 0.0,
        position: [
            // Flown south, looking right (west) by the tilt: the track lies east of the scene.
            [740_000.0 + 830_000.0 * tilt.tan(), 900.0, 0.3],
            [4_050_000.0, -6540.0, 0.1],
            [830_000.0, -5.0, 0.0],
        ],
        attitude: [[1e-4, 2e-6, 0.0], [-2e-4, 1e-6, 0.0], [1e-3, 0.0, 0.0]],
    }
}

/// The fastest of `runs` timings of `f` over all points, points per second.
fn rate(points: usize, runs: usize, mut f: impl FnMut() -> f64) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..runs {
        let t = Instant::now();
        black_box(f());
        best = best.min(t.elapsed().as_secs_f64());
    }
    points as f64 / best
}

fn main() {
    let s = view();
    let geo = Geographic::new(Crs::Epsg(32616)).unwrap();
    let heights = [0.0, 2000.0];
    let (rpc, fit) = fit_rpc(&s, &geo, heights, FitGrid::default()).unwrap();
    let sensor = RpcSensor {
        rpc: rpc.clone(),
        geo: geo.clone(),
        width: 6000,
        height: 6000,
    };
    let n = 100_000;
    let ground: Vec<_> = (0..n)
        .map(|k| {
            let k = k as f64;
            let frac = |v: f64| v - v.floor();
            let q = PixelXY::new(
                frac(k * 0.754_877_7) * 6000.0,
                frac(k * 0.569_840_3) * 6000.0,
            );
            s.image_to_ground(q, frac(k * 0.618_034) * 2000.0).unwrap()
        })
        .collect();
    let lonlat: Vec<_> = ground.iter().map(|g| geo.to_lonlat(*g).unwrap()).collect();
    let rigorous = rate(n, 5, || {
        ground
            .iter()
            .map(|g| s.ground_to_image(*g).map_or(0.0, |q| q.col))
            .sum()
    });
    let polys = rate(n, 5, || {
        lonlat
            .iter()
            .map(|l| rpc.project(*l).map_or(0.0, |q| q.0))
            .sum()
    });
    let through = rate(n, 5, || {
        ground
            .iter()
            .map(|g| sensor.ground_to_image(*g).map_or(0.0, |q| q.col))
            .sum()
    });
    println!(
        "RPC fitted to the rigorous model: {:.1e} px RMS at the check points",
        fit.check_rms_px
    );
    println!("ground → image, {n} points, one thread (best of 5):");
    println!(
        "  rigorous line scanner:        {:>12.0} points/s  (1.00)",
        rigorous
    );
    println!(
        "  RPC00B polynomials (WGS 84):  {:>12.0} points/s  ({:.2} × the rigorous)",
        polys,
        polys / rigorous
    );
    println!(
        "  RPC sensor (UTM → WGS 84 → RPC): {:>9.0} points/s  ({:.2} × the rigorous)",
        through,
        through / rigorous
    );
}
