//! Film at its real size: a pair scanned four times finer gives the model the coarse scan
//! gives, matched at the pyramid level `[dem] photo_level = "auto"` picks, read strip by strip.
//!
//! The validation scene `lidar-banks` (a renderer not ours: 600 px photos of 0.83 m on the
//! ground, 1 m posts) is scanned again at a quarter of its pixel (2 400 px photos, bilinear,
//! 16-bit strips, `pixel_mm` / 4, the points' pixels moved to the finer grid). "auto" must read
//! it at level 1 (0.41 m pixels: two a post, the coarsest that keeps them, and 1 200 px a side),
//! say so in report.json, and give a model whose error against the scene's true DEM is that of
//! the 600 px pair's (within a quarter) over as many of its posts (within 3 %). The level's
//! own arithmetic is checked in `photos::level_for`'s unit test.

use std::path::Path;
use std::process::Command;

const SCENE: &str = "tests/data/validation/scenes/lidar-banks";
const K: usize = 4;

/// The scene's project with photos 1 and 2 alone, `pixel_mm` divided by `k`.
fn project(k: usize) -> String {
    let text = std::fs::read_to_string(Path::new(SCENE).join("project.toml")).unwrap();
    let mut out = String::new();
    let mut skip = false;
    for line in text.lines() {
        if line.starts_with('[') {
            skip = false;
        }
        if line.starts_with("id = \"3\"") || line.starts_with("id = \"4\"") {
            // Drop the [[photo]] header written just before and the rest of the block.
            let at = out.trim_end().rfind("[[photo]]").unwrap();
            out.truncate(at);
            skip = true;
            continue;
        }
        if skip {
            continue;
        }
        if let Some(v) = line.strip_prefix("pixel_mm = ") {
            let v: f64 = v.split_whitespace().next().unwrap().parse().unwrap();
            out.push_str(&format!("pixel_mm = {}\n", v / k as f64));
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

/// The image upsampled `k` times a side, bilinear with pixel c over [c, c + 1) on both grids
/// (the fine pixel i samples the coarse at (i + 0.5)/k − 0.5, edges clamped), as 16-bit strips.
fn upsample(src: &Path, dst: &Path, k: usize) {
    let a = rig::image::load_grey(src, 1 << 30).unwrap();
    let (w, h) = (a.width * k, a.height * k);
    let axis = |i: usize, n: usize| {
        let u = ((i as f64 + 0.5) / k as f64 - 0.5).clamp(0.0, (n - 1) as f64);
        let i0 = (u as usize).min(n - 2);
        (i0, u - i0 as f64)
    };
    let mut px = vec![0u16; w * h];
    for r in 0..h {
        let (j, fy) = axis(r, a.height);
        for c in 0..w {
            let (i, fx) = axis(c, a.width);
            let v = |i: usize, j: usize| a.data[j * a.width + i] as f64;
            let top = v(i, j) * (1.0 - fx) + v(i + 1, j) * fx;
            let bot = v(i, j + 1) * (1.0 - fx) + v(i + 1, j + 1) * fx;
            px[r * w + c] = (top * (1.0 - fy) + bot * fy).round().clamp(0.0, 65535.0) as u16;
        }
    }
    let mut enc = tiff::encoder::TiffEncoder::new(std::fs::File::create(dst).unwrap()).unwrap();
    let mut img = enc
        .new_image::<tiff::encoder::colortype::Gray16>(w as u32, h as u32)
        .unwrap();
    img.rows_per_strip(64).unwrap();
    img.write_data(&px).unwrap();
}

/// The scene's points of photos 1 and 2, their pixels moved to a grid `k` times finer (centre
/// at c + ½ both ways: c → (c + ½)·k − ½ in the CSV's integer-centred pixels).
fn points(k: usize) -> String {
    let text = std::fs::read_to_string(Path::new(SCENE).join("points.csv")).unwrap();
    let mut lines = text.lines();
    let head = lines.next().unwrap();
    let cols: Vec<&str> = head.split(',').collect();
    let at = |n: &str| cols.iter().position(|c| *c == n).unwrap();
    let (pc, cc, rc) = (at("photo"), at("col"), at("row"));
    let mut out = format!("{head}\n");
    for l in lines {
        let mut f: Vec<String> = l.split(',').map(String::from).collect();
        if !(f[pc] == "1" || f[pc] == "2") {
            continue;
        }
        for c in [cc, rc] {
            let v: f64 = f[c].parse().unwrap();
            f[c] = format!("{}", (v + 0.5) * k as f64 - 0.5);
        }
        out.push_str(&f.join(","));
        out.push('\n');
    }
    out
}

fn dtm(dir: &Path) -> serde_json::Value {
    let out = dir.join("out");
    let r = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["dtm"])
        .arg(dir.join("project.toml"))
        .arg("--out")
        .arg(&out)
        .arg("--json")
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
}

#[test]
fn a_pair_scanned_four_times_finer_gives_the_same_model_at_the_level_auto_picks() {
    let tmp = tempfile::tempdir().unwrap();
    let (small, large) = (tmp.path().join("small"), tmp.path().join("large"));
    for (d, k) in [(&small, 1), (&large, K)] {
        std::fs::create_dir(d).unwrap();
        std::fs::write(d.join("project.toml"), project(k)).unwrap();
        std::fs::write(d.join("points.csv"), points(k)).unwrap();
        std::fs::copy(
            Path::new(SCENE).join("truth_dem.tif"),
            d.join("truth_dem.tif"),
        )
        .unwrap();
        for n in ["photo_1.tif", "photo_2.tif"] {
            if k == 1 {
                std::fs::copy(Path::new(SCENE).join(n), d.join(n)).unwrap();
            } else {
                upsample(&Path::new(SCENE).join(n), &d.join(n), k);
            }
        }
    }
    let (a, b) = (dtm(&small), dtm(&large));
    let read = |r: &serde_json::Value| -> Vec<(u64, u64)> {
        r["photos_read"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| {
                (
                    p["factor"].as_u64().unwrap(),
                    p["size"][0].as_u64().unwrap(),
                )
            })
            .collect()
    };
    assert_eq!(read(&a), vec![(1, 600), (1, 600)], "{}", a["photos_read"]);
    assert_eq!(read(&b), vec![(2, 1200), (2, 1200)], "{}", b["photos_read"]);
    let rmse = |r: &serde_json::Value| r["comparison"]["rmse_m"].as_f64().unwrap();
    let nodes = |r: &serde_json::Value| r["comparison"]["nodes"].as_f64().unwrap();
    eprintln!(
        "600 px: RMSE {:.3} m over {} posts; 2 400 px read at 1 200: RMSE {:.3} m over {} posts",
        rmse(&a),
        nodes(&a),
        rmse(&b),
        nodes(&b)
    );
    assert!(rmse(&b) <= 1.25 * rmse(&a), "{} vs {}", rmse(&b), rmse(&a));
    assert!(
        nodes(&b) >= 0.97 * nodes(&a),
        "{} vs {}",
        nodes(&b),
        nodes(&a)
    );
    // As scanned (level 0) the two 2 400² photos take 43 MiB as grey values: under a limit of
    // 30 MiB the run is refused before a pixel is read, with the figure and the way out;
    // "auto" fits (2 × 5.5 MiB).
    let text = std::fs::read_to_string(large.join("project.toml")).unwrap();
    let level0 = text.replace("[dem]\n", "[dem]\nphoto_level = 0\n");
    assert_ne!(level0, text);
    std::fs::write(large.join("level0.toml"), level0).unwrap();
    let r = Command::new(env!("CARGO_BIN_EXE_rig"))
        .arg("dtm")
        .arg(large.join("level0.toml"))
        .args(["--max-memory", "30", "--out"])
        .arg(large.join("out0"))
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success());
    assert!(
        e.contains("43 MiB") && e.contains("the limit is 30 MiB") && e.contains("photo_level"),
        "{e}"
    );
    assert!(!e.contains("reading photos"), "refused after reading: {e}");
}
