//! Hostile matching projects: every number a project, its points file or a flag gives is
//! range-checked with a message naming the field and its range; memory and work are estimated
//! and refused before the run; nothing panics, aborts (under a 4 GiB address-space limit) or
//! hangs; the project's own files are never changed; a run killed half way can be run again.

mod common;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// A small rendered scene (160 × 160 px), made once.
fn scene() -> &'static PathBuf {
    static S: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &S.get_or_init(|| {
        let d = tempfile::tempdir().unwrap();
        let scene = d.path().join("scene");
        let out = common::rig()
            .args([
                "sim",
                "scene",
                "--seed",
                "3",
                "--area",
                "44,-2,48,2",
                "--out",
            ])
            .arg(&scene)
            .output()
            .unwrap();
        assert!(out.status.success(), "{out:?}");
        (d, scene)
    })
    .1
}

/// The project with `key = value` set in `[section]` (the key must be there, or be added).
fn with(section: &str, key: &str, value: &str) -> String {
    let text = std::fs::read_to_string(scene().join("project.toml")).unwrap();
    let mut out = String::new();
    let mut here = false;
    let mut done = false;
    for line in text.lines() {
        if line.starts_with('[') {
            if here && !done {
                out.push_str(&format!("{key} = {value}\n"));
                done = true;
            }
            here = line.trim() == format!("[{section}]");
        }
        if here && line.split('=').next().map(str::trim) == Some(key) {
            out.push_str(&format!("{key} = {value}\n"));
            done = true;
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    if !done {
        if !here {
            out.push_str(&format!("[{section}]\n"));
        }
        out.push_str(&format!("{key} = {value}\n"));
    }
    assert_ne!(out, text, "{section}.{key} was not set");
    out
}

/// Hashes of the scene's own files (other tests add theirs beside them), to show a failed
/// run changed nothing.
fn snapshot(dir: &Path) -> Vec<(String, u64)> {
    use std::hash::{Hash, Hasher};
    let own = [
        "photo-1.json",
        "photo-1.tiff",
        "photo-2.json",
        "photo-2.tiff",
        "points.json",
        "project.toml",
        "truth-dem.tif",
        "truth.json",
    ];
    own.iter()
        .map(|n| {
            let mut h = std::collections::hash_map::DefaultHasher::new();
            std::fs::read(dir.join(n)).unwrap().hash(&mut h);
            (n.to_string(), h.finish())
        })
        .collect()
}

/// Runs `rig dtm` on `project_text` (written beside the scene's files) into a new
/// directory; returns the exit code and what it said.
fn dtm(project_text: &str, extra: &[&str]) -> (Option<i32>, String) {
    let name = format!("p{:x}.toml", {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        (project_text, extra).hash(&mut h);
        h.finish()
    });
    let p = scene().join(&name);
    std::fs::write(&p, project_text).unwrap();
    let out = tempfile::tempdir().unwrap();
    let before = snapshot(scene());
    let mut cmd = common::rig();
    cmd.arg("dtm")
        .arg(&p)
        .arg("--out")
        .arg(out.path().join("o"))
        .args(extra);
    let h = common::run_hostile(&mut cmd, 4, 60);
    assert_eq!(before, snapshot(scene()), "the project's files changed");
    let _ = std::fs::remove_file(&p);
    (h.code, format!("{}{}", h.stdout, h.stderr))
}

#[test]
fn hostile_project_numbers_are_refused_by_field_and_range() {
    for (section, key, value, says) in [
        ("matching", "h_max", "inf", "h_max"),
        ("matching", "h_min", "-inf", "h_min"),
        ("matching", "h_min", "nan", "h_min"),
        ("matching", "h_max", "1e300", "h_max"),
        ("matching", "h_step", "1e-9", "h_step"),
        ("matching", "h_step", "0", "h_step"),
        ("matching", "h_step", "-2", "h_step"),
        ("matching", "window", "1000001", "window"),
        ("matching", "window", "8", "window"),
        ("matching", "threshold", "nan", "threshold"),
        ("matching", "threshold", "1", "threshold"),
        ("matching", "stride", "0", "stride"),
        ("pmf", "order", "9", "order"),
        (
            "regions",
            "search_distance",
            "1000000000",
            "search_distance",
        ),
        ("regions", "height_threshold", "inf", "height_threshold"),
        ("grid", "cell_m", "1e-6", "cell_m"),
        ("grid", "cell_m", "0", "cell_m"),
        ("grid", "flying_height_m", "-1", "flying_height_m"),
        ("limits", "max_memory_mb", "1", "max_memory_mb"),
        ("limits", "max_candidates_g", "nan", "max_candidates_g"),
    ] {
        let (code, said) = dtm(&with(section, key, value), &[]);
        assert_eq!(code, Some(1), "{section}.{key} = {value}: {said}");
        assert!(said.contains(says), "{section}.{key} = {value}: {said}");
        assert!(said.contains("project") || said.contains(".toml"), "{said}");
    }
}

#[test]
fn work_and_memory_are_estimated_before_the_run() {
    // The smallest grid cell the range check passes, and a limit it needs more than.
    let (code, said) = dtm(
        &with("limits", "max_memory_mb", "64").replace("cell_m = 10.0", "cell_m = 0.01"),
        &[],
    );
    assert_eq!(code, Some(1), "{said}");
    assert!(said.contains("MiB") && said.contains("cell_m"), "{said}");
    // A work limit below this sweep's candidates.
    let (code, said) = dtm(&with("limits", "max_candidates_g", "1e-6"), &[]);
    assert_eq!(code, Some(1), "{said}");
    assert!(
        said.contains("candidate heights") && said.contains("max_candidates_g"),
        "{said}"
    );
    // The command-line limit overrides the project's.
    let (code, said) = dtm(&with("grid", "cell_m", "0.01"), &["--max-memory", "16"]);
    assert_eq!(code, Some(1), "{said}");
    assert!(said.contains("the limit is 16 MiB"), "{said}");
    let (code, said) = dtm(&with("grid", "cell_m", "10"), &["--max-memory", "1"]);
    assert_eq!(code, Some(2), "{said}");
    assert!(said.contains("--max-memory"), "{said}");
}

#[test]
fn hostile_points_files_are_refused() {
    let project = std::fs::read_to_string(scene().join("project.toml")).unwrap();
    let good: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(scene().join("points.json")).unwrap())
            .unwrap();
    let mut cases: Vec<(&str, serde_json::Value, &str)> = Vec::new();
    let mut none = good.clone();
    none["gcps"] = serde_json::json!([]);
    cases.push(("no control points", none, "control points"));
    let mut four = good.clone();
    four["gcps"] = serde_json::json!(good["gcps"].as_array().unwrap()[..4]);
    cases.push(("four control points", four, "control points"));
    let mut same = good.clone();
    let first = good["gcps"][0].clone();
    same["gcps"] = serde_json::json!(vec![first; 12]);
    cases.push(("twelve copies of one point", same, "listed twice"));
    let mut huge = good.clone();
    huge["gcps"][3]["ground"]["z"] = serde_json::json!(1e300);
    cases.push(("a height of 1e300", huge, "gcps[3]"));
    let mut nocp = good.clone();
    nocp["cps"] = serde_json::json!([]);
    cases.push(("no check points", nocp, "check points"));
    for (what, pts, says) in cases {
        let f = scene().join("hostile-points.json");
        std::fs::write(&f, serde_json::to_vec(&pts).unwrap()).unwrap();
        let text = project.replace("file = \"points.json\"", "file = \"hostile-points.json\"");
        assert_ne!(text, project);
        let (code, said) = dtm(&text, &[]);
        let _ = std::fs::remove_file(&f);
        assert_eq!(code, Some(1), "{what}: {said}");
        assert!(said.contains(says), "{what}: {said}");
    }
}

#[test]
fn a_one_node_reference_model_does_not_crash_the_comparison() {
    use rig::matching::grid::ElevationGrid;
    let g = ElevationGrid {
        x0: 0.0,
        y0: 0.0,
        cell_m: 10.0,
        cols: 1,
        rows: 1,
        z: vec![450.0],
    };
    let f = scene().join("one-node.tif");
    rig::matching::products::files::write_geotiff(&f, &g, rig::geometry::Crs::Local).unwrap();
    let text = with("grid", "reference", "\"one-node.tif\"");
    let (code, said) = dtm(&text, &[]);
    let _ = std::fs::remove_file(&f);
    assert_eq!(code, Some(0), "{said}");
}

#[test]
fn a_killed_run_can_be_run_again_and_foreign_files_are_kept() {
    let p = scene().join("project.toml");
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("o");
    let run = || {
        let mut cmd = common::rig();
        cmd.arg("dtm").arg(&p).arg("--out").arg(&out);
        common::run_hostile(&mut cmd, 4, 60)
    };
    assert_eq!(run().code, Some(0));
    let dem = std::fs::read(out.join("dem.tif")).unwrap();
    // As a kill half way leaves it: one output gone, another half written under its
    // temporary name.
    std::fs::remove_file(out.join("points.ply")).unwrap();
    std::fs::write(out.join("report.json.part"), b"{\"half").unwrap();
    let again = run();
    assert_eq!(again.code, Some(0), "{}", again.stderr);
    // Standard error is a pipe here, as a log file would be: the progress comes as lines, a
    // step's start and its end, not as a terminal's bar.
    let lines: Vec<&str> = again.stderr.lines().collect();
    assert!(
        lines.iter().any(|l| l.contains(": 0/")) && lines.iter().any(|l| l.contains(" done in ")),
        "{}",
        again.stderr
    );
    assert!(
        !again.stderr.contains('\r'),
        "a bar's carriage returns in a log"
    );
    assert_eq!(
        std::fs::read(out.join("dem.tif")).unwrap(),
        dem,
        "the same result"
    );
    assert!(out.join("points.ply").exists());
    assert!(
        !out.join("report.json.part").exists() || {
            // A leftover .part of an earlier run is harmless; the real report is whole.
            serde_json::from_slice::<serde_json::Value>(
                &std::fs::read(out.join("report.json")).unwrap(),
            )
            .is_ok()
        }
    );
    // Somebody else's file: the directory is not ours to write over.
    std::fs::write(out.join("notes.txt"), b"mine").unwrap();
    let refused = run();
    assert_eq!(refused.code, Some(1));
    assert!(refused.stderr.contains("notes.txt"), "{}", refused.stderr);
    assert_eq!(std::fs::read(out.join("notes.txt")).unwrap(), b"mine");
}

/// Heights that miss the terrain: the run finishes and warns (matches piled at a bound, few
/// matched), exit 0; with --strict the same outputs and exit 12.
#[test]
fn heights_that_miss_the_terrain_warn_and_strict_makes_it_an_exit_code() {
    let text = with("matching", "h_min", "150.0");
    let text: String = text
        .lines()
        .map(|l| {
            if l.split('=').next().map(str::trim) == Some("h_max") {
                "h_max = 250.0".to_string()
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    assert!(text.contains("h_max = 250.0"), "{text}");
    let (code, said) = dtm(&text, &[]);
    assert_eq!(code, Some(0), "{said}");
    assert!(said.contains("rig dtm: warning:"), "{said}");
    let (code, said) = dtm(&text, &["--strict"]);
    assert_eq!(code, Some(rig::exit::DOUBTFUL), "{said}");
    assert!(said.contains("rig dtm: warning:"), "{said}");
    // A run that finds the terrain does not warn, --strict or not.
    let (code, said) = dtm(
        &std::fs::read_to_string(scene().join("project.toml")).unwrap(),
        &["--strict"],
    );
    assert_eq!(code, Some(0), "{said}");
    assert!(!said.contains("warning"), "{said}");
}

/// `order = "auto"`: the check points choose each mapping's order; the report says which. A
/// word other than "auto" is refused naming the field.
#[test]
fn the_mapping_order_can_be_left_to_the_check_points() {
    let (code, said) = dtm(&with("pmf", "order", "\"auto\""), &["--json"]);
    assert_eq!(code, Some(0), "{said}");
    let json = said.lines().find(|l| l.starts_with('{')).unwrap();
    let v: serde_json::Value = serde_json::from_str(json).unwrap();
    let fits = v["pairs"][0]["pmf"].as_array().unwrap();
    assert!(!fits.is_empty());
    for f in fits {
        let o = f["order"].as_u64().unwrap();
        assert!((1..=3).contains(&o), "{f}");
    }
    let (code, said) = dtm(&with("pmf", "order", "\"cubic\""), &[]);
    assert_ne!(code, Some(0));
    assert!(said.contains("order") && said.contains("auto"), "{said}");
}

#[test]
fn scene_lists_that_start_with_a_minus_reach_their_range_checks() {
    let d = tempfile::tempdir().unwrap();
    // A negative first number is a value, not a flag: the area is read, and the offsets' own
    // range check is what refuses them (before anything is rendered).
    let out = common::rig()
        .args([
            "sim",
            "scene",
            "--area",
            "-4,-2,48,2",
            "--offsets",
            "-30001,0",
            "--out",
        ])
        .arg(d.path().join("s"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "a usage error: {err}");
    assert!(
        err.contains("--offsets `-30001,0`: -30001 is outside"),
        "{err}"
    );
    let out = common::rig()
        .args(["sim", "scene", "--area", "-101,-2,48,2", "--out"])
        .arg(d.path().join("s"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "a usage error: {err}");
    assert!(err.contains("inside ±100 mm"), "{err}");
    assert!(!d.path().join("s").exists(), "nothing written");
}
