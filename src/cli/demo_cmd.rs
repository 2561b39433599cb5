//! `rig demo`: the whole chain on the built-in simulator, step by step as an operator would
//! type it — pixel→carriage calibration, the interior orientation and a scan of each of two
//! overlapping photos, control points, the elevation model by seed 000's method — and a
//! report comparing it with the simulator's true DEM. Every step is the real `rig` command,
//! printed before it runs, so the demo doubles as a worked example.

use anyhow::{bail, Context};
use clap::Args;
use rig::coords::PhotoMm;
use rig::scan::ScannedPhoto;
use rig_sim::scene::{jacksboro, AerialPhoto};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Directory for everything the demo makes (created; must be empty).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Simulator seed (the rig, the films, the block).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Fewer positions and frames in the calibrations (a quicker, slightly rougher run).
    #[arg(long)]
    pub quick: bool,
}

/// The area of photo 1 that is scanned and matched, photo mm (inside the overlap with
/// photo 2, whose centre lies about 92 mm along x).
const AREA: [f64; 4] = [36.0, -8.0, 56.0, 8.0];

fn step(title: &str, args: &[String]) -> anyhow::Result<Value> {
    eprintln!("\n== {title}\n$ rig {}", args.join(" "));
    let exe = std::env::current_exe().context("finding the rig executable")?;
    let t = Instant::now();
    let out = Command::new(exe)
        .args(args)
        .stderr(std::process::Stdio::inherit())
        .output()
        .with_context(|| format!("running rig {}", args.join(" ")))?;
    if !out.status.success() {
        bail!(
            "step `{title}` failed ({}); what it made so far is kept",
            out.status
        );
    }
    eprintln!("   ({:.1} s)", t.elapsed().as_secs_f64());
    let text = String::from_utf8_lossy(&out.stdout);
    Ok(serde_json::from_str(text.trim()).unwrap_or(Value::String(text.into_owned())))
}

fn s(p: &Path) -> String {
    p.display().to_string()
}

fn scan_script(path: &Path, interior: &Path, region: [f64; 4], out: &Path) -> anyhow::Result<()> {
    std::fs::write(
        path,
        format!(
            r#"# Written by `rig demo`.
[film]
name = "simulated block, {name}"
interior_session = "{interior}"

[output]
dir = "{out}"
resolution_um = 25.0

[capture]
frames = 8
overlap = 0.2
settle_ms = 0

[[region]]
name = "stereo"
photo_mm = [{:.3}, {:.3}, {:.3}, {:.3}]
"#,
            region[0],
            region[1],
            region[2],
            region[3],
            name = path.file_stem().and_then(|n| n.to_str()).unwrap_or("photo"),
            interior = interior.display(),
            out = out.display(),
        ),
    )?;
    Ok(())
}

