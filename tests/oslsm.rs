//! Seed 001's object-space least-squares matching end to end: `rig sim scene` renders three
//! photos of the block with planted radiometry (gains 1, 1.2 and 0.85, offsets 0, −3000 and
//! +4000 grey values) and image noise, and writes the true terrain (truth-dem.tif) and the
//! true reflectance (truth-reflectance.tif); `rig dtm` runs the project with
//! `method = "oslsm"`, once from the sweep's coarse model and once from a coarse model up to
//! 3 px of parallax off; the heights, gains and reflectance are compared with the simulator's.

mod common;

use common::{dtm_json, rig, sim_scene};
use rig::matching::products::files::{read_geotiff, write_geotiff};
use serde_json::Value;
use std::path::{Path, PathBuf};

const GAINS: [f64; 3] = [1.0, 1.2, 0.85];
const OFFSETS: [f64; 3] = [0.0, -3000.0, 4000.0];

/// block.toml with method "oslsm", photo 1 the reference, and `extra` in [matching.oslsm].
fn project(scene: &Path, name: &str, extra: &str) -> PathBuf {
    let text = std::fs::read_to_string(scene.join("block.toml")).unwrap();
    assert!(
        text.contains("method = \"sweep\""),
        "block.toml changed form"
    );
    let out = text.replace(
        "method = \"sweep\"",
        &format!("method = \"oslsm\"\n\n[matching.oslsm]\nreference = \"1\"\n{extra}\n#"),
    );
    let p = scene.join(format!("{name}.toml"));
    std::fs::write(&p, out).unwrap();
    p
}

/// Pearson's correlation of two series.
fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        ab += (x - ma) * (y - mb);
        aa += (x - ma).powi(2);
        bb += (y - mb).powi(2);
    }
    ab / (aa * bb).sqrt()
}

/// The run's heights, gains, offsets, reflectance and σ against the simulator's truth.
fn check_goals(what: &str, v: &Value, out: &Path, scene: &Path) -> f64 {
    let m_per_px = v["m_per_px"].as_f64().unwrap();
    let rmse = v["comparison"]["rmse_m"].as_f64().unwrap();
    let nodes = v["comparison"]["nodes"].as_u64().unwrap();
    let coarse = v["coarse_comparison"]["rmse_m"].as_f64().unwrap();
    let ratio = v["sigma_vs_reference"]["ratio"].as_f64().unwrap();
    eprintln!(
        "{what}: coarse RMSE {coarse:.3} m ({:.2} px) → {rmse:.3} m = {:.3} px of parallax over {nodes} posts; RMS(error/σ) {ratio:.2}",
        coarse / m_per_px,
        rmse / m_per_px
    );
    assert!(rmse / m_per_px <= 0.1, "{what}: {:.3} px", rmse / m_per_px);
    // Since the sweep takes its windows' averaging out of its nodes (src/matching/accuracy/averaging.rs)
    // its model is the better one on this block (0.05 against 0.08 px): the refinement must
    // not lose what its start had by more than half again (open in issue 37).
    assert!(rmse < 1.8 * coarse, "{what}: worse than the coarse model");
    assert!(nodes > 2000, "{what}: only {nodes} posts refined");
    assert!(
        (0.7..=1.3).contains(&ratio),
        "{what}: RMS(error/σ) {ratio:.2}"
    );
    // The gains and offsets against photo 1's (the datum): gₖ/g₁ and oₖ − (gₖ/g₁)·o₁.
    let range = 60_000.0 * (0.88 - 0.05);
    for (k, r) in v["radiometry"].as_array().unwrap().iter().enumerate() {
        let n = k + 1;
        let want_gain = GAINS[n] / GAINS[0];
        let want_offset = OFFSETS[n] - want_gain * OFFSETS[0];
        let gain = r["gain_median"].as_f64().unwrap();
        let offset = r["offset_median"].as_f64().unwrap();
        eprintln!(
            "{what}: photo {}: gain {gain:.4} (patches {:.4} … {:.4}) for {want_gain}, offset {offset:.0} for {want_offset}",
            n + 1,
            r["gain_min"].as_f64().unwrap(),
            r["gain_max"].as_f64().unwrap()
        );
        assert!(
            (gain - want_gain).abs() < 0.01 * want_gain,
            "{what}: gain {gain}"
        );
        assert!(
            (offset - want_offset).abs() < 0.01 * range,
            "{what}: offset {offset}"
        );
    }
    // The reflectance, against the truth at each groundel's centre.
    let refl = read_geotiff(&out.join("reflectance.tif")).unwrap();
    let truth = read_geotiff(&scene.join("truth-reflectance.tif")).unwrap();
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for r in 0..refl.rows {
        for c in 0..refl.cols {
            let d = refl.z[r * refl.cols + c];
            let [x, y] = refl.node(c, r);
            let t = truth.interpolate(x, y);
            if d.is_finite() && t.is_finite() {
                a.push(d as f64);
                b.push(t);
            }
        }
    }
    let corr = correlation(&a, &b);
    eprintln!(
        "{what}: reflectance against the truth: correlation {corr:.4} over {} groundels",
        a.len()
    );
    assert!(a.len() > 100_000, "{} groundels", a.len());
    assert!(corr >= 0.98, "{what}: reflectance correlation {corr:.4}");
    assert_eq!(
        v["warnings"],
        serde_json::json!([]),
        "{what}: a good run warns"
    );
    m_per_px
}

