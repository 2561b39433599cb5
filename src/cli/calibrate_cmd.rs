//! `rig calibrate`: calibration sessions on the rig or on the simulator.

use super::connect::{connect, Hardware};
use super::usage::usage_bail;
use anyhow::{bail, Context};
use clap::{Args, Subcommand};
use rig::calibrate::run::{Finished, Hands, InteriorJob, PixelJob, SessionError};
use rig::calibrate::{
    InteriorOptions, InteriorOrientation, PixelCalibration, PixelOptions, Session,
};
use std::path::PathBuf;

/// Options of `rig calibrate` (its help text is on `Command::Calibrate`).
#[derive(Debug, Args)]
pub struct CalibrateArgs {
    #[command(flatten)]
    pub conn: super::connect::ConnectArgs,
    #[command(flatten)]
    pub sessions: super::shared_args::SessionStore,
    #[command(flatten)]
    pub output: super::shared_args::JsonOutput,
    #[command(subcommand)]
    pub action: CalibrateAction,
}

#[derive(Debug, Subcommand)]
pub enum CalibrateAction {
    /// The pixel→carriage transformation: the central cross through a 5×5 grid of image
    /// positions, then every cross under the measuring mark.
    Pixel {
        /// The carriage plate's certificate (TOML; see docs/calibration.md). With --sim: the
        /// simulator's own, written into the session.
        #[arg(long, value_name = "FILE")]
        plate_cert: Option<PathBuf>,
        /// The session directory (default: a new one in --store).
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Frames averaged at each position.
        #[arg(long, default_value_t = 32)]
        frames: u32,
        /// Positions per side of the grid.
        #[arg(long, default_value_t = 5)]
        grid: usize,
        /// Nominal pixel spacing to start from, µm (x,y): the first look measures it.
        #[arg(long, value_name = "X,Y", default_value = "10,10")]
        pixel_um: String,
        /// Do not home first (the stage must already be homed).
        #[arg(long)]
        no_home: bool,
        /// Only the 5×5 grid: skip the crosses that locate the measuring mark.
        #[arg(long)]
        grid_only: bool,
        /// No flat field (by default one is taken on clear plate glass first, and every image
        /// of this session and of the interior sessions that use it is divided by it).
        #[arg(long)]
        no_flat: bool,
    },
    /// Compare the newest pixel session with the earlier ones in --store: scales, shears, the
    /// measuring mark's pixel (seed 002, Tables 2 and 3); changes beyond the thresholds are
    /// flagged as drift (exit code 10).
    History {
        /// Drift threshold for scales, µm per px.
        #[arg(long, default_value_t = 0.005)]
        scale_um: f64,
        /// Drift threshold for shears, µm per px.
        #[arg(long, default_value_t = 0.01)]
        shear_um: f64,
        /// Drift threshold for the measuring mark, px.
        #[arg(long, default_value_t = 0.3)]
        mark_px: f64,
    },
    /// The interior orientation: find and measure the film's fiducials, fit carriage→image
    /// with all fiducials, the corners only and the mid-sides only (seed 002, Table 5).
    Interior {
        /// The film camera's certificate (TOML; see docs/calibration.md). With --sim: the simulator's
        /// own, written into the session.
        #[arg(long, value_name = "FILE")]
        camera_cert: Option<PathBuf>,
        /// The pixel session whose pixel→carriage transformation to use (default: the newest
        /// in --store).
        #[arg(long, value_name = "DIR")]
        pixel_session: Option<PathBuf>,
        /// Where the film's centre lies on the carriage, roughly (mm): the search starts there.
        #[arg(long, value_name = "X,Y", default_value = "125,125")]
        film_centre: String,
        /// The session directory (default: a new one in --store).
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Frames averaged at each fiducial.
        #[arg(long, default_value_t = 32)]
        frames: u32,
        /// Do not home first (the stage must already be homed).
        #[arg(long)]
        no_home: bool,
    },
}

/// Two positive numbers X,Y (a spacing, a position on the carriage).
fn parse_pair(s: &str, what: &str) -> anyhow::Result<[f64; 2]> {
    match super::camera_cmd::parse_pair(s, what)? {
        (x, y) if x > 0.0 && y > 0.0 => Ok([x, y]),
        _ => usage_bail!("{what} `{s}`: two positive numbers X,Y"),
    }
}