pub fn run(a: &DemoArgs) -> anyhow::Result<i32> {
    if a.out.exists() && std::fs::read_dir(&a.out)?.next().is_some() {
        bail!("{} is not empty: give a new directory", a.out.display());
    }
    std::fs::create_dir_all(&a.out)?;
    let out = std::fs::canonicalize(&a.out)?;
    let t0 = Instant::now();
    let seed = a.seed.to_string();
    let store = out.join("sessions");
    let sim = |photo: u32| -> Vec<String> {
        vec![
            "--sim".into(),
            "--sim-seed".into(),
            seed.clone(),
            "--sim-photo".into(),
            photo.to_string(),
        ]
    };
    let (grid, frames) = if a.quick { ("3", "8") } else { ("5", "32") };
    // 1. Pixel → carriage.
    let mut args: Vec<String> = vec!["calibrate".into(), "pixel".into()];
    args.extend(sim(1));
    args.extend(["--grid", grid, "--frames", frames, "--json", "--store"].map(String::from));
    args.push(s(&store));
    let pixel = step("pixel → carriage calibration (seed 002)", &args)?;
    // The simulator's block, to place photo 2's scan where it sees photo 1's area.
    let dem = jacksboro();
    let (p1, p2) = (
        AerialPhoto::new(dem.clone(), a.seed, 1, 110.0),
        AerialPhoto::new(dem, a.seed, 2, 110.0),
    );
    let hs = super::scene_cmd::terrain_range(&p1, AREA);
    let area2 = super::scene_cmd::matching_area(&p1, &p2, AREA, [hs[0] - 30.0, hs[1] + 30.0]);
    let mut sidecars = Vec::new();
    let mut interiors = Vec::new();
    for (photo, region) in [(1u32, AREA), (2, area2)] {
        // 2. Interior orientation of the film on the carriage.
        let dir = store.join(format!("interior-photo-{photo}"));
        let mut args: Vec<String> = vec!["calibrate".into(), "interior".into()];
        args.extend(sim(photo));
        args.extend(["--frames", frames, "--json", "--store"].map(String::from));
        args.push(s(&store));
        args.extend(["--out".into(), s(&dir)]);
        interiors.push(step(
            &format!("interior orientation of photo {photo} (fiducials, seed 002 Table 5)"),
            &args,
        )?);
        // 3. The scan of its part of the overlap.
        let script = out.join(format!("scan-photo-{photo}.toml"));
        let scan_dir = out.join(format!("scan-photo-{photo}"));
        scan_script(&script, &dir, region, &scan_dir)?;
        let mut args: Vec<String> = vec!["scan".into()];
        args.extend(sim(photo));
        args.extend(["--json".into(), "run".into(), s(&script)]);
        step(
            &format!("scan of photo {photo}, region {region:.1?} mm"),
            &args,
        )?;
        sidecars.push(scan_dir.join("stereo.json"));
    }
    // 4. Control and check points in the scanned photos (an operator would measure them; here
    // the simulator's truth plus measuring noise), the true DEM, the project.
    eprintln!("\n== control points, the true DEM and the matching project");
    let (s1, _) = ScannedPhoto::load(&sidecars[0])?;
    let (s2, _) = ScannedPhoto::load(&sidecars[1])?;
    let mut rng = rig_sim::rng::Rng::new(a.seed ^ 0xDE40);
    let noise = (0.005, 0.5);
    let gcps =
        super::scene_cmd::draw_points((&p1, &s1.grid), (&p2, &s2.grid), 20, "gcp", noise, &mut rng);
    let cps =
        super::scene_cmd::draw_points((&p1, &s1.grid), (&p2, &s2.grid), 30, "cp", noise, &mut rng);
    rig::digitise::output::write_json(
        &out.join("points.json"),
        &json!({"gcps": gcps, "cps": cps}),
    )?;
    let truth = super::scene_cmd::truth_grid(&p1, AREA, 10.0)?;
    rig::matching::output::write_geotiff(&out.join("truth-dem.tif"), &truth, rig::sim_scene::CRS)?;
    std::fs::write(
        out.join("project.toml"),
        super::scene_cmd::project_toml(
            "# Written by `rig demo`: the two scanned photos, their control points, seed 000's parameters.",
            [&sidecars[0], &sidecars[1]],
            hs,
        ),
    )?;
    // 5. The elevation model.
    let dtm_dir = out.join("dtm");
    let dtm = step(
        "elevation model by polynomial mapping functions and a height sweep (seed 000)",
        &[
            "dtm".into(),
            s(&out.join("project.toml")),
            "--json".into(),
            "--out".into(),
            s(&dtm_dir),
        ],
    )?;
    let report = json!({
        "seed": a.seed,
        "seconds": t0.elapsed().as_secs_f64(),
        "pixel": pixel["calibration"]["affine"],
        "interior": interiors.iter().map(|i| &i["calibration"]["versions"]).collect::<Vec<_>>(),
        "scans": sidecars,
        "dtm": dtm,
        "photo_centre_mm": PhotoMm::new(0.0, 0.0),
    });
    rig::digitise::output::write_json(&out.join("report.json"), &report)?;
    let t = &dtm["dtm"];
    let c = &t["comparison"];
    println!(
        "\nrig demo (seed {}), {:.0} s, in {}:",
        a.seed,
        t0.elapsed().as_secs_f64(),
        out.display()
    );
    let af = &pixel["calibration"];
    println!(
        "  pixel → carriage: x-scale {:.4}, y-scale {:.4}, x-shear {:.4}, y-shear {:.4} µm (simulator: 10.19, 10.96, 0.09, 0.10), RMS {:.3} µm",
        af["x_scale"].as_f64().unwrap_or(f64::NAN),
        af["y_scale"].as_f64().unwrap_or(f64::NAN),
        af["x_shear"].as_f64().unwrap_or(f64::NAN),
        af["y_shear"].as_f64().unwrap_or(f64::NAN),
        af["rms_um"].as_f64().unwrap_or(f64::NAN)
    );
    for (k, i) in interiors.iter().enumerate() {
        let v = &i["calibration"]["versions"][0];
        println!(
            "  photo {}: interior orientation ({}), RMS {:.2} µm; scanned at 25 µm → {}",
            k + 1,
            v["name"].as_str().unwrap_or("?"),
            v["rms_um"].as_f64().unwrap_or(f64::NAN),
            sidecars[k].display()
        );
    }
    println!(
        "  matching: {:.1} % of {} points matched, {:.1} % kept after the height and population criteria",
        t["matched_percent"].as_f64().unwrap_or(f64::NAN),
        t["points_total"],
        t["remaining_percent"].as_f64().unwrap_or(f64::NAN)
    );
    println!(
        "  elevation model vs the true DEM: RMSE {:.2} m ({:.3} ‰ of the 6 500 m flying height; height step {} m), mean {:+.2} m, max +{:.2} / {:.2} m over {} nodes",
        c["rmse_m"].as_f64().unwrap_or(f64::NAN),
        t["rmse_permille_of_flying_height"].as_f64().unwrap_or(f64::NAN),
        super::scene_cmd::HEIGHT_STEP_M,
        c["mean_m"].as_f64().unwrap_or(f64::NAN),
        c["max_positive_m"].as_f64().unwrap_or(f64::NAN),
        c["max_negative_m"].as_f64().unwrap_or(f64::NAN),
        c["nodes"]
    );
    println!(
        "  look at: {}/hillshade.png, {}/error.png; the model: {}/dem.tif; everything: report.json",
        dtm_dir.display(),
        dtm_dir.display(),
        dtm_dir.display()
    );
    Ok(0)
}
