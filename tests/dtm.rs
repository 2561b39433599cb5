//! Seed 000's method end to end on a scene rendered by the simulator: `rig sim scene`, then
//! `rig dtm` on its format-1 project, the elevation model against the true DEM.

mod common;

use common::{rig, run_ok};
use serde_json::Value;

/// `rig sim scene` of seed 3 over a small area, in `dir`/scene.
fn rendered_scene(dir: &std::path::Path) -> std::path::PathBuf {
    let scene = dir.join("scene");
    run_ok(
        rig()
            .args([
                "sim",
                "scene",
                "--seed",
                "3",
                "--area",
                "38,-6,52,6",
                "--out",
            ])
            .arg(&scene),
    );
    scene
}

#[test]
fn elevation_model_from_a_rendered_pair_meets_half_the_height_step() {
    let d = tempfile::tempdir().unwrap();
    let scene = rendered_scene(d.path());
    let project = std::fs::read_to_string(scene.join("project.toml")).unwrap();
    for (from, name) in [("points", "dtm-points"), ("rigorous", "dtm-rigorous")] {
        let p = scene.join(format!("{name}.toml"));
        let text = project.replace("from = \"points\"", &format!("from = \"{from}\""));
        assert!(
            project.contains("from = \"points\""),
            "the scene's project changed form"
        );
        std::fs::write(&p, text).unwrap();
        let out = d.path().join(name);
        let v = common::dtm_json(&p, &out);
        // Format 1 runs as the format-2 sweep of its two photos.
        let pairs = v["pairs"].as_array().unwrap();
        assert_eq!(pairs.len(), 1, "{v}");
        assert_eq!(
            (&pairs[0]["left"], &pairs[0]["right"]),
            (&"left".into(), &"right".into())
        );
        // The mappings asked for (not the default the text may have kept): fitted to the
        // control points, or sampled from the resected photos (which alone report the
        // check points' error in the other space).
        let fits = pairs[0]["pmf"].as_array().unwrap();
        assert!(!fits.is_empty());
        for f in fits
            .iter()
            .filter(|f| f["name"].as_str().unwrap().contains('→'))
        {
            assert_eq!(f["cp_rmse_other"].is_null(), from == "points", "{f}");
        }
        let t = &pairs[0]["dtm"];
        let step = pairs[0]["h_step_m"].as_f64().unwrap();
        let rmse = v["comparison"]["rmse_m"].as_f64().unwrap();
        let mean = v["comparison"]["mean_m"].as_f64().unwrap();
        let matched = t["matched_percent"].as_f64().unwrap();
        let left = t["remaining_percent"].as_f64().unwrap();
        eprintln!(
            "PMFs from {from}: matched {matched:.1} %, left {left:.1} %, RMSE {rmse:.2} m (step {step} m), mean {mean:+.2} m"
        );
        assert!(matched > 95.0 && left > 90.0);
        assert!(rmse <= 0.5 * step, "RMSE {rmse} m against a {step} m step");
        assert!(mean.abs() < 0.3 * step);
        for f in [
            "dem.tif",
            "points.ply",
            "hillshade.png",
            "error.png",
            "report.json",
            "mappings.json",
        ] {
            assert!(out.join(f).is_file(), "{f}");
        }
        let g = rig::matching::products::files::read_geotiff(&out.join("dem.tif")).unwrap();
        assert!(g.filled() > 1000);
    }
    // The mappings given directly: the first run's mappings.json, and its one pair's set
    // alone (format 1's pmfs.json form): the same model, byte for byte.
    let first = d.path().join("dtm-points");
    let written: Value =
        serde_json::from_slice(&std::fs::read(first.join("mappings.json")).unwrap()).unwrap();
    let one = scene.join("pmfs.json");
    std::fs::write(&one, written["pairs"][0]["mappings"].to_string()).unwrap();
    for (file, name) in [(first.join("mappings.json"), "dtm-file"), (one, "dtm-pmfs")] {
        let p = scene.join(format!("{name}.toml"));
        std::fs::write(
            &p,
            project.replace(
                "from = \"points\"",
                &format!("from = \"file\"\nfile = \"{}\"", file.display()),
            ),
        )
        .unwrap();
        let again = d.path().join(name);
        common::dtm_json(&p, &again);
        assert_eq!(
            std::fs::read(first.join("dem.tif")).unwrap(),
            std::fs::read(again.join("dem.tif")).unwrap(),
            "{name}"
        );
    }
    // The same project written as format 2 by `rig dtm upgrade` is the project format 1 is
    // read as (so its run is the one above), and a second upgrade overwrites nothing.
    let up = scene.join("dtm-points-format2.toml");
    run_ok(
        rig()
            .args(["dtm", "upgrade"])
            .arg(scene.join("dtm-points.toml")),
    );
    let text = std::fs::read_to_string(&up).unwrap();
    assert!(
        text.contains("format = 2") && text.contains("mappings = \"points\""),
        "{text}"
    );
    let o = rig()
        .args(["dtm", "upgrade"])
        .arg(scene.join("dtm-points.toml"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{o:?}");
    assert!(String::from_utf8_lossy(&o.stderr).contains("is not overwritten"));
    use rig::matching::project::Project;
    let (mut two, one) = (
        Project::load(&up).unwrap(),
        Project::load(&scene.join("dtm-points.toml")).unwrap(),
    );
    assert_eq!(two.observations().unwrap(), one.observations().unwrap());
    assert_ne!(two.points_file, one.points_file, "the CSV, and the JSON");
    (two.path, two.points_file) = (one.path.clone(), one.points_file.clone());
    assert_eq!(
        serde_json::to_value(&two).unwrap(),
        serde_json::to_value(&one).unwrap()
    );
    // A height range that misses most of the terrain: the run warns that the heights pile at
    // the bound (it does not pass silently).
    let h_min: f64 = project
        .lines()
        .find_map(|l| l.strip_prefix("h_min = "))
        .expect("the scene's project has h_min")
        .trim()
        .parse()
        .unwrap();
    let h_max_line = project
        .lines()
        .find(|l| l.starts_with("h_max = "))
        .expect("the scene's project has h_max");
    let low = scene.join("low.toml");
    std::fs::write(
        &low,
        project.replace(h_max_line, &format!("h_max = {}", h_min + 86.0)),
    )
    .unwrap();
    let o = run_ok(
        rig()
            .args(["dtm"])
            .arg(&low)
            .arg("--out")
            .arg(d.path().join("dtm-low")),
    );
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("warning") && e.contains("within a step of the highest height tried"),
        "{e}"
    );
    // Where standard error is not a terminal (here: a pipe, as a log file) the progress
    // comes as plain lines, a step's start and end, with no bar redrawn in place.
    assert!(
        e.contains("sweep (candidate heights, least squares counted): 0/"),
        "{e}"
    );
    assert!(!e.contains('\r') && !e.contains("=>"), "{e}");
    // A project with a bad value names the file and the field.
    let bad = scene.join("bad.toml");
    let text = project.replace("[matching]\n", "[matching]\nh_step = -2\n");
    assert_ne!(text, project, "the scene's project has no [matching]");
    std::fs::write(&bad, text).unwrap();
    let o = rig()
        .arg("dtm")
        .arg(&bad)
        .arg("--out")
        .arg(d.path().join("never"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("bad.toml") && e.contains("h_step"), "{e}");
}

#[test]
fn the_demo_runs_the_whole_chain_and_meets_half_the_height_step() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("demo");
    let o = run_ok(
        rig()
            .args(["demo", "--quick", "--seed", "2", "--out"])
            .arg(&out),
    );
    let text = String::from_utf8_lossy(&o.stdout);
    eprintln!("{text}");
    let v: Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    // Three photos, every pair swept, the heights merged (project format 2).
    let t = &v["dtm"];
    let rmse = t["comparison"]["rmse_m"].as_f64().unwrap();
    // Seed 000's target: half its 2 m height step.
    assert!(rmse <= 1.0, "demo RMSE {rmse} m");
    let pairs = t["pairs"].as_array().unwrap();
    assert_eq!(pairs.len(), 3);
    for p in pairs {
        // Most of the overlap matched (the edges where the other photo cannot show every
        // height tried get none), and the wrong-height criteria removed little of it.
        let d = &p["dtm"];
        assert!(d["matched_percent"].as_f64().unwrap() > 70.0, "{p}");
        let removed = d["regions"]["points_removed"].as_f64().unwrap();
        let matched = d["points_matched"].as_f64().unwrap();
        assert!(removed < 0.1 * matched, "{p}");
    }
    assert_eq!(t["crs"], "EPSG:32616");
    // The photos oriented as one block (dtm/orientation/), none resected alone, from the
    // control points and the tie points the rig found; the model's σ carries the block's
    // covariance.
    assert_eq!(t["resected"].as_array().unwrap().len(), 0);
    let o = &v["orientation"];
    assert_eq!(o["photos"], 3);
    assert!(o["tie_points"].as_u64().unwrap() > 100, "{o}");
    assert!(t["orientation_sigma_m"].as_f64().unwrap() > 0.0);
    // No tilt left to speak of: the RMSE with the best plane removed is most of the RMSE
    // (the goal 0.8: seeds 1–4 give 0.80–0.93, this quick run 0.815; a tilted datum,
    // as the old 0.5 m control gave, 0.28).
    let c = &t["comparison"];
    let flat = c["rmse_without_plane_m"].as_f64().unwrap() / c["rmse_m"].as_f64().unwrap();
    assert!(
        (0.75..=1.0).contains(&flat),
        "plane removed / as is: {flat:.3}"
    );
    for f in [
        "scan-photo-1/stereo.tiff",
        "scan-photo-2/stereo.tiff",
        "scan-photo-3/stereo.tiff",
        "points.csv",
        "dtm/dem.tif",
        "dtm/hillshade.png",
        "project.toml",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    assert!(text.contains("RMSE"));
    // The demo's folder can be moved: what a run reads (the project, the points, the scans'
    // hand-overs, manifests and calibrations) names everything relative to itself, and a
    // share of the sweep run in the moved copy reads the same inputs and gives the same bytes
    // as in the original (a share: the whole run again is the single run's, byte for byte, by
    // tests/format2.rs's tiles).
    let mut read = vec![
        out.join("project.toml"),
        out.join("points.csv"),
        out.join("dtm/orientation/project.toml"),
    ];
    for k in 1..=3 {
        for e in std::fs::read_dir(out.join(format!("scan-photo-{k}"))).unwrap() {
            let f = e.unwrap().path();
            if matches!(
                f.extension().and_then(|x| x.to_str()),
                Some("json" | "toml")
            ) {
                read.push(f);
            }
        }
    }
    let here = out.to_str().unwrap();
    for f in &read {
        let text = std::fs::read_to_string(f).unwrap();
        assert!(!text.contains(here), "{} names {here}", f.display());
    }
    let share = |project: &std::path::Path, to: &std::path::Path| -> Value {
        let o = run_ok(
            rig()
                .arg("dtm")
                .arg(project)
                .args(["--tile", "1/6", "--json", "--out"])
                .arg(to),
        );
        serde_json::from_slice(&o.stdout).unwrap()
    };
    // (The oriented project: a block of approximations is oriented once, before any share.)
    let oriented = "dtm/orientation/project.toml";
    let before = share(&out.join(oriented), &d.path().join("share-before"));
    let moved = d.path().join("moved-demo");
    std::fs::rename(&out, &moved).unwrap();
    let after = share(&moved.join(oriented), &d.path().join("share-after"));
    for key in ["project_fnv64", "inputs_fnv64", "units"] {
        assert_eq!(before[key], after[key], "{key}");
    }
    for part in before["parts"].as_array().unwrap() {
        let f = part["file"].as_str().unwrap();
        assert_eq!(
            std::fs::read(d.path().join("share-before").join(f)).unwrap(),
            std::fs::read(d.path().join("share-after").join(f)).unwrap(),
            "the moved demo's {f} differs"
        );
    }
    // The pages link what is there, relative to themselves, and their pictures are at least
    // 800 px wide.
    for page in ["report.html", "dtm/report.html"] {
        let path = moved.join(page);
        let html = std::fs::read_to_string(&path).unwrap();
        let base = path.parent().unwrap();
        let mut pictures = 0;
        for attr in ["src=\"", "href=\""] {
            for part in html.split(attr).skip(1) {
                let target = part.split('"').next().unwrap();
                assert!(!target.starts_with('/'), "{page}: absolute link {target}");
                let f = base.join(target.replace("%20", " "));
                assert!(f.is_file(), "{page} links {target}, which is not there");
                if attr == "src=\"" {
                    let (w, _) = image::image_dimensions(&f).unwrap();
                    // The scans' previews are the photos themselves, at their size.
                    if !target.ends_with("stereo.png") {
                        assert!(w >= 800, "{target}: {w} px wide");
                    }
                    pictures += 1;
                }
            }
        }
        assert!(pictures >= 3, "{page}: {pictures} pictures");
    }
}

/// The sweep's own accuracy, apart from any orientation error: a rendered pair with the
/// simulator's exact orientations as a format-2 project (mapping functions derived from the
/// sensors). The model's RMSE against the true DEM, in pixels of parallax (the step is half a
/// pixel), is at most 0.15 px.
#[test]
fn with_exact_orientations_the_model_is_within_a_seventh_of_a_pixel_of_parallax() {
    let d = tempfile::tempdir().unwrap();
    let scene = rendered_scene(d.path());
    let truth: Value =
        serde_json::from_slice(&std::fs::read(scene.join("truth.json")).unwrap()).unwrap();
    let [ox, oy] = rig::sim_scene::ORIGIN_M;
    let mut toml = String::from("format = 2\ncrs = \"EPSG:32616\"\n");
    for ph in truth["photos"].as_array().unwrap() {
        let e = &ph["exterior"];
        let f = |k: &str| e[k].as_f64().unwrap();
        toml += &format!(
            "[[photo]]\nid = \"{n}\"\nscan = \"photo-{n}.json\"\nposition = [{}, {}, {}]\nangles_deg = [{}, {}, {}]\n",
            f("x0_m") + ox,
            f("y0_m") + oy,
            f("z0_m"),
            f("omega_deg"),
            f("phi_deg"),
            f("kappa_deg"),
            n = ph["number"]
        );
    }
    let [lo, hi] = [
        truth["terrain_m"][0].as_f64().unwrap(),
        truth["terrain_m"][1].as_f64().unwrap(),
    ];
    toml += &format!(
        "[dem]\ncell_m = 10.0\nheights = [{}, {}]\n[check]\nreference = \"truth-dem.tif\"\n",
        lo - 30.0,
        hi + 30.0
    );
    let p = scene.join("exact.toml");
    std::fs::write(&p, toml).unwrap();
    let out = d.path().join("exact");
    let o = run_ok(
        rig()
            .arg("dtm")
            .arg(&p)
            .arg("--json")
            .arg("--out")
            .arg(&out),
    );
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    let pair = &v["pairs"][0];
    let px_m = 2.0 * pair["h_step_m"].as_f64().unwrap();
    let rmse = v["comparison"]["rmse_m"].as_f64().unwrap();
    let matched = pair["dtm"]["matched_percent"].as_f64().unwrap();
    eprintln!(
        "RMSE {rmse:.3} m = {:.3} px of parallax ({px_m:.3} m per px), {matched:.1} % matched",
        rmse / px_m
    );
    assert!(rmse / px_m <= 0.15, "{:.3} px", rmse / px_m);
    assert!(matched > 85.0, "{matched:.1} % matched");
}