/// Creates the session's folder (in --store unless --out) and connects the hardware (the
/// simulator keeps its truth in the session).
fn begin(
    a: &CalibrateArgs,
    out: &Option<PathBuf>,
    kind: &str,
    film: bool,
) -> anyhow::Result<(Session, Hardware)> {
    let session = match out {
        Some(d) => Session::create(d),
        None => Session::new_in_store(&a.sessions.store, kind),
    }
    .with_context(|| {
        format!(
            "creating the session directory in {}",
            out.as_deref().unwrap_or(&a.sessions.store).display()
        )
    })?;
    let hw = connect(
        &a.conn,
        Some(session.dir.join("sim-truth.json")),
        film,
        &Default::default(),
    )?;
    Ok((session, hw))
}

/// Runs one session (rig::calibrate::run) with a progress display, closes the hardware, and
/// prints the results (`--json`: the results document; else `print` of the calibration and
/// its session's folder). The calibration's own error comes first; a failure to close the
/// hardware after it is reported as well, never instead.
fn run_session<T>(
    a: &CalibrateArgs,
    hw: Hardware,
    body: impl FnOnce(Hands) -> Result<Finished<T>, SessionError>,
    print: impl FnOnce(&T, &std::path::Path),
) -> anyhow::Result<i32> {
    let Finished {
        calibration,
        results,
        dir,
    } = run_closing(a, hw, body)?;
    if a.output.json {
        println!("{results}");
    } else {
        print(&calibration, &dir);
    }
    Ok(0)
}

/// [`run_session`]'s run: the session with a progress display, then the hardware closed.
fn run_closing<T>(
    a: &CalibrateArgs,
    mut hw: Hardware,
    body: impl FnOnce(Hands) -> Result<Finished<T>, SessionError>,
) -> anyhow::Result<Finished<T>> {
    let mut steps = super::progress_bar::Steps::new(a.output.json);
    let mut progress = |st: rig::calibrate::pixel::Step<'_>| steps.step(st.what, st.of);
    let r = body(Hands {
        stage: hw.stage.as_mut(),
        camera: hw.camera.as_mut(),
        progress: &mut progress,
        interrupt: None,
        seen: None,
    });
    steps.finish();
    let closed = hw.close();
    if let (Err(_), Err(c)) = (&r, &closed) {
        eprintln!("rig: also, closing the hardware failed: {c:#}");
    }
    let done = r.map_err(|e| match e {
        SessionError::Calibrate { .. } => anyhow::Error::new(e)
            .context("calibration failed (stored as failed, not used as the latest)"),
        e => e.into(),
    })?;
    closed?;
    Ok(done)
}

fn check_frames(frames: u32) -> anyhow::Result<()> {
    if frames == 0 || frames > 1024 {
        usage_bail!("--frames {frames} is out of range: use 1 to 1024");
    }
    Ok(())
}

