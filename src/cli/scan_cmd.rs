//! `rig scan`: plan a scripted film scan, run it (pause, resume), mosaic it again.

use super::connect::{connect, ConnectArgs};
use anyhow::Context;
use clap::{Args, Subcommand};
use rig::scan::run::{Outcome, Progress, Reopen, RunOptions, ScanRig};
use rig::scan::{plan, Plan, ScanCalibration, ScanDir, ScanScript};
use serde_json::json;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// Exit code of a scan paused by Ctrl-C.
pub const EXIT_PAUSED: i32 = rig::exit::PAUSED;
/// Exit code of a plan refused (soft limits, frame size).
pub const EXIT_REFUSED: i32 = rig::exit::OUTSIDE_LIMITS;

/// The command that continues this scan: the same hardware (or simulator), store and
/// script, with --resume — what the operator can paste.
fn resume_command(a: &ScanArgs, script: &std::path::Path, out: Option<&std::path::Path>) -> String {
    let mut c = String::from("rig scan");
    let c_ = &a.conn;
    if c_.sim.on {
        c += &format!(
            " --sim --sim-seed {} --sim-photo {}",
            c_.sim.seed, c_.sim_photo
        );
    } else {
        if let Some(p) = &c_.port.stage {
            c += &format!(" --stage {}", p.display());
        }
        if let Some(d) = c_.port.dialect {
            c += &format!(" --dialect {}", format!("{d:?}").to_lowercase());
        }
        if let Some(cam) = &c_.camera.device {
            c += &format!(" --camera {cam}");
        }
    }
    c += &format!(
        " --store {} run {} --resume",
        a.sessions.store.display(),
        script.display()
    );
    if let Some(o) = out {
        c += &format!(" --out {}", o.display());
    }
    c
}

#[derive(Debug, Args)]
pub struct ScanArgs {
    #[command(flatten)]
    pub conn: ConnectArgs,
    #[command(flatten)]
    pub sessions: super::shared_args::SessionStore,
    #[command(flatten)]
    pub output: super::shared_args::JsonOutput,
    /// Refuse a region whose mosaic would need more memory than this (MiB): the plan says
    /// how much each needs before anything is allocated.
    #[arg(long, value_name = "MIB", global = true, default_value_t = rig::scan::plan::DEFAULT_MAX_MEMORY_MIB,
          value_parser = clap::value_parser!(u64).range(16..=1_048_576))]
    pub max_memory: u64,
    #[command(subcommand)]
    pub action: ScanAction,
}

#[derive(Debug, Subcommand)]
pub enum ScanAction {
    /// Tile the script's regions, check every stage position against the soft limits, and
    /// estimate the time and the bytes. Nothing moves; no hardware is needed (the calibration
    /// sessions recorded the rig).
    Plan {
        /// The scan script (TOML; see docs/scanning.md).
        script: PathBuf,
        /// Also draw the plan (frame, fiducials, tiles, the stage's path, regions, the flat
        /// field's spot) into this PNG.
        #[arg(long, value_name = "FILE.png")]
        plot: Option<PathBuf>,
    },
    /// Run the scan: home, flat field, every tile (checkpointed as it is taken), then the
    /// photos. Ctrl-C pauses at the next tile boundary (a second Ctrl-C quits at once);
    /// --resume continues a paused, crashed or killed scan where it stopped.
    Run {
        /// The scan script (TOML; see docs/scanning.md).
        script: PathBuf,
        /// Continue the scan already in the output directory.
        #[arg(long)]
        resume: bool,
        /// Write the scan here instead of the script's [output] dir.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Do not home first (the stage must already be homed).
        #[arg(long)]
        no_home: bool,
    },
    /// Mosaic the photos again from a scan directory's tiles.
    ///
    /// With --tile I/N --out SHARE_DIR only share I of N of the scan's photos is mosaicked,
    /// into SHARE_DIR (for a cluster or several machines); `rig scan merge` puts all shares'
    /// photos into the scan directory, byte for byte those of one `rig scan mosaic DIR`.
    ///
    /// Examples:
    ///   rig scan mosaic film-1
    ///   for i in 1 2 3; do rig scan mosaic film-1 --tile $i/3 --out shares/$i & done; wait
    ///   rig scan merge shares/*
    #[command(verbatim_doc_comment)]
    Mosaic {
        /// The scan directory.
        dir: PathBuf,
        /// Mosaic only share I of N of the photos (I counts from 1); needs --out.
        #[arg(long, value_name = "I/N", requires = "out")]
        tile: Option<rig::matching::methods::sweep::tiles::TileSpec>,
        /// The share's directory (with --tile).
        #[arg(long, value_name = "SHARE_DIR", requires = "tile")]
        out: Option<PathBuf>,
    },
    /// Put the photos of all shares of `rig scan mosaic DIR --tile I/N --out SHARE_DIR` (all N,
    /// any order) into the scan directory, after checking every file against its hash.
    ///
    /// Example:
    ///   rig scan merge shares/1 shares/2 shares/3
    #[command(verbatim_doc_comment)]
    Merge {
        /// The shares' directories.
        #[arg(value_name = "SHARE_DIR", required = true, num_args = 1..)]
        shares: Vec<PathBuf>,
        /// The scan directory (default: the one the shares were mosaicked from).
        #[arg(long, value_name = "DIR")]
        into: Option<PathBuf>,
    },
}

