//! Seed 002's multiphoto geometrically constrained matching end to end: `rig sim scene` renders
//! four photos of the block (with image noise) over a part of photo 1 that all of them see;
//! `rig dtm` runs the project with `method = "mgcm"` on three of them and on two and four, and
//! the points are compared with the simulator's true terrain (truth-dem.tif, 2 m cells) by the
//! run's own accuracy analysis, whose arithmetic has its own hand-computed test.

mod common;

use common::{dtm_json, rig, sim_scene};
use serde_json::Value;
use std::path::Path;

/// block.toml with only `photos`, method "mgcm" and `extra` in [matching.mgcm].
fn project(scene: &Path, name: &str, photos: &[u32], extra: &str) -> std::path::PathBuf {
    let text = std::fs::read_to_string(scene.join("block.toml")).unwrap();
    assert!(
        text.contains("method = \"sweep\""),
        "block.toml changed form"
    );
    let mut out = String::new();
    for (k, part) in text.split("\n[[photo]]").enumerate() {
        if k == 0 {
            out += part;
            continue;
        }
        let id: u32 = part
            .split("id = \"")
            .nth(1)
            .and_then(|s| s.split('"').next())
            .and_then(|s| s.parse().ok())
            .unwrap();
        let (photo, rest) = match part.find("\n[dem]") {
            Some(i) => part.split_at(i),
            None => (part, ""),
        };
        if photos.contains(&id) {
            out += "\n[[photo]]";
            out += photo;
        }
        out += rest;
    }
    let out = out.replace(
        "method = \"sweep\"",
        &format!("method = \"mgcm\"\n\n[matching.mgcm]\nreference = \"1\"\n{extra}\n#"),
    );
    let p = scene.join(format!("{name}.toml"));
    std::fs::write(&p, out).unwrap();
    p
}

#[test]
fn three_photos_meet_the_goals_and_four_rays_beat_two() {
    let d = tempfile::tempdir().unwrap();
    let scene = sim_scene(
        d.path(),
        &[
            "--seed",
            "11",
            "--area",
            "40,-72,51,-61",
            "--photos",
            "4",
            "--noise-dn",
            "150",
            "--truth-cell-m",
            "2",
        ],
    );
    // Three photos, the interest operator's points.
    let p3 = project(&scene, "three", &[1, 2, 3], "");
    let out = d.path().join("three");
    let v = dtm_json(&p3, &out);
    let a = &v["accuracy"];
    let m_per_px = v["m_per_px"].as_f64().unwrap();
    let hg = a["flying_height_m"].as_f64().unwrap();
    let v1 = &a["versions"][0];
    let v2 = &a["versions"][1];
    let rms = v1["rms_m"].as_f64().unwrap();
    let max = v2["max_abs_m"].as_f64().unwrap();
    let ratio = a["precision"]["rms_ratio"].as_f64().unwrap();
    let undetected = a["undetected_percent"].as_f64().unwrap();
    let (kept, selected) = (v["kept"].as_u64().unwrap(), v["selected"].as_u64().unwrap());
    eprintln!(
        "3 photos: {kept}/{selected} points kept, RMS {rms:.3} m = {:.3} px of parallax ({:.3} ‰ of {hg:.0} m), max {max:.2} m ({:.2} ‰), undetected blunders {undetected:.2} %, RMS(error/σ) {ratio:.2}",
        rms / m_per_px,
        1000.0 * rms / hg,
        1000.0 * max / hg
    );
    assert!(rms / m_per_px <= 0.1, "{:.3} px", rms / m_per_px);
    assert!(1000.0 * max / hg < 1.0, "max {max:.2} m");
    assert!(undetected < 0.5, "{undetected:.2} % undetected");
    assert!((0.8..=1.25).contains(&ratio), "RMS(error/σ) {ratio:.2}");
    assert!(kept * 10 >= selected * 8, "{kept} of {selected} kept");
    assert_eq!(v["warnings"], serde_json::json!([]), "a good run warns");
    // The outputs, as the sweep's, and the points with their reasons.
    for f in [
        "dem.tif",
        "quality.tif",
        "points.csv",
        "points.ply",
        "points.las",
        "accuracy.txt",
        "accuracy.json",
        "report.json",
        "report.html",
    ] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    let csv = std::fs::read_to_string(out.join("points.csv")).unwrap();
    let mut lines = csv.lines();
    assert!(lines
        .next()
        .unwrap()
        .starts_with("id,col,row,x,y,z,sigma_x"));
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len() as u64, selected);
    for r in &rows {
        assert!(
            r.contains(",kept,") || (r.contains(",refused,\"") && !r.contains(",refused,\"\"")),
            "a refused point without its reason: {r}"
        );
    }
    let table = std::fs::read_to_string(out.join("accuracy.txt")).unwrap();
    assert!(
        table.contains("1 without bias, without blunders"),
        "{table}"
    );
    // More rays: the same grid of points from photo 1 with photo 2 alone, and with 2, 3, 4.
    let mut rmse = Vec::new();
    for (name, photos) in [("two", &[1u32, 2][..]), ("four", &[1, 2, 3, 4][..])] {
        let p = project(&scene, name, photos, "points = \"grid\"");
        let v = dtm_json(&p, &d.path().join(name));
        let r = v["accuracy"]["versions"][1]["rms_m"].as_f64().unwrap();
        let u = v["accuracy"]["undetected"].as_u64().unwrap();
        eprintln!("{name} photos: RMS {r:.3} m with the blunders, {u} undetected");
        rmse.push(r);
    }
    assert!(
        rmse[1] <= 0.75 * rmse[0],
        "{rmse:?}: 4 rays cut less than 25 %"
    );
    // Heights that miss the top of the terrain: the run says so, and --strict fails it.
    let text = std::fs::read_to_string(&p3).unwrap();
    let line = text
        .lines()
        .find(|l| l.starts_with("heights = ["))
        .expect("block.toml gives [dem] heights");
    let hs: Vec<f64> = line
        .trim_start_matches("heights = [")
        .trim_end_matches(']')
        .split(',')
        .map(|v| v.trim().parse().unwrap())
        .collect();
    let cut = format!("heights = [{}, {}]", hs[0], 0.5 * (hs[0] + hs[1]));
    let low = scene.join("low.toml");
    std::fs::write(&low, text.replace(line, &cut)).unwrap();
    let o = rig()
        .arg("dtm")
        .arg(&low)
        .args(["--json", "--strict", "--out"])
        .arg(d.path().join("low"))
        .output()
        .unwrap();
    let v: Value = serde_json::from_slice(&o.stdout)
        .unwrap_or_else(|e| panic!("{cut}: {e}: {}", String::from_utf8_lossy(&o.stderr)));
    let w = v["warnings"].to_string();
    assert!(w.contains("widen [dem] heights"), "{cut}: {w}");
    assert_eq!(o.status.code(), Some(rig::exit::DOUBTFUL), "{cut}: {w}");
}