/// Runs `rig calibrate`; returns the exit code.
pub fn run(a: CalibrateArgs) -> anyhow::Result<i32> {
    match &a.action {
        CalibrateAction::Pixel {
            plate_cert,
            out,
            frames,
            grid,
            pixel_um,
            no_home,
            grid_only,
            no_flat,
        } => {
            check_frames(*frames)?;
            if !(2..=15).contains(grid) {
                usage_bail!("--grid {grid} is out of range: use 2 to 15");
            }
            let nominal = parse_pair(pixel_um, "--pixel-um")?;
            if plate_cert.is_none() && !a.conn.sim.on {
                usage_bail!("--plate-cert FILE is needed (the carriage plate's certificate; docs/calibration.md shows its format)");
            }
            let (session, hw) = begin(&a, out, "pixel", false)?;
            let cert_path = match (plate_cert, &hw.sim) {
                (Some(p), _) => p.clone(),
                (None, Some(s)) => session
                    .keep_certificate(
                        "plate-cert.toml",
                        &rig_sim::certificates::plate_certificate(&s.world.plate, s.world.seed),
                    )
                    .with_context(|| {
                        format!("writing plate-cert.toml in {}", session.dir.display())
                    })?,
                (None, None) => unreachable!("checked above"),
            };
            let job = PixelJob {
                plate_certificate: cert_path,
                options: PixelOptions {
                    frames: *frames,
                    grid: *grid,
                    nominal_um_per_px: nominal,
                    home: !no_home,
                    all_crosses: !grid_only,
                    flat_field: !no_flat,
                    ..Default::default()
                },
                sim: a.conn.sim.on,
            };
            run_session(
                &a,
                hw,
                |hands| rig::calibrate::run::pixel(session, hands, &job),
                print_pixel,
            )
        }
        CalibrateAction::History {
            scale_um,
            shear_um,
            mark_px,
        } => {
            for (name, v) in [
                ("--scale-um", scale_um),
                ("--shear-um", shear_um),
                ("--mark-px", mark_px),
            ] {
                if v.is_nan() || *v <= 0.0 {
                    usage_bail!("{name} {v}: a positive threshold");
                }
            }
            let dirs = rig::calibrate::session::list(&a.sessions.store, "pixel")?;
            if dirs.is_empty() {
                bail!(
                    "no pixel sessions in {}: run `rig calibrate pixel` (or give --store DIR)",
                    a.sessions.store.display()
                );
            }
            let h = rig::calibrate::history::history(
                &dirs,
                rig::calibrate::history::DriftThresholds {
                    scale_um: *scale_um,
                    shear_um: *shear_um,
                    mark_px: *mark_px,
                },
            )
            .map_err(anyhow::Error::msg)?;
            let drift = h.newest_vs.first().is_some_and(|c| !c.drift.is_empty());
            if a.output.json {
                println!("{}", serde_json::to_string(&h)?);
            } else {
                print_history(&h);
            }
            Ok(if drift {
                rig::exit::DRIFT
            } else {
                rig::exit::OK
            })
        }
        CalibrateAction::Interior {
            camera_cert,
            pixel_session,
            film_centre,
            out,
            frames,
            no_home,
        } => {
            check_frames(*frames)?;
            let centre = parse_pair(film_centre, "--film-centre")?;
            if camera_cert.is_none() && !a.conn.sim.on {
                usage_bail!("--camera-cert FILE is needed (the film camera's certificate with its fiducials; docs/calibration.md shows its format)");
            }
            let pixel_dir = match pixel_session {
                Some(d) => d.clone(),
                None => rig::calibrate::session::list(&a.sessions.store, "pixel")?
                    .pop()
                    .with_context(|| {
                        format!(
                            "no pixel session in {}: run `rig calibrate pixel` first, or name one with --pixel-session DIR",
                            a.sessions.store.display()
                        )
                    })?,
            };
            // Read before a session folder is made or the hardware opened.
            rig::calibrate::documents::pixel_transform(&pixel_dir)?;
            let (session, hw) = begin(&a, out, "interior", true)?;
            let cert_path = match (camera_cert, &hw.sim) {
                (Some(p), _) => p.clone(),
                (None, Some(s)) => {
                    let film = s
                        .world
                        .film
                        .as_ref()
                        .expect("the simulator was started with a film");
                    session
                        .keep_certificate(
                            "camera-cert.toml",
                            &rig_sim::certificates::camera_certificate(film, s.world.seed),
                        )
                        .with_context(|| {
                            format!("writing camera-cert.toml in {}", session.dir.display())
                        })?
                }
                (None, None) => unreachable!("checked above"),
            };
            let job = InteriorJob {
                camera_certificate: cert_path,
                pixel_session: pixel_dir,
                options: InteriorOptions {
                    frames: *frames,
                    film_centre: rig::coords::CarriageUm::from_mm(centre[0], centre[1]),
                    ..Default::default()
                },
                home: !no_home,
                film_centre_mm: centre,
                sim: a.conn.sim.on,
            };
            run_session(
                &a,
                hw,
                |hands| rig::calibrate::run::interior(session, hands, &job),
                print_interior,
            )
        }
    }
}

