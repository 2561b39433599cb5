//! RPCs as vendors ship them (tests/data/rpc, their sources in its README.md), read by the
//! rig and checked against GDAL: `gdalinfo` must show the same 92 numbers, and
//! `gdaltransform -rpc` must project 100 ground points to the same pixels (to 1e-6 px) and
//! bring those pixels back to the same ground at their heights.
//!
//! Conventions: the rig's [`Rpc::project`] gives RPC00B's (sample, line), (0, 0) at the
//! centre of the top-left pixel; GDAL's pixel/line put 0 at the top-left corner of the
//! image, so GDAL pixel = sample + 0.5 and GDAL line = line + 0.5. GDAL finds an image's
//! RPCs beside it under its own names: `foo.RPB`, `foo_rpc.txt`, or for an Airbus tile
//! `IMG_<id>_R1C1.TIF` the product's `RPC_<id>.XML`; a 16 × 16 TIFF stands in for each image.

mod common;

use rig::geometry::{LonLatH, Rpc};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Each real file: its name in tests/data/rpc, the image GDAL opens for it and the name
/// GDAL looks for beside that image.
const CASES: [(&str, &str, &str); 5] = [
    ("md_dg.RPB", "md_dg.tif", "md_dg.RPB"),
    (
        "md_ge_rgb_0010000_rpc.txt",
        "md_ge_rgb_0010000.tif",
        "md_ge_rgb_0010000_rpc.txt",
    ),
    ("rpc_IKONOS.txt", "ikonos.tif", "ikonos_rpc.txt"),
    (
        "RPC_PHR1B_P_201709281038393_SEN_PRG_FC_178609-001.XML",
        "IMG_PHR1B_P_201709281038393_SEN_PRG_FC_178609-001_R1C1.TIF",
        "RPC_PHR1B_P_201709281038393_SEN_PRG_FC_178609-001.XML",
    ),
    ("rpc_SPOT6.xml", "IMG_SPOT6_R1C1.TIF", "RPC_SPOT6.XML"),
];

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/rpc")
        .join(name)
}

/// The image of a case in `dir`, with the RPC file beside it under GDAL's name.
fn lay_out(dir: &Path, (file, image, beside): (&str, &str, &str)) -> PathBuf {
    let img = dir.join(image);
    rig::digitise::output::write_tiff16(&img, 16, 16, &[1000u16; 256]).unwrap();
    std::fs::copy(data(file), dir.join(beside)).unwrap();
    img
}

#[test]
fn every_real_file_is_read_directly_and_from_beside_its_image() {
    let d = tempfile::tempdir().unwrap();
    for case in CASES {
        let direct = Rpc::read(&data(case.0)).unwrap_or_else(|e| panic!("{e}"));
        let img = lay_out(d.path(), case);
        assert_eq!(Rpc::read(&img).unwrap(), direct, "{}", case.0);
    }
}

/// `gdaltransform -rpc` on `image` (`-i`: ground → image); GDAL's pixel → ground is iterated
/// to 1e-9 px (its default stops at 0.1 px).
fn gdaltransform(image: &Path, inverse: bool, points: &[[f64; 3]]) -> Vec<Vec<f64>> {
    let mut args = vec![
        "-rpc",
        "-to",
        "RPC_PIXEL_ERROR_THRESHOLD=1e-9",
        "-to",
        "RPC_MAX_ITERATIONS=100",
    ];
    if inverse {
        args.push("-i");
    }
    common::gdaltransform(&args, image, points)
}

