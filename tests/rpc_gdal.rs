//! The rig's RPCs as GDAL reads them (issue 20's goal: `gdaltransform -rpc` on the rig's
//! `_RPC.TXT` agrees with the rig's own evaluation to 1e-3 px). GDAL is the independent
//! evaluator: its own term order, its own normalisation, its own pixel convention.

mod common;

use rig::geometry::rpc::{fit_rpc, FitGrid};
use rig::geometry::{Crs, Geographic, LonLatH, Pushbroom, Rpc, RpcSensor, Sensor};
use std::process::Command;

/// A tilted SPOT-like view with a drifting attitude (ground pixel about 10 m), flown north:
/// looking 15° left (west) and 5° forward (north), it passes east of and behind (south of)
/// the ground it sees.
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
            [700_000.0 - 830_000.0 * tilt.tan(), 1200.0, 0.3],
            [
                4_060_000.0 - 830_000.0 * 5f64.to_radians().tan(),
                6500.0,
                -0.1,
            ],
            [830_000.0, 3.0, 0.0],
        ],
        attitude: [[2e-4, 1e-6, 0.0], [1e-4, -2e-6, 0.0], [-1e-3, 0.0, 0.0]],
    }
}

/// `gdaltransform -rpc` (`-i`: ground → image), GDAL's pixel → ground iterated to 1e-7 px
/// (its default stops at 0.1 px).
fn gdaltransform(image: &std::path::Path, inverse: bool, points: &[[f64; 3]]) -> Vec<Vec<f64>> {
    let mut args = vec!["-rpc", "-to", "RPC_PIXEL_ERROR_THRESHOLD=1e-7"];
    if inverse {
        args.push("-i");
    }
    common::gdaltransform(&args, image, points)
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
    let input: Vec<[f64; 3]> = lonlat.iter().map(|l| [l.lon, l.lat, l.h]).collect();
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
    let input: Vec<[f64; 3]> = pix.iter().map(|(q, z)| [q.col, q.row, *z]).collect();
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

/// The RPCs in a TIFF's RPCCoefficientTag (50844), both ways: GDAL reads the tag the rig
/// writes (gdalinfo's RPC metadata, with no `_RPC.TXT` beside the image), and the rig reads the
/// tag GDAL writes (gdal_translate of an image whose RPCs are in its `_RPC.TXT`).
#[test]
fn the_tiff_rpc_tag_is_read_and_written_as_gdal_does() {
    let s = view();
    let geo = Geographic::new(Crs::Epsg(32616)).unwrap();
    let (rpc, _) = fit_rpc(&s, &geo, [100.0, 1500.0], FitGrid::default()).unwrap();
    let d = tempfile::tempdir().unwrap();
    let tagged = d.path().join("tagged.tif");
    let px = vec![1000u16; 16 * 16];
    rig::digitise::output::write_tiff16_tagged(
        &tagged,
        16,
        16,
        &px,
        &[(rig::geometry::rpc::TIFF_TAG, &rpc.to_values())],
    )
    .unwrap();
    assert!(!Rpc::txt_path(&tagged).exists());
    assert_eq!(Rpc::read_tiff_tag(&tagged).unwrap(), rpc);
    // An image without the tag is refused with the tag named.
    let plain = d.path().join("plain.tif");
    rig::digitise::output::write_tiff16(&plain, 16, 16, &px).unwrap();
    let e = Rpc::read_tiff_tag(&plain).unwrap_err().to_string();
    assert!(e.contains("50844") && e.contains("plain.tif"), "{e}");
    if !common::gdal_tools() {
        return;
    }
    let out = Command::new("gdalinfo").arg(&tagged).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let values: std::collections::BTreeMap<String, String> = text
        .lines()
        .skip_while(|l| !l.starts_with("RPC Metadata:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.trim().split_once('=').map(|(k, v)| (k.into(), v.into())))
        .collect();
    let num = |k: &str| -> f64 {
        values
            .get(k)
            .unwrap_or_else(|| panic!("gdalinfo shows no {k}: {text}"))
            .trim()
            .parse()
            .unwrap()
    };
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * a.abs().max(b.abs()).max(1.0);
    assert!(close(num("LINE_OFF"), rpc.line_off), "{text}");
    assert!(close(num("SAMP_SCALE"), rpc.samp_scale), "{text}");
    assert!(close(num("LAT_OFF"), rpc.lat_off), "{text}");
    assert!(close(num("LONG_SCALE"), rpc.long_scale), "{text}");
    let coeffs = |k: &str| -> Vec<f64> {
        values[k]
            .split_whitespace()
            .map(|w| w.parse().unwrap())
            .collect()
    };
    for (k, want) in [
        ("LINE_NUM_COEFF", &rpc.line_num),
        ("SAMP_DEN_COEFF", &rpc.samp_den),
    ] {
        let got = coeffs(k);
        assert_eq!(got.len(), 20, "{k}: {got:?}");
        for (g, w) in got.iter().zip(want.iter()) {
            assert!(close(*g, *w), "{k}: {got:?} against {want:?}");
        }
    }
    // GDAL writes the tag: an image with an _RPC.TXT translated to a new GeoTIFF.
    rpc.write_beside(&plain).unwrap();
    let by_gdal = d.path().join("by_gdal.tif");
    let st = Command::new("gdal_translate")
        .args(["-q"])
        .arg(&plain)
        .arg(&by_gdal)
        .status()
        .unwrap();
    assert!(st.success());
    assert!(
        !Rpc::txt_path(&by_gdal).exists(),
        "GDAL wrote an _RPC.TXT: the tag would not be tested"
    );
    let theirs = Rpc::read_tiff_tag(&by_gdal).unwrap();
    let (a, b) = (
        RpcSensor {
            rpc: rpc.clone(),
            geo: geo.clone(),
            width: 2000,
            height: 2400,
        },
        RpcSensor {
            rpc: theirs,
            geo,
            width: 2000,
            height: 2400,
        },
    );
    let mut worst: f64 = 0.0;
    for i in 0..10 {
        for j in 0..10 {
            let q = rig::coords::PixelXY::new(50.0 + 210.0 * i as f64, 40.0 + 250.0 * j as f64);
            let g = s.image_to_ground(q, 200.0 + 100.0 * j as f64).unwrap();
            let (p, r) = (a.ground_to_image(g).unwrap(), b.ground_to_image(g).unwrap());
            worst = worst.max(p.dist(r));
        }
    }
    eprintln!("the RPCs through GDAL's tag project within {worst:.2e} px of the rig's");
    assert!(worst < 1e-6, "{worst} px");
}

/// The Orfeo Toolbox as a second, independent reader: `otbcli_ConvertSensorToGeoPoint`
/// (OTB's own RPC model, its pixel (0, 0) at the top-left pixel's centre as GDAL's RPC
/// convention) on an image with the rig's `_RPC.TXT` beside it, against the rig's image →
/// ground at height 0. OTB iterates its inverse only to a few centimetres, so the goal is a
/// tenth of a pixel. Skipped where OTB is not installed (CI installs otb-bin and sets
/// RIG_OTB=1). OTB 8.1 does not read the RPC TIFF tag, and needs an absolute path.
#[test]
fn otb_reads_the_rigs_rpc_file_and_agrees_within_a_tenth_of_a_pixel() {
    let required = std::env::var("RIG_OTB").is_ok_and(|v| v == "1");
    let app = "otbcli_ConvertSensorToGeoPoint";
    if Command::new(app).arg("-help").output().is_err() {
        assert!(!required, "RIG_OTB=1 but {app} cannot run");
        eprintln!("{app} not installed: OTB check skipped");
        return;
    }
    let s = view();
    let geo = Geographic::new(Crs::Epsg(32616)).unwrap();
    let (rpc, _) = fit_rpc(&s, &geo, [-100.0, 1500.0], FitGrid::default()).unwrap();
    let d = tempfile::tempdir().unwrap();
    let image = std::fs::canonicalize(d.path()).unwrap().join("view.tif");
    rig::digitise::output::write_tiff16(&image, 2000, 2400, &vec![1000u16; 2000 * 2400]).unwrap();
    rpc.write_beside(&image).unwrap();
    let sensor = RpcSensor {
        rpc,
        geo: geo.clone(),
        width: 2000,
        height: 2400,
    };
    let mut worst: f64 = 0.0;
    for (i, j) in [
        (10, 10),
        (1000, 1200),
        (1990, 15),
        (25, 2390),
        (1985, 2385),
        (700, 1900),
    ] {
        let out = Command::new(app)
            .arg("-in")
            .arg(&image)
            .args(["-input.idx", &i.to_string(), "-input.idy", &j.to_string()])
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout).to_string()
            + &String::from_utf8_lossy(&out.stderr);
        let value = |key: &str| -> f64 {
            text.lines()
                .find_map(|l| l.strip_prefix(key))
                .and_then(|v| v.trim().parse().ok())
                .unwrap_or_else(|| panic!("{app} gave no {key}: {text}"))
        };
        let theirs = geo
            .to_ground(LonLatH {
                lon: value("output.idx:"),
                lat: value("output.idy:"),
                h: 0.0,
            })
            .unwrap();
        let ours = sensor
            .image_to_ground(
                rig::coords::PixelXY::new(i as f64 + 0.5, j as f64 + 0.5),
                0.0,
            )
            .unwrap();
        worst = worst.max((ours.x - theirs.x).hypot(ours.y - theirs.y));
    }
    eprintln!(
        "OTB's image → ground against the rig's: {worst:.3} m at most (pixels of about 10 m)"
    );
    assert!(worst <= 1.0, "{worst} m");
}
