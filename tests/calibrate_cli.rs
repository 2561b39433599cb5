//! `rig calibrate` through the binary, against the simulator's truth (issue 4, item 6).

mod common;
use common::*;
use serde_json::Value;

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

#[test]
fn pixel_calibration_matches_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("session");
    let o = rig()
        .args([
            "calibrate",
            "pixel",
            "--sim",
            "--sim-seed",
            "3",
            "--json",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let (code, doc, err) = parse(o);
    assert_eq!(code, 0, "{err}");
    let c = &doc["calibration"];
    let truth: Value =
        serde_json::from_slice(&std::fs::read(out.join("sim-truth.json")).unwrap()).unwrap();
    let af = &truth["camera"]["affine"];
    let (xs, ys, xsh, ysh) = (
        f(&af["a"][0]),
        f(&af["b"][1]),
        f(&af["a"][1]),
        f(&af["b"][0]),
    );
    println!(
        "x-scale {:.5} (truth {xs}), y-scale {:.5} ({ys}), x-shear {:.5} ({xsh}), y-shear {:.5} ({ysh}), RMS {:.3} µm",
        f(&c["x_scale"]), f(&c["y_scale"]), f(&c["x_shear"]), f(&c["y_shear"]), f(&c["rms_um"])
    );
    assert!((f(&c["x_scale"]) - xs).abs() < 0.001);
    assert!((f(&c["y_scale"]) - ys).abs() < 0.001);
    assert!((f(&c["x_shear"]) - xsh).abs() < 0.01);
    assert!((f(&c["y_shear"]) - ysh).abs() < 0.01);
    // Every grid position measured and used.
    let grid = c["grid"].as_array().unwrap();
    assert_eq!(grid.len(), 25);
    assert!(grid.iter().all(|o| o["rejected"].is_null()), "{grid:?}");
    // The measuring mark, from all nine crosses: within the stage's own repeatability of the
    // truth (0.15 µm ≈ 0.015 px σ, and its drift).
    let m = &c["mark"];
    let (mc, mr) = (f(&m["mean"]["col"]), f(&m["mean"]["row"]));
    let (tc, tr) = (f(&af["mark_px"][0]), f(&af["mark_px"][1]));
    println!("mark ({mc:.3}, {mr:.3}) truth ({tc}, {tr}); σ {}", m["std"]);
    assert_eq!(m["per_cross"].as_array().unwrap().len(), 9);
    assert!((mc - tc).abs() < 0.1 && (mr - tr).abs() < 0.1);
    // The seed's observation: without shifts the 4-parameter fit is biased.
    let l4 = &c["linear4"];
    assert!(f(&l4["residual_sum"][0]).abs() + f(&l4["residual_sum"][1]).abs() > 0.5);
    // The session: log documents in order, a crop per mark, the results document.
    let log = std::fs::read_to_string(out.join("log.jsonl")).unwrap();
    let docs: Vec<Value> = log
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(docs[0]["doc"], "start");
    assert_eq!(docs[1]["doc"], "descriptor");
    assert_eq!(docs.last().unwrap()["doc"], "stop");
    assert_eq!(docs.last().unwrap()["status"], "done");
    let measured = docs.iter().filter(|d| d["name"] == "measured").count();
    assert_eq!(measured, 25 + 9);
    for id in ["grid-1-1", "grid-5-5", "cross-1", "cross-9"] {
        assert!(
            out.join("crops").join(format!("{id}.png")).is_file(),
            "{id}"
        );
    }
    let saved: Value =
        serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(saved, doc, "results.json is what --json printed");
}

#[test]
fn calibrate_usage_errors_say_what_to_do() {
    let dir = tempfile::tempdir().unwrap();
    for (args, needle) in [
        (vec!["calibrate", "pixel"], "--plate-cert"),
        (
            vec!["calibrate", "pixel", "--sim", "--pixel-um", "ten"],
            "--pixel-um",
        ),
        (
            vec!["calibrate", "pixel", "--sim", "--frames", "0"],
            "--frames",
        ),
    ] {
        let o = rig()
            .args(&args)
            .arg("--store")
            .arg(dir.path())
            .output()
            .unwrap();
        let (code, _, err) = parse(o);
        assert_ne!(code, 0, "{args:?}");
        assert!(err.contains(needle), "{args:?}: {err}");
    }
    // A session directory is never written over.
    let used = dir.path().join("used");
    std::fs::create_dir_all(&used).unwrap();
    std::fs::write(used.join("results.json"), "{}").unwrap();
    let o = rig()
        .args(["calibrate", "pixel", "--sim", "--out"])
        .arg(&used)
        .output()
        .unwrap();
    let (code, _, err) = parse(o);
    assert_ne!(code, 0);
    assert!(err.contains("not empty"), "{err}");
    assert_eq!(
        std::fs::read_to_string(used.join("results.json")).unwrap(),
        "{}"
    );
}