/// The RPC metadata `gdalinfo` shows for `image`: key → its words.
fn gdalinfo_rpc(image: &Path) -> std::collections::BTreeMap<String, Vec<f64>> {
    let out = Command::new("gdalinfo").arg(image).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    let m: std::collections::BTreeMap<String, Vec<f64>> = text
        .lines()
        .skip_while(|l| !l.starts_with("RPC Metadata:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.trim().split_once('='))
        .map(|(k, v)| {
            // `+003754.00 pixels`: the number, not its unit.
            let nums = if k.ends_with("COEFF") {
                v.split_whitespace().map(|w| w.parse().unwrap()).collect()
            } else {
                vec![v.split_whitespace().next().unwrap().parse().unwrap()]
            };
            (k.to_string(), nums)
        })
        .collect();
    assert!(
        !m.is_empty(),
        "gdalinfo shows no RPCs for {image:?}: {text}"
    );
    m
}

#[test]
fn gdal_reads_the_same_models_and_agrees_on_100_points_each() {
    if !common::gdal_tools() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let mut report = Vec::new();
    for case in CASES {
        let rpc = Rpc::read(&data(case.0)).unwrap();
        let img = lay_out(d.path(), case);
        // The numbers: GDAL's metadata, key by key.
        let theirs = gdalinfo_rpc(&img);
        let ours = rpc.to_values();
        let keys = [
            "ERR_BIAS",
            "ERR_RAND",
            "LINE_OFF",
            "SAMP_OFF",
            "LAT_OFF",
            "LONG_OFF",
            "HEIGHT_OFF",
            "LINE_SCALE",
            "SAMP_SCALE",
            "LAT_SCALE",
            "LONG_SCALE",
            "HEIGHT_SCALE",
        ];
        for (k, key) in keys.iter().enumerate() {
            match theirs.get(*key) {
                Some(v) => assert_eq!(v[0], ours[k], "{}: {key}", case.0),
                // GDAL leaves unknown errors out; the rig says −1.
                None => assert!(k < 2 && ours[k] == -1.0, "{}: GDAL has no {key}", case.0),
            }
        }
        for (a, key) in [
            "LINE_NUM_COEFF",
            "LINE_DEN_COEFF",
            "SAMP_NUM_COEFF",
            "SAMP_DEN_COEFF",
        ]
        .iter()
        .enumerate()
        {
            assert_eq!(
                theirs[*key][..],
                ours[12 + 20 * a..32 + 20 * a],
                "{}: {key}",
                case.0
            );
        }
        // 100 ground points over the model's ground domain and height range.
        let ground: Vec<LonLatH> = (0..100)
            .map(|k| {
                let (i, j) = ((k % 10) as f64, (k / 10) as f64);
                LonLatH {
                    lon: rpc.long_off + rpc.long_scale * (-0.8 + 0.16 * i + 0.01 * j),
                    lat: rpc.lat_off + rpc.lat_scale * (-0.8 + 0.16 * j - 0.007 * i),
                    h: rpc.height_off + rpc.height_scale * (((k * 37) % 11) as f64 / 5.0 - 1.0),
                }
            })
            .collect();
        let input: Vec<[f64; 3]> = ground.iter().map(|g| [g.lon, g.lat, g.h]).collect();
        let pix = gdaltransform(&img, true, &input);
        assert_eq!(pix.len(), 100, "{}", case.0);
        let mut worst_px: f64 = 0.0;
        for (g, p) in ground.iter().zip(&pix) {
            let (s, l) = rpc.project(*g).unwrap();
            // GDAL's pixel/line: corner origin.
            worst_px = worst_px
                .max((s + 0.5 - p[0]).abs())
                .max((l + 0.5 - p[1]).abs());
        }
        // And back: GDAL's pixels at their heights to ground, by both.
        let input: Vec<[f64; 3]> = pix.iter().map(|p| [p[0], p[1], p[2]]).collect();
        let back = gdaltransform(&img, false, &input);
        assert_eq!(back.len(), 100, "{}", case.0);
        let metres = |a: LonLatH, lon: f64, lat: f64| {
            let m = 111_319.5;
            ((a.lon - lon) * m * a.lat.to_radians().cos()).hypot((a.lat - lat) * m)
        };
        let (mut worst_m, mut worst_deg, mut gdal_m): (f64, f64, f64) = (0.0, 0.0, 0.0);
        for ((p, b), g) in pix.iter().zip(&back).zip(&ground) {
            let ours = rpc
                .locate(p[0] - 0.5, p[1] - 0.5, p[2])
                .unwrap_or_else(|e| panic!("{}: the rig finds no ground at {p:?}: {e}", case.0));
            worst_m = worst_m.max(metres(ours, b[0], b[1]));
            worst_deg = worst_deg
                .max((ours.lon - b[0]).abs())
                .max((ours.lat - b[1]).abs());
            gdal_m = gdal_m.max(metres(*g, b[0], b[1]));
        }
        let line = format!(
            "{}: ground → image {worst_px:.1e} px; image → ground {worst_m:.1e} m ({worst_deg:.1e}°); GDAL's own round trip {gdal_m:.1e} m",
            case.0
        );
        eprintln!("{line}");
        report.push((case.0, worst_px, worst_m, line));
    }
    for (name, px, m, line) in report {
        assert!(px <= 1e-6, "{name}: {line}");
        assert!(m <= 1e-6, "{name}: {line}");
    }
}
