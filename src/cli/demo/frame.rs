//! `rig demo`: the whole chain on the built-in simulator, step by step as an operator would
//! type it — pixel→carriage calibration, the interior orientation and a scan of each of three
//! overlapping photos (two along the strip, one from the next strip), control points, the
//! elevation model from a format-2 project (the photos oriented as one block from approximate
//! orientations, the control points and the tie points the rig finds; every pair swept, seed
//! 000's method) — and a report comparing it with the simulator's true DEM. Every step is the real `rig` command,
//! printed before it runs, so the demo doubles as a worked example.

use anyhow::{bail, Context};
use clap::Args;
use rig::calibrate::documents::{InteriorResults, PixelResults};
use rig::coords::PhotoMm;
use rig::matching::run::Report;
use rig::scan::ScannedPhoto;
use rig_sim::scene::{jacksboro, AerialPhoto};
use serde_json::json;
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
    /// Fewer positions in the pixel calibration and fewer frames averaged in the calibrations
    /// and the scans (a quicker, slightly noisier run).
    #[arg(long)]
    pub quick: bool,
    /// The matcher of the elevation model: "sweep" (seed 000's height sweep over every pair)
    /// or "mgcm" (seed 002's multiphoto geometrically constrained matching, all three photos
    /// at once).
    #[arg(long, value_enum, default_value_t = Method::Sweep)]
    pub method: Method,
    /// "frame": the aerial film chain above. "pushbroom": a SPOT-like triplet of satellite
    /// views (simulated, no rig hardware): each view's RPCs left beside it (view-N_RPC.TXT),
    /// the noise-free points in truth_points.csv, and the elevation model from the three
    /// views through their line-scanner models.
    #[arg(long, value_enum, default_value_t = DemoSensor::Frame)]
    pub sensor: DemoSensor,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DemoSensor {
    Frame,
    Pushbroom,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    Sweep,
    Mgcm,
}

/// The area of photo 1 that is scanned and matched, photo mm: where photos 2 (about 92 mm
/// along x) and 3 (the next strip, about 161 mm across y) see it too.
const AREA: [f64; 4] = [36.0, -80.0, 56.0, -64.0];
/// σ of the control and check points' ground, m: a GNSS survey's. (The block's datum is the
/// control's: at 0.5 m, a 2σ draw of its noise tilted the model by 1 m per km, more than
/// anything the orientation can do.)
const GROUND_SIGMA_M: f64 = 0.05;
/// σ of a control or check point measured in a scan, mm on the film: a tenth of the 25 µm
/// pixel, as least-squares matching measures a signalised point. (The block's datum rests on
/// these measurements: at 5 µm its tilt, within 1.5 σ of the orientations' covariance, was
/// 0.1 m RMS over the model.)
const MEASURING_SIGMA_MM: f64 = 0.0025;
/// Photos of the block the demo uses.
const PHOTOS: [u32; 3] = [1, 2, 3];

/// Runs `rig ARGS` and reads what it printed with --json as a `T` (the type the command
/// wrote it with).
fn step<T: serde::de::DeserializeOwned>(title: &str, args: &[String]) -> anyhow::Result<T> {
    let text = run_step(title, args)?;
    read_report(title, &text)
}

fn read_report<T: serde::de::DeserializeOwned>(title: &str, text: &str) -> anyhow::Result<T> {
    serde_json::from_str(text.trim())
        .with_context(|| format!("step `{title}` printed no report the demo can read"))
}

