//! The rig's RPCs as GDAL reads them (issue 20's goal: `gdaltransform -rpc` on the rig's
//! `_RPC.TXT` agrees with the rig's own evaluation to 1e-3 px). GDAL is the independent
//! evaluator: its own term order, its own normalisation, its own pixel convention.

mod common;

use rig::geometry::rpc::{fit_rpc, FitGrid};
use rig::geometry::{Crs, Geographic, LonLatH, Pushbroom, Rpc, RpcSensor, Sensor};
use std::io::Write;
use std::process::{Command, Stdio};

/// A tilted SPOT-like view with a drifting attitude (ground pixel about 10 m).
fn view() -> Pushbroom {
    let tilt = (-15f64).to_radians();
    Pushbroom {
        columns: 2000,
        lines: 2400,
        line_period_s: 10.0 / 6600.0,
        focal_px: 83_000.0 / tilt.cos(),
        principal_col: 1000.0,
        tilt_across: tilt,
        tilt_along: 5f64.to_radians(),
        position: [
            [700_000.0 - 830_000.0 * 5f64.to_radians().tan(), 1200.0, 0.3],
            [4_060_000.0 + 830_000.0 * tilt.tan(), 6500.0, -0.1],
            [830_000.0, 3.0, 0.0],
        ],
        attitude: [[2e-4, 1e-6, 0.0], [1e-4, -2e-6, 0.0], [-1e-3, 0.0, 0.0]],
    }
}

fn gdaltransform(image: &std::path::Path, inverse: bool, input: &str) -> Vec<[f64; 3]> {
    let mut cmd = Command::new("gdaltransform");
    // GDAL solves pixel → ground iteratively to 0.1 px by default: tighten it to compare.
    cmd.args(["-rpc", "-to", "RPC_PIXEL_ERROR_THRESHOLD=1e-7"]);
    if inverse {
        cmd.arg("-i");
    }
    let mut child = cmd
        .arg(image)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(input.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|w| w.parse().unwrap()).collect();
            [v[0], v[1], v[2]]
        })
        .collect()
}

#[test]
fn gdaltransform_agrees_with_the_rigs_rpc_evaluation() {
    if !common::gdal_tools() {
        return;
    }
    let s = view();
    s.check().unwrap();
    let geo = Geographic::new(Crs::Epsg(32616)).unwrap();
    let heights = [100.0, 1500.0];
    let (rpc, report) = fit_rpc(&s, &geo, heights, FitGrid::default()).unwrap();
    eprintln!("fit: {report:?}");
    let d = tempfile::tempdir().unwrap();
    let image = d.path().join("view.tif");
    image::GrayImage::new(16, 16).save(&image).unwrap();
    let txt = rpc.write_beside(&image).unwrap();
    assert_eq!(Rpc::read_beside(&image).unwrap(), rpc, "{}", txt.display());
    let sensor = RpcSensor {
        rpc,
        geo: geo.clone(),
        width: 2000,
        height: 2400,
    };
    // Ground points over the image and the heights, as WGS 84 for GDAL.
    let mut ground = Vec::new();
    for i in 0..15 {
        for j in 0..15 {
            let q = rig::coords::PixelXY::new(20.0 + 131.0 * i as f64, 10.0 + 160.0 * j as f64);
            let z = heights[0] + (heights[1] - heights[0]) * ((i * 7 + j * 3) % 11) as f64 / 10.0;
            ground.push((s.image_to_ground(q, z).unwrap(), z));
        }
    }
    let lonlat: Vec<LonLatH> = ground
        .iter()
        .map(|(g, _)| geo.to_lonlat(*g).unwrap())
        .collect();
    let input: String = lonlat
        .iter()
        .map(|l| format!("{:.12} {:.12} {}\n", l.lon, l.lat, l.h))
        .collect();
    let gdal = gdaltransform(&image, true, &input);
    assert_eq!(gdal.len(), ground.len());
    let mut worst: f64 = 0.0;
    for ((g, _), v) in ground.iter().zip(&gdal) {
        // GDAL's pixel/line have the corner origin, as the core's.
        let q = sensor.ground_to_image(*g).unwrap();
        worst = worst.max((q.col - v[0]).abs()).max((q.row - v[1]).abs());
    }
    eprintln!("ground → image: the rig and gdaltransform -rpc -i differ by at most {worst:.2e} px");
    assert!(worst <= 1e-3, "{worst} px");
    // And the other way: pixel and height → longitude, latitude.
    let pix: Vec<(rig::coords::PixelXY, f64)> = ground
        .iter()
        .map(|(g, z)| (sensor.ground_to_image(*g).unwrap(), *z))
        .collect();
    let input: String = pix
        .iter()
        .map(|(q, z)| format!("{} {} {z}\n", q.col, q.row))
        .collect();
    let gdal = gdaltransform(&image, false, &input);
    let mut worst_m: f64 = 0.0;
    for ((q, z), v) in pix.iter().zip(&gdal) {
        let g = sensor.image_to_ground(*q, *z).unwrap();
        let back = geo
            .to_ground(LonLatH {
                lon: v[0],
                lat: v[1],
                h: *z,
            })
            .unwrap();
        worst_m = worst_m.max((g.x - back.x).hypot(g.y - back.y));
    }
    eprintln!("image → ground: the rig and gdaltransform -rpc differ by at most {worst_m:.2e} m");
    assert!(worst_m <= 0.01, "{worst_m} m");
}