fn print_history(h: &rig::calibrate::history::History) {
    println!("pixel → carriage sessions (seed 002, Tables 2 and 3):");
    println!(
        "  {:<34} {:>9} {:>9} {:>8} {:>8} {:>6}  {:>17}",
        "session", "x-scale", "y-scale", "x-shear", "y-shear", "RMS", "mark (col, row)"
    );
    for s in &h.sessions {
        let name = s.session.file_name().map_or_else(
            || s.session.display().to_string(),
            |n| n.to_string_lossy().to_string(),
        );
        println!(
            "  {:<34} {:>9.4} {:>9.4} {:>8.4} {:>8.4} {:>6.2}  {}",
            name,
            s.x_scale,
            s.y_scale,
            s.x_shear,
            s.y_shear,
            s.rms_um,
            s.mark
                .map_or("—".into(), |m| format!("{:.3}, {:.3}", m[0], m[1]))
        );
    }
    for c in &h.newest_vs {
        let name = c.earlier.file_name().map_or_else(
            || c.earlier.display().to_string(),
            |n| n.to_string_lossy().to_string(),
        );
        if c.drift.is_empty() {
            println!("newest vs {name}: no drift");
        } else {
            println!("newest vs {name}: DRIFT");
            for d in &c.drift {
                println!("  {d}");
            }
        }
    }
}

fn print_interior(c: &InteriorOrientation, dir: &std::path::Path) {
    if let Some(t) = &c.matching {
        rig::targets::measure::print_match_table(t, "fiducials, coarse → fine matching");
    }
    println!("fiducials:");
    for f in &c.fiducials {
        match (&f.carriage_um, &f.missing) {
            (Some(cu), None) => println!(
                "  {} ({:?}) at carriage ({:.4}, {:.4}) mm",
                f.id,
                f.group,
                cu.x_mm(),
                cu.y_mm()
            ),
            (_, why) => println!(
                "  {} ({:?}): left out — {}",
                f.id,
                f.group,
                why.as_deref().unwrap_or("not measured")
            ),
        }
    }
    println!("carriage → image (affine), residuals in µm:");
    for v in &c.versions {
        match &v.fit {
            Some(fit) => {
                println!(
                    "  {:<9} RMS {:.2} µm over {} fiducials",
                    v.name,
                    fit.rms_total(),
                    v.fiducials.len()
                );
                for r in &fit.residuals {
                    println!(
                        "    {:>3}: vx {:+6.2}  vy {:+6.2}{}",
                        r.id,
                        r.v[0],
                        r.v[1],
                        if r.w > rig::calibrate::affine_fit::OUTLIER_W {
                            "  ← outlier?"
                        } else {
                            ""
                        }
                    );
                }
            }
            None => println!(
                "  {:<9} not fitted: {}",
                v.name,
                v.error.as_deref().unwrap_or("")
            ),
        }
    }
    println!("session: {}", dir.display());
}

fn print_pixel(c: &PixelCalibration, dir: &std::path::Path) {
    let used = c
        .grid
        .iter()
        .filter(|o| o.result.centre().is_some())
        .count();
    if let Some(t) = &c.matching {
        rig::targets::measure::print_match_table(t, "crosses, coarse → fine matching");
    }
    println!(
        "pixel → carriage ({used} of {} grid positions used)",
        c.grid.len()
    );
    println!(
        "  x-scale {:.4} µm  y-scale {:.4} µm  x-shear {:.4} µm  y-shear {:.4} µm  RMS {:.2} µm",
        c.x_scale, c.y_scale, c.x_shear, c.y_shear, c.rms_um
    );
    for o in c.grid.iter().chain(&c.crosses) {
        if let Some(why) = &o.result.rejected {
            println!("  {}: left out — {why}", o.id);
        }
    }
    for r in c.affine.residuals.iter().filter(|r| r.rejected) {
        println!("  {}: rejected as an outlier (w = {:.1})", r.id, r.w);
    }
    if let Some(m) = &c.mark {
        println!(
            "measuring mark at pixel ({:.3}, {:.3}) ± ({:.3}, {:.3}) from {} crosses; from the affine ({:.3}, {:.3})",
            m.mean.col, m.mean.row, m.std[0], m.std[1], m.per_cross.len(), m.from_affine.col, m.from_affine.row
        );
    }
    if let Some(l) = &c.linear4 {
        println!(
            "4-parameter variant (centred at the mark): RMS {:.2} µm, residual sums ({:+.2}, {:+.2}) µm",
            l.rms_total(),
            l.residual_sum[0],
            l.residual_sum[1]
        );
    }
    println!("session: {}", dir.display());
}