/// Runs `rig ARGS` as a step of the demo (printed before it runs, timed); what it printed on
/// its standard output.
pub(super) fn run_step(title: &str, args: &[String]) -> anyhow::Result<String> {
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
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// Runs `rig ARGS` beside other steps: what it says on standard error is held and printed with
/// its title when it ends (under `print`, so that the steps' lines do not interleave); what it
/// printed on its standard output.
fn run_step_beside(
    title: &str,
    args: &[String],
    print: &std::sync::Mutex<()>,
) -> anyhow::Result<String> {
    let exe = std::env::current_exe().context("finding the rig executable")?;
    let t = Instant::now();
    let out = Command::new(exe)
        .args(args)
        .output()
        .with_context(|| format!("running rig {}", args.join(" ")))?;
    {
        let _one_at_a_time = print.lock().unwrap_or_else(|e| e.into_inner());
        eprint!(
            "\n== {title}\n$ rig {}\n{}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr)
        );
        if out.status.success() {
            eprintln!("   ({:.1} s)", t.elapsed().as_secs_f64());
        }
    }
    if !out.status.success() {
        bail!(
            "step `{title}` failed ({}); what it made so far is kept",
            out.status
        );
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// The demo's folder, created, as an absolute path.
pub(super) fn out_dir(a: &DemoArgs) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(&a.out)
        .and_then(|()| std::fs::canonicalize(&a.out))
        .with_context(|| {
            format!(
                "cannot make the demo's folder {} (give --out a directory that can be made)",
                a.out.display()
            )
        })
}

pub(super) fn s(p: &Path) -> String {
    p.display().to_string()
}

fn scan_script(
    path: &Path,
    interior: &Path,
    region: [f64; 4],
    out: &Path,
    frames: &str,
) -> anyhow::Result<()> {
    // Relative to the script's directory (as the script reads them): the demo's folder moves.
    let base = path.parent().unwrap_or(Path::new("."));
    let rel = |p: &Path| rig::relative::relative_to(base, p);
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
frames = {frames}
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
            interior = rel(interior).display(),
            frames = frames,
            out = rel(out).display(),
        ),
    )?;
    Ok(())
}