/// The script's calibration; the operator's --limits tighten the recorded soft limits.
fn calibration(a: &ScanArgs, s: &ScanScript) -> anyhow::Result<ScanCalibration> {
    Ok(ScanCalibration::for_script(
        s,
        &a.sessions.store,
        a.conn.port.limits.as_ref(),
    )?)
}

fn duration(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    match s {
        0..=59 => format!("{s} s"),
        60..=3599 => format!("{} min {:02} s", s / 60, s % 60),
        _ => format!("{} h {:02} min", s / 3600, (s % 3600) / 60),
    }
}

fn megabytes(b: u64) -> String {
    format!("{:.1} MB", b as f64 / 1e6)
}

fn print_plan(s: &ScanScript, cal: &ScanCalibration, p: &Plan) {
    println!("scan plan: film \"{}\" ({})", s.film_name, s.path.display());
    println!(
        "  calibration: interior session {} ({} fiducials, RMS {:.2} µm), pixel session {}",
        cal.interior_session.display(),
        cal.version.name(),
        cal.rms_um,
        cal.pixel_session.display()
    );
    println!(
        "  tiles: {:.2} × {:.2} mm of the photo each, {:.0} % overlap, {} frames, filter {}",
        2.0 * p.tile_half_mm[0],
        2.0 * p.tile_half_mm[1],
        100.0 * s.capture.overlap,
        s.capture.frames,
        match s.capture.filter {
            rig::scan::script::Filter::Stripes => "stripes",
            rig::scan::script::Filter::None => "none",
        }
    );
    for (ri, r) in p.regions.iter().enumerate() {
        let e = r.grid.extent_mm();
        println!(
            "  region {}: photo x {:.2}…{:.2}, y {:.2}…{:.2} mm → {} × {} px at {} µm; {} × {} = {} tiles",
            r.name,
            e[0],
            e[2],
            e[1],
            e[3],
            r.grid.width,
            r.grid.height,
            s.resolution_um,
            r.cols,
            r.rows,
            p.tiles.iter().filter(|t| t.region == ri).count()
        );
    }
    if p.flat_stage_um.is_some() {
        let [x, y] = s.capture.flat_photo_mm;
        println!("  flat field: clear film base at photo ({x:.1}, {y:.1}) mm");
    }
    let l = &cal.rig.limits;
    println!(
        "  soft limits: all {} stage positions inside X {:.1}…{:.1}, Y {:.1}…{:.1} mm",
        p.tiles.len() + p.flat_stage_um.is_some() as usize,
        l.min.x_mm(),
        l.max.x_mm(),
        l.min.y_mm(),
        l.max.y_mm()
    );
    let e = &p.estimate;
    println!(
        "  estimate: {} (homing at most {}, the drive from the home corner {}, {} frames/s{}, stage travel {:.0} mm; processing not included); {} of tiles, {} of photos; mosaicking takes up to {} MiB of memory",
        duration(e.seconds),
        duration(e.homing_s),
        duration(e.first_drive_s),
        e.frame_rate_hz,
        if e.frame_rate_assumed { ", assumed" } else { "" },
        e.travel_mm,
        megabytes(e.tile_bytes),
        megabytes(e.mosaic_bytes),
        e.mosaic_mib
    );
    println!("  output: {}", s.out_dir.display());
}

/// A scan directory opened to mosaic its photos, with a warning when tiles are missing.
fn open_for_mosaic(dir: &std::path::Path, max_memory_mib: u64) -> anyhow::Result<ScanDir> {
    let sd = ScanDir::open(
        dir,
        &Reopen {
            limits: None,
            max_memory_mib,
        },
    )?;
    let (done, total) = (sd.manifest.done(), sd.manifest.tiles.len());
    if done < total {
        eprintln!("rig: only {done} of {total} tiles are taken: the photos have holes (nodata 0) where the others belong");
    }
    Ok(sd)
}