#[test]
fn three_photos_with_planted_radiometry_meet_the_goals() {
    let d = tempfile::tempdir().unwrap();
    let list = |v: &[f64]| {
        v.iter()
            .map(|x| x.to_string())
            .collect::<Vec<_>>()
            .join(",")
    };
    let (gains, offsets) = (list(&GAINS), list(&OFFSETS));
    let scene = sim_scene(
        d.path(),
        &[
            "--seed",
            "3",
            "--area",
            "38,-70,50,-58",
            "--photos",
            "3",
            "--noise-dn",
            "150",
            "--truth-cell-m",
            "2",
            "--gains",
            &gains,
            "--offsets",
            &offsets,
        ],
    );
    // From the sweep's coarse model.
    let p = project(&scene, "oslsm", "");
    let out = d.path().join("sweep");
    let v = dtm_json(&p, &out);
    let m_per_px = check_goals("from the sweep", &v, &out, &scene);
    for f in [
        "dem.tif",
        "quality.tif",
        "reflectance.tif",
        "convergence.png",
        "ortho.tif",
        "report.json",
        "report.html",
        "coarse/dem.tif",
        "coarse/report.json",
    ] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    // From a coarse model up to 3 px of parallax off (1.5 px RMS): the truth plus waves of
    // that amplitude.
    let mut off = read_geotiff(&scene.join("truth-dem.tif")).unwrap();
    let a = 3.0 * m_per_px;
    for r in 0..off.rows {
        for c in 0..off.cols {
            let [x, y] = off.node(c, r);
            off.z[r * off.cols + c] += (a * (x / 47.0).sin() * (y / 61.0).cos()) as f32;
        }
    }
    write_geotiff(&scene.join("off.tif"), &off, "EPSG:32616".parse().unwrap()).unwrap();
    let p = project(&scene, "off", "coarse = \"off.tif\"");
    let out = d.path().join("off");
    let v = dtm_json(&p, &out);
    let c = &v["coarse_comparison"];
    let worst = c["max_positive_m"]
        .as_f64()
        .unwrap()
        .max(-c["max_negative_m"].as_f64().unwrap());
    assert!(
        worst > 2.9 * m_per_px,
        "the coarse model is only {:.2} px off at worst",
        worst / m_per_px
    );
    check_goals("from 3 px off", &v, &out, &scene);
    assert!(
        !out.join("coarse").exists(),
        "no sweep when a file is given"
    );
    // A coarse file that is not there: refused, naming the key.
    let p = project(&scene, "missing", "coarse = \"nowhere.tif\"");
    let o = rig()
        .arg("dtm")
        .arg(&p)
        .arg("--out")
        .arg(d.path().join("missing"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("[matching.oslsm] coarse") && err.contains("nowhere.tif"),
        "{err}"
    );
}

/// Weak texture (fields with sharp borders and a faint texture inside, 300 grey values of
/// noise): the sweep's correlation windows see mostly noise and its model is off by pixels
/// of parallax; the feature route's edges, matched as strings, give the terrain within a
/// pixel. (Not everywhere: over the fault's ridge, `--area 38,-8,48,2` with heights 329-555
/// m, the coarsest level's edges mismatch too often and the route is off by 17 m RMS too:
/// see the closing note.)
#[test]
fn on_weak_texture_the_feature_route_finds_the_terrain_where_the_sweep_fails() {
    let d = tempfile::tempdir().unwrap();
    let scene = sim_scene(
        d.path(),
        &[
            "--seed",
            "3",
            "--area",
            "78,-68,88,-58",
            "--texture",
            "fields",
            "--noise-dn",
            "300",
            "--truth-cell-m",
            "2",
        ],
    );
    let text = std::fs::read_to_string(scene.join("block.toml")).unwrap();
    let sweep = scene.join("sweep.toml");
    std::fs::write(&sweep, &text).unwrap();
    let s = dtm_json(&sweep, &d.path().join("sweep"));
    // The feature route's model, refined or not (the refinement may fail in the fields):
    // its grid and record in coarse/.
    let p = project(&scene, "features", "coarse = \"features\"");
    let out = d.path().join("features");
    let _ = rig()
        .arg("dtm")
        .arg(&p)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let coarse = read_geotiff(&out.join("coarse/dem.tif")).unwrap();
    let truth = read_geotiff(&scene.join("truth-dem.tif")).unwrap();
    let c = coarse.compare(|x, y| truth.interpolate(x, y));
    let record: Value =
        serde_json::from_slice(&std::fs::read(out.join("coarse/report.json")).unwrap()).unwrap();
    let m_per_px = record["m_per_px"].as_f64().unwrap();
    assert_eq!(record["comparison"]["nodes"].as_u64(), Some(c.nodes as u64));
    let sweep_rmse = s["comparison"]["rmse_m"].as_f64().unwrap();
    eprintln!(
        "weak texture: the sweep {sweep_rmse:.2} m = {:.2} px over {} nodes; the feature route {:.2} m = {:.2} px over {} nodes",
        sweep_rmse / m_per_px,
        s["comparison"]["nodes"],
        c.rmse_m,
        c.rmse_m / m_per_px,
        c.nodes
    );
    assert!(
        sweep_rmse / m_per_px > 1.5,
        "the sweep did not fail: {sweep_rmse:.2} m"
    );
    assert!(
        c.rmse_m / m_per_px < 1.0,
        "the feature route: {:.2} m",
        c.rmse_m
    );
    assert!(c.rmse_m * 2.0 < sweep_rmse);
    assert!(c.nodes > 100, "{} nodes", c.nodes);
}