/// The frame camera's demo (the dispatcher, `crate::cli::run`, has checked `a.out` is new).
pub fn run(a: &DemoArgs) -> anyhow::Result<i32> {
    let out = out_dir(a)?;
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
    let (grid, frames, scan_frames) = if a.quick {
        ("3", "4", "4")
    } else {
        ("5", "32", "8")
    };
    // 1. Pixel → carriage.
    let mut args: Vec<String> = vec!["calibrate".into(), "pixel".into()];
    args.extend(sim(1));
    args.extend(["--grid", grid, "--frames", frames, "--json", "--store"].map(String::from));
    args.push(s(&store));
    let pixel: PixelResults = step("pixel → carriage calibration (seed 002)", &args)?;
    // The simulator's block, to place the other photos' scans where they see photo 1's area.
    let dem = jacksboro();
    let block: Vec<AerialPhoto> = PHOTOS
        .iter()
        .map(|&k| AerialPhoto::new(dem.clone(), a.seed, k, 110.0))
        .collect();
    let p1 = &block[0];
    let hs = crate::cli::scene::frame::terrain_range(p1, AREA);
    let regions: Vec<[f64; 4]> = block
        .iter()
        .enumerate()
        .map(|(k, b)| {
            if k == 0 {
                AREA
            } else {
                crate::cli::scene::frame::matching_area(p1, b, AREA, [hs[0] - 30.0, hs[1] + 30.0])
            }
        })
        .collect();
    // 2–3. Each photo's interior orientation on the carriage, then the scan of its part of the
    // overlap: the three photos at once (each step its own simulator, as three rigs would be;
    // a step's lines are printed whole when it ends).
    eprintln!(
        "\n== the {} photos' interior orientations and scans, the photos at once",
        PHOTOS.len()
    );
    let print = std::sync::Mutex::new(());
    let chain = |photo: u32, region: [f64; 4]| -> anyhow::Result<(InteriorResults, PathBuf)> {
        let dir = store.join(format!("interior-photo-{photo}"));
        let mut args: Vec<String> = vec!["calibrate".into(), "interior".into()];
        args.extend(sim(photo));
        args.extend(["--frames", frames, "--json", "--store"].map(String::from));
        args.push(s(&store));
        args.extend(["--out".into(), s(&dir)]);
        let title = format!("interior orientation of photo {photo} (fiducials, seed 002 Table 5)");
        let interior: InteriorResults =
            read_report(&title, &run_step_beside(&title, &args, &print)?)?;
        let script = out.join(format!("scan-photo-{photo}.toml"));
        let scan_dir = out.join(format!("scan-photo-{photo}"));
        scan_script(&script, &dir, region, &scan_dir, scan_frames)?;
        let mut args: Vec<String> = vec!["scan".into()];
        args.extend(sim(photo));
        args.extend(["--json".into(), "run".into(), s(&script)]);
        let title = format!("scan of photo {photo}, region {region:.1?} mm");
        read_report::<serde_json::Value>(&title, &run_step_beside(&title, &args, &print)?)?;
        Ok((interior, scan_dir.join("stereo.json")))
    };
    let chains: Vec<anyhow::Result<(InteriorResults, PathBuf)>> = std::thread::scope(|sc| {
        let running: Vec<_> = PHOTOS
            .iter()
            .zip(&regions)
            .map(|(&photo, &region)| sc.spawn(move || chain(photo, region)))
            .collect();
        running
            .into_iter()
            .zip(PHOTOS)
            .map(|(h, photo)| {
                h.join()
                    .unwrap_or_else(|_| bail!("photo {photo}'s steps stopped unexpectedly"))
            })
            .collect()
    });
    let mut sidecars = Vec::new();
    let mut interiors: Vec<InteriorResults> = Vec::new();
    for c in chains {
        let (interior, sidecar) = c?;
        interiors.push(interior);
        sidecars.push(sidecar);
    }
    // 4. Control and check points in the scanned photos (an operator would measure them; here
    // the simulator's truth plus measuring noise), the true DEM, the project.
    eprintln!("\n== control points, the true DEM and the matching project");
    let grids: Vec<rig::geometry::PhotoGrid> = sidecars
        .iter()
        .map(|f| ScannedPhoto::load(f).map(|(s, _)| s.grid))
        .collect::<Result<_, _>>()?;
    let mut rng = rig_sim::rng::Rng::new(a.seed ^ 0xDE40);
    let mut csv = String::from("id,kind,x,y,z,photo,col,row\n");
    points_csv(&mut csv, &block, &grids, 24, "gcp", &mut rng);
    points_csv(&mut csv, &block, &grids, 30, "cp", &mut rng);
    std::fs::write(out.join("points.csv"), &csv)?;
    let truth = crate::cli::scene::frame::truth_grid(p1, AREA, 10.0)?;
    rig::matching::products::files::write_geotiff(
        &out.join("truth-dem.tif"),
        &truth,
        rig::sim_scene::CRS,
    )?;
    let mut project = format!(
        "# Written by `rig demo`: three scanned photos with approximate orientations (a flight\n\
         # index map's), oriented as one block from the control points and the tie points the rig\n\
         # finds (`rig dtm` does it first, into dtm/orientation/), every pair swept (seed 000), in\n\
         # the simulated world's CRS.\nformat = 2\ncrs = \"{}\"\n",
        rig::sim_scene::CRS
    );
    for (k, f) in sidecars.iter().enumerate() {
        // The flight index map's centre: the true one off by some 20 m, the photo taken as
        // vertical.
        let e = block[k].exterior;
        let c = rig::sim_scene::to_crs([
            e.x0_m + 20.0 * rng.normal(),
            e.y0_m + 20.0 * rng.normal(),
            e.z0_m + 20.0 * rng.normal(),
        ]);
        project.push_str(&format!(
            "\n[[photo]]\nid = \"{}\"\nscan = \"{}\"\nposition = [{:.1}, {:.1}, {:.1}]\nangles_deg = [0, 0, 0]\nposition_sigma_m = 50\nangles_sigma_deg = 3\n",
            PHOTOS[k],
            f.strip_prefix(&out).unwrap_or(f).display(),
            c.x,
            c.y,
            c.z
        ));
    }
    // The DEM covers the ground of photo 1's scanned area, where all three photos overlap and
    // every node gets the median of three pairs.
    let e = {
        let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
        for x in [AREA[0], AREA[2]] {
            for y in [AREA[1], AREA[3]] {
                let g = rig::sim_scene::to_crs(p1.ground_point([x, y]));
                lo = [lo[0].min(g.x), lo[1].min(g.y)];
                hi = [hi[0].max(g.x), hi[1].max(g.y)];
            }
        }
        [lo[0], lo[1], hi[0], hi[1]]
    };
    project.push_str(&format!(
        "\n[points]\nfile = \"points.csv\"\nground_sigma_m = {GROUND_SIGMA_M} # the control points were surveyed by GNSS to {GROUND_SIGMA_M} m (the demo adds that noise)\n\n[dem]\ncell_m = 10.0\nextent = [{:.0}, {:.0}, {:.0}, {:.0}]\nheights = [{:.0}, {:.0}]\n\n\
         [matching]\nmethod = \"{}\"\nwindow = 9\nthreshold = 0.5\nstride = 2 # every second pixel of the 1 m scans: still some 25 points a 10 m node\n\n[check]\nreference = \"truth-dem.tif\"\n",
        e[0],
        e[1],
        e[2],
        e[3],
        hs[0] - 30.0,
        hs[1] + 30.0,
        match a.method {
            Method::Sweep => "sweep",
            Method::Mgcm => "mgcm",
        }
    ));
    std::fs::write(out.join("project.toml"), project)?;
    // 5. The elevation model.
    let dtm_dir = out.join("dtm");
    let args = [
        "dtm".into(),
        s(&out.join("project.toml")),
        "--json".into(),
        "--out".into(),
        s(&dtm_dir),
    ];
    let dtm = match a.method {
        Method::Sweep => Report::Sweep(step(
            "elevation model: the three photos oriented as one block (bundle adjustment), then every pair swept along its mapping functions (seeds 000, 004)",
            &args,
        )?),
        Method::Mgcm => Report::Mgcm(step(
            "elevation model: the three photos oriented as one block (bundle adjustment), then matched at once, geometrically constrained (seed 002)",
            &args,
        )?),
    };
    // The block's orientation, as `rig dtm` wrote it before matching.
    let orientation: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(
        dtm_dir.join("orientation").join("report.json"),
    )?)?;
    let report = json!({
        "orientation": orientation,
        "seed": a.seed,
        "seconds": t0.elapsed().as_secs_f64(),
        "pixel": pixel.calibration.affine,
        "interior": interiors.iter().map(|i| &i.calibration.versions).collect::<Vec<_>>(),
        "scans": sidecars,
        "dtm": dtm,
        "photo_centre_mm": PhotoMm::new(0.0, 0.0),
    });
    rig::digitise::output::write_json(&out.join("report.json"), &report)?;
    demo_page(
        &out,
        a.seed,
        t0.elapsed().as_secs_f64(),
        &pixel,
        &interiors,
        &sidecars,
        &dtm,
    )
    .write(&out.join("report.html"))?;
    println!(
        "\nrig demo (seed {}), {:.0} s, in {}:",
        a.seed,
        t0.elapsed().as_secs_f64(),
        out.display()
    );
    println!("  pixel → carriage: {}", pixel_line(&pixel));
    for (k, i) in interiors.iter().enumerate() {
        let v = i.calibration.versions.first();
        println!(
            "  photo {}: interior orientation ({}), RMS {:.2} µm; scanned at 25 µm → {}",
            k + 1,
            v.map_or("?", |v| v.name.as_str()),
            v.and_then(|v| v.rms_um).unwrap_or(f64::NAN),
            sidecars[k].display()
        );
    }
    let num = |k: &str| orientation[k].as_f64().unwrap_or(f64::NAN);
    println!(
        "  the block: {} photos oriented from {} control and {} tie points the rig found, σ̂₀ {:.2}; check points RMSE XY {:.2} m, Z {:.2} m",
        orientation["photos"],
        orientation["control_points"],
        orientation["tie_points"],
        num("sigma0"),
        orientation["check_rmse_m"][0].as_f64().unwrap_or(f64::NAN),
        orientation["check_rmse_m"][1].as_f64().unwrap_or(f64::NAN),
    );
    match &dtm {
        Report::Sweep(r) => {
            for pr in &r.pairs {
                println!(
                    "  photos {} × {}: step {:.2} m (half a pixel of parallax), {:.1} % of {} points matched, {:.1} % kept after the height and population criteria",
                    pr.left,
                    pr.right,
                    pr.h_step_m,
                    pr.dtm.matched_percent,
                    pr.dtm.points_total,
                    pr.dtm.remaining_percent
                );
            }
        }
        Report::Mgcm(r) => {
            println!(
                "  photo {} against {}: {} of {} points kept ({:.0} points/s)",
                r.reference,
                r.searched.join(", "),
                r.kept,
                r.selected,
                r.points_per_second
            );
            if let Some(acc) = &r.accuracy {
                let v1 = &acc.versions[0];
                println!(
                    "  the points vs the true DEM: RMS {:.3} m ({:.3} px of parallax), max {:.2} m, {} undetected blunders; RMS(error/σ) {:.2} ({:.2} with the bias {:+.2} m)",
                    v1.rms_m,
                    v1.rms_m / r.m_per_px,
                    v1.max_abs_m,
                    acc.undetected,
                    acc.precision.as_ref().map_or(f64::NAN, |p| p.rms_ratio),
                    acc.precision.as_ref().map_or(f64::NAN, |p| p.rms_ratio_with_bias),
                    acc.bias_without_blunders_m
                );
            }
        }
        // The object-space matching has its own figures in its report; the demo asks for the
        // sweep or the MGCM.
        Report::Oslsm(_) => {}
    }
    if let Some(c) = &dtm.model().comparison {
        println!(
            "  elevation model vs the true DEM: RMSE {:.2} m ({:.3} ‰ of the 6 500 m flying height; {:.2} m with the best plane removed: what a tilt of the orientations leaves), mean {:+.2} m, max +{:.2} / {:.2} m over {} nodes; in {}",
            c.rmse_m,
            1000.0 * c.rmse_m / rig_sim::scene::FLYING_HEIGHT_M,
            c.rmse_without_plane_m,
            c.mean_m,
            c.max_positive_m,
            c.max_negative_m,
            c.nodes,
            dtm.crs()
        );
    }
    if let Report::Sweep(dtm) = &dtm {
        if let Some(sv) = &dtm.model.sigma_vs_reference {
            println!(
            "  its standard deviations (quality.tif: the matching's, the terrain the nodes do not resolve{}): RMS {:.2} m; the true errors are {:.2} × them, {:.0} % within 2σ",
            dtm.orientation_sigma_m.map_or(String::new(), |o| format!(", the orientations' {o:.2} m")),
            sv.rms_sigma_m,
            sv.ratio,
            sv.within_2_sigma_percent
        );
            if dtm.orientation_sigma_m.is_some() {
                // The orientations' error moves the whole model at once (a shift, a tilt): a
                // model holds one draw of it, so one seed's ratio says little of σ.
                println!(
                    "    (the orientations' error is one draw for the whole model, here a mean of {:+.2} m: the ratio changes from seed to seed, --seed draws another)",
                    dtm.model.comparison.as_ref().map_or(f64::NAN, |c| c.mean_m)
                );
            }
        }
    }
    println!(
        "  look at: {} (the plots and maps on one page); the model: {}/dem.tif, quality.tif, ortho.tif, points.las; everything: report.json",
        out.join("report.html").display(),
        dtm_dir.display(),
    );
    Ok(0)
}