/// A photo's mosaic, band `b` of `n` done, on the bar.
fn mosaic_progress(bar: &super::progress_bar::Bar, region: &str, b: usize, n: usize) {
    use rig::matching::progress::Progress as _;
    if b == 1 {
        bar.begin(&format!("mosaic of {region} (bands)"), n as u64);
    }
    bar.advance(1);
    if b == n {
        bar.end();
    }
}

/// Draws the tiles' progress (a bar on a terminal, a line per tile otherwise, nothing with
/// --json off a terminal).
fn progress_printer(json: bool) -> impl FnMut(Progress) {
    let mut steps = super::progress_bar::Steps::new(json);
    move |p: Progress| {
        if p.tile.is_empty() {
            return;
        }
        steps.step(
            &format!(
                "tile {}/{} {} ({} left)",
                p.done,
                p.total,
                p.tile,
                duration(p.eta_s)
            ),
            // The tiles taken so far are done: the bar stands at the next.
            Some((p.done + 1, p.total.max(p.done))),
        );
    }
}

pub fn run(a: ScanArgs) -> anyhow::Result<i32> {
    match &a.action {
        ScanAction::Plan { script, plot } => {
            let s = ScanScript::load(script)?;
            let cal = calibration(&a, &s)?;
            let p = match plan(&s, &cal, a.max_memory) {
                Ok(p) => p,
                Err(e) => {
                    eprintln!("rig: plan refused: {e}");
                    return Ok(EXIT_REFUSED);
                }
            };
            if let Some(f) = plot {
                rig::scan::plan_plot::plan_plot(&p, &cal, s.capture.flat_photo_mm, f)
                    .with_context(|| format!("writing {}", f.display()))?;
            }
            if a.output.json {
                println!(
                    "{}",
                    json!({"script": s.path, "out": s.out_dir, "calibration": cal, "plan": p})
                );
            } else {
                print_plan(&s, &cal, &p);
                println!("nothing moved.");
            }
            Ok(0)
        }
        ScanAction::Run {
            script,
            resume,
            out,
            no_home,
        } => {
            // A resumed scan keeps the calibration it began with (calibration.json in its
            // directory), whatever the sessions hold now.
            let mut s = ScanScript::load(script)?;
            if let Some(o) = out {
                s.out_dir = o.clone();
            }
            let dir = s.out_dir.clone();
            let mut sd = if *resume {
                let check = Reopen {
                    limits: a.conn.port.limits,
                    max_memory_mib: a.max_memory,
                };
                match ScanDir::resume(&dir, s, &check) {
                    Ok(sd) => sd,
                    Err(rig::scan::ScanError::Plan(e)) => {
                        eprintln!("rig: resume refused, nothing moved: {e}");
                        return Ok(EXIT_REFUSED);
                    }
                    Err(e) => return Err(e.into()),
                }
            } else {
                let cal = calibration(&a, &s)?;
                let p = match plan(&s, &cal, a.max_memory) {
                    Ok(p) => p,
                    Err(e) => {
                        eprintln!("rig: plan refused, nothing moved: {e}");
                        return Ok(EXIT_REFUSED);
                    }
                };
                ScanDir::create(&dir, s, cal, p)?
            };
            let pause = Arc::new(AtomicBool::new(false));
            // A first Ctrl-C asks for a pause at the next tile boundary; a second quits.
            signal_hook::flag::register_conditional_shutdown(
                signal_hook::consts::SIGINT,
                130,
                pause.clone(),
            )?;
            signal_hook::flag::register(signal_hook::consts::SIGINT, pause.clone())?;
            let mut hw = connect(
                &a.conn,
                Some(dir.join("sim-truth.json")),
                true,
                &Default::default(),
            )?;
            let tty = std::io::stderr().is_terminal();
            let mut show = progress_printer(a.output.json);
            let r = rig::scan::run::run(
                &mut sd,
                &mut ScanRig {
                    stage: hw.stage.as_mut(),
                    camera: hw.camera.as_mut(),
                },
                &RunOptions {
                    home: !no_home,
                    pause: &pause,
                    frame_timeout: std::time::Duration::from_secs(5),
                },
                &mut show,
            );
            if tty {
                eprintln!();
            }
            if let Err(e) = &r {
                let _ = sd.log.stop("failed", Some(&e.to_string()));
            }
            // The scan's own error comes first: a failure to shut the simulator down after it
            // is reported as well, never instead.
            let closed = hw.close();
            if let (Err(_), Err(c)) = (&r, &closed) {
                eprintln!("rig: also, closing the hardware failed: {c:#}");
            }
            let outcome = r.with_context(|| {
                format!(
                    "the scan stopped; every tile taken so far is kept in {} — fix the cause and continue with: {}",
                    dir.display(),
                    resume_command(&a, script, out.as_deref())
                )
            })?;
            closed?;
            match outcome {
                Outcome::Complete { photos } => {
                    if a.output.json {
                        println!(
                            "{}",
                            json!({"status": "complete", "dir": dir, "photos": photos, "tiles": sd.manifest.tiles.len()})
                        );
                    } else {
                        println!(
                            "scan complete: {} tiles in {}",
                            sd.manifest.tiles.len(),
                            dir.display()
                        );
                        for p in photos {
                            println!("  photo {} (+ .tiff, .png preview)", p.display());
                        }
                    }
                    Ok(0)
                }
                Outcome::Paused { done, total } => {
                    if a.output.json {
                        println!(
                            "{}",
                            json!({"status": "paused", "dir": dir, "done": done, "total": total})
                        );
                    } else {
                        println!(
                            "scan paused after {done} of {total} tiles; continue with: {}",
                            resume_command(&a, script, out.as_deref())
                        );
                    }
                    Ok(EXIT_PAUSED)
                }
            }
        }
        ScanAction::Merge { shares, into } => {
            let (dir, photos) = rig::scan::mosaic_shares::merge_shares(shares, into.as_deref())?;
            if a.output.json {
                println!("{}", json!({"dir": dir, "photos": photos}));
            } else {
                for p in photos {
                    println!("photo {} (+ .tiff, .png)", p.display());
                }
            }
            Ok(0)
        }
        ScanAction::Mosaic {
            dir,
            tile: Some(spec),
            out: Some(out),
        } => {
            let sd = open_for_mosaic(dir, a.max_memory)?;
            let bar = super::progress_bar::Bar::new(!a.output.json);
            let m = rig::scan::mosaic_shares::mosaic_share(
                &sd,
                *spec,
                out,
                rig::scan::mosaic::Interpolation::Bicubic,
                &|r, b, n| mosaic_progress(&bar, r, b, n),
            )?;
            if a.output.json {
                println!("{}", serde_json::to_string(&m)?);
            } else {
                println!(
                    "share {spec}: {} of the scan's {} photos into {}{}",
                    m.photos.len(),
                    sd.manifest.plan.regions.len(),
                    out.display(),
                    if m.photos.is_empty() {
                        " (none: more shares than photos)"
                    } else {
                        ""
                    }
                );
                println!(
                    "when all {} shares are done: rig scan merge SHARE_DIR…",
                    spec.count
                );
            }
            Ok(0)
        }
        ScanAction::Mosaic { dir, .. } => {
            let mut sd = open_for_mosaic(dir, a.max_memory)?;
            let bar = super::progress_bar::Bar::new(!a.output.json);
            let photos = rig::scan::run::mosaic_all(
                &mut sd,
                rig::scan::mosaic::Interpolation::Bicubic,
                &|r, b, n| mosaic_progress(&bar, r, b, n),
            )?;
            if a.output.json {
                println!("{}", json!({"dir": dir, "photos": photos}));
            } else {
                for p in photos {
                    println!("photo {} (+ .tiff, .png preview)", p.display());
                }
            }
            Ok(0)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli::{Cli, Command};
    use clap::Parser;
    use std::path::Path;

    fn args(argv: &[&str]) -> ScanArgs {
        match Cli::try_parse_from(argv).unwrap().command {
            Command::Scan(a) => a,
            _ => unreachable!("a scan command was parsed"),
        }
    }

    /// The hint the operator pastes repeats the hardware (or simulator) and the store: a resume
    /// without --sim would look for a real stage.
    #[test]
    fn the_resume_hint_repeats_how_the_scan_was_run() {
        let a = args(&[
            "rig",
            "scan",
            "--sim",
            "--sim-seed",
            "4",
            "--sim-photo",
            "2",
            "--store",
            "st",
            "run",
            "s.toml",
        ]);
        assert_eq!(
            resume_command(&a, Path::new("s.toml"), Some(Path::new("o"))),
            "rig scan --sim --sim-seed 4 --sim-photo 2 --store st run s.toml --resume --out o"
        );
        let a = args(&[
            "rig",
            "scan",
            "--stage",
            "/dev/ttyUSB0",
            "--dialect",
            "grbl",
            "--camera",
            "/dev/video0",
            "run",
            "s.toml",
        ]);
        let c = resume_command(&a, Path::new("s.toml"), None);
        assert!(
            c.starts_with(
                "rig scan --stage /dev/ttyUSB0 --dialect grbl --camera /dev/video0 --store "
            ) && c.ends_with(" run s.toml --resume"),
            "{c}"
        );
    }
}