/// The pixel → carriage calibration against the simulator's values, for the terminal and the
/// page.
fn pixel_line(pixel: &PixelResults) -> String {
    let af = &pixel.calibration;
    format!(
        "x-scale {:.4}, y-scale {:.4}, x-shear {:.4}, y-shear {:.4} µm (simulator: 10.19, 10.96, 0.09, 0.10), RMS {:.3} µm",
        af.x_scale, af.y_scale, af.x_shear, af.y_shear, af.rms_um
    )
}

/// `report.html` of the demo: what each step found, its plots and maps, links to the data. Paths
/// relative to `out`, so the folder can be moved.
fn demo_page(
    out: &std::path::Path,
    seed: u64,
    seconds: f64,
    pixel: &PixelResults,
    interiors: &[InteriorResults],
    sidecars: &[PathBuf],
    dtm: &Report,
) -> rig::matching::products::html::Page {
    use rig::matching::products::html::{Page, Section};
    let rel = |p: &std::path::Path| {
        p.strip_prefix(out)
            .unwrap_or(p)
            .to_string_lossy()
            .into_owned()
    };
    let mut calibration = Section {
        heading: "Calibration".into(),
        rows: vec![("pixel → carriage".into(), pixel_line(pixel))],
        pictures: vec![(
            rel(&pixel.session.join("residuals-affine.png")),
            "pixel → carriage: residuals of the affine fit".into(),
        )],
        ..Default::default()
    };
    for (k, i) in interiors.iter().enumerate() {
        if let Some(v) = i.calibration.versions.first() {
            calibration.rows.push((
                format!("photo {}: interior orientation", PHOTOS[k]),
                format!(
                    "{} fiducials, RMS {:.2} µm",
                    v.name,
                    v.rms_um.unwrap_or(f64::NAN)
                ),
            ));
            calibration.pictures.push((
                rel(&i.session.join(format!("residuals-{}.png", v.name))),
                format!(
                    "photo {}: carriage → photo residuals at the fiducials",
                    PHOTOS[k]
                ),
            ));
        }
    }
    let scans = Section {
        heading: "Scans".into(),
        pictures: sidecars
            .iter()
            .enumerate()
            .map(|(k, f)| {
                (
                    rel(&f.with_extension("png")),
                    format!("photo {}: the scanned overlap at 25 µm", PHOTOS[k]),
                )
            })
            .collect(),
        links: sidecars
            .iter()
            .map(|f| {
                (
                    rel(f),
                    "the scan's hand-over (image, grid, interior orientation)".into(),
                )
            })
            .collect(),
        ..Default::default()
    };
    let model = Section {
        heading: "Elevation model".into(),
        rows: dtm.summary(),
        pictures: [
            ("hillshade.png", "heights, shaded"),
            ("error.png", "the model minus the true DEM"),
            ("quality.png", "each node's standard deviation"),
        ]
        .iter()
        .map(|(f, c)| (format!("dtm/{f}"), (*c).to_string()))
        .collect(),
        links: vec![
            (
                "dtm/report.html".into(),
                "the elevation model's own page".into(),
            ),
            ("dtm/dem.tif".into(), "heights, GeoTIFF".into()),
            (
                "dtm/orientation/report.html".into(),
                "the block's orientation: residuals, check points, blunders".into(),
            ),
            (
                "project.toml".into(),
                "the matching project (format 2)".into(),
            ),
            ("points.csv".into(), "control and check points".into()),
            ("report.json".into(), "everything, for scripts".into()),
        ],
    };
    Page {
        title: "rig demo".into(),
        intro: format!(
            "The whole chain on the simulator (seed {seed}, {seconds:.0} s): calibrate the rig, orient and scan three overlapping photos, orient them as a block, compute their elevation model, compare it with the true DEM."
        ),
        sections: vec![calibration, scans, model],
    }
}

/// Appends `n` points of photo 1's scanned area to the points file: their ground (in the
/// world's CRS) and their place in every photo that sees them, with measuring noise
/// ([`MEASURING_SIGMA_MM`] on the film, [`GROUND_SIGMA_M`] on the ground). Pixels in the convention of docs/conventions.md (integer values at pixel
/// centres; the scans' grids count from the corner). Control points on a jittered grid that
/// reaches the area's edges, check points anywhere inside.
fn points_csv(
    csv: &mut String,
    block: &[AerialPhoto],
    grids: &[rig::geometry::PhotoGrid],
    n: usize,
    kind: &str,
    rng: &mut rig_sim::rng::Rng,
) {
    use rig::coords::PixelXY;
    use std::fmt::Write as _;
    let g0 = &grids[0];
    let side = (n as f64).sqrt().ceil() as usize;
    for k in 0..n {
        let (u, w) = if kind == "gcp" {
            let (i, j) = (k % side, k / side);
            let f = |t: usize, r: f64| {
                (0.03 + 0.94 * (t as f64 + 0.25 * (r - 0.5)) / (side - 1) as f64).clamp(0.02, 0.98)
            };
            (f(i, rng.uniform()), f(j, rng.uniform()))
        } else {
            (0.05 + 0.9 * rng.uniform(), 0.05 + 0.9 * rng.uniform())
        };
        let p = g0.photo(PixelXY::new(u * g0.width as f64, w * g0.height as f64));
        let g = block[0].ground_point([p.x, p.y]);
        let noisy = [
            g[0] + GROUND_SIGMA_M * rng.normal(),
            g[1] + GROUND_SIGMA_M * rng.normal(),
            g[2] + GROUND_SIGMA_M * rng.normal(),
        ];
        let world = rig::sim_scene::to_crs(noisy);
        for (i, (b, grid)) in block.iter().zip(grids).enumerate() {
            let q = b.project(g);
            let px = grid.pixel(PhotoMm::new(q[0], q[1]));
            let inside = px.col > 1.0
                && px.row > 1.0
                && px.col < grid.width as f64 - 1.0
                && px.row < grid.height as f64 - 1.0;
            if !inside {
                continue;
            }
            let e = MEASURING_SIGMA_MM / grid.step_mm;
            let _ = writeln!(
                csv,
                "{kind}{},{kind},{:.3},{:.3},{:.3},{},{:.3},{:.3}",
                k + 1,
                world.x,
                world.y,
                world.z,
                PHOTOS[i],
                px.col - 0.5 + e * rng.normal(),
                px.row - 0.5 + e * rng.normal()
            );
        }
    }
}
