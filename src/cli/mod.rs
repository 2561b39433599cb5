//! The `rig` command line.

pub mod calibrate_cmd;
pub mod camera_cmd;
pub mod client_cmd;
pub mod config;
pub mod connect;
pub mod demo;
pub mod dtm_cmd;
pub mod match_cmd;
pub mod measure_cmd;
pub mod orient_cmd;
pub mod shared_args;
pub use rig::exit;
pub mod progress_bar;
pub mod scan_cmd;
pub mod scene;
pub mod serve_cmd;
pub mod stage_cmd;
pub mod usage;

use clap::{Args, Parser, Subcommand};

/// `rig sim`: the simulated controller, or with `scene` a rendered stereo scene.
#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct SimCmd {
    #[command(subcommand)]
    pub action: Option<SimAction>,
    #[command(flatten)]
    pub serve: rig_sim::cli::SimArgs,
}

#[derive(Debug, Subcommand)]
pub enum SimAction {
    /// Render a stereo pair of the simulator's terrain (photos 1 and 2 of its block, or up to
    /// six) with control and check points, the true elevation model and a matching project;
    /// or, with --sensor pushbroom, two or three SPOT-like satellite views with their
    /// line-scanner models and RPCs.
    Scene(Box<scene::SceneArgs>),
}

/// The version and the features this binary was built with.
pub const VERSION: &str = if cfg!(feature = "v4l2") {
    concat!(env!("CARGO_PKG_VERSION"), " (features: v4l2)")
} else {
    concat!(
        env!("CARGO_PKG_VERSION"),
        " (features: none; cameras: the simulator and sim: sockets, no V4L2)"
    )
};

/// The rig: digitise and calibrate aerial film on a camera over motorised X/Y stages.
///
/// Every hardware command runs against real hardware (`--stage PATH`) or against the
/// built-in simulator (`--sim`), which behaves like the hardware and knows the truth.
#[derive(Debug, Parser)]
#[command(
    name = "rig",
    version = VERSION,
    propagate_version = true,
    max_term_width = 100,
    after_help = exit::TABLE
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
    /// -v: what each step does (info), -vv: details (debug), -vvv: everything; -q: errors
    /// only. RUST_LOG (e.g. RUST_LOG=rig::stage=debug) overrides both. Log lines go to
    /// standard error.
    #[command(flatten)]
    pub verbosity: clap_verbosity_flag::Verbosity<clap_verbosity_flag::WarnLevel>,
}

/// Sends the log to standard error at the level -v/-q chose, or as RUST_LOG says.
pub fn init_logging(v: &clap_verbosity_flag::Verbosity<clap_verbosity_flag::WarnLevel>) {
    use std::io::IsTerminal;
    let filter = match std::env::var("RUST_LOG") {
        Ok(s) if !s.trim().is_empty() => tracing_subscriber::EnvFilter::new(s),
        _ => {
            tracing_subscriber::EnvFilter::new(v.tracing_level_filter().to_string().to_lowercase())
        }
    };
    // A second initialisation (never in the binary) is ignored rather than a panic.
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .with_target(true)
        .try_init();
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// The whole chain on the built-in simulator: calibrate, orient and scan three overlapping
    /// photos, compute their elevation model, compare it with the true DEM.
    ///
    /// Example:
    ///   rig demo --out demo
    ///
    /// Every step is a real `rig` command, printed before it runs; everything lands in --out
    /// (sessions/, scan-photo-1/ … scan-photo-3/, project.toml, dtm/, report.json).
    #[command(verbatim_doc_comment, after_help = exit::TABLE)]
    Demo(demo::DemoArgs),
    /// Drive the X/Y stages: status, home, move, jog, stop.
    ///
    /// Positions are carriage coordinates in millimetres, 0..travel on both axes, whatever
    /// the controller's dialect.
    ///
    /// Examples:
    ///   rig stage --sim status --json
    ///   rig stage --stage /dev/ttyUSB0 --dialect grbl home
    ///   rig stage --sim move 120 80
    ///   rig stage --sim move --relative -0.5 0
    ///
    #[command(verbatim_doc_comment, after_help = exit::TABLE)]
    Stage(stage_cmd::StageArgs),
    /// Look at the camera and grab averaged, stripe-filtered frames.
    ///
    /// Examples:
    ///   rig camera --sim info
    ///   rig camera --sim grab --frames 32 -o plate.tiff
    ///   rig camera --sim grab --frames 32 --no-filter --stretch none -o raw.tiff
    ///
    /// `grab` writes a 16-bit TIFF and a JSON sidecar beside it (frames, dropped frames,
    /// exposure, gain, stage position, the stripe parameters it estimated and removed, and how
    /// grey levels were mapped). With --sim the stage first moves over the plate's central
    /// cross (or --at X,Y).
    ///
    #[command(verbatim_doc_comment, after_help = exit::TABLE)]
    Camera(camera_cmd::CameraArgs),
    /// Calibrate the rig: pixel→carriage from the plate's crosses (and, with a film, the
    /// interior orientation from its fiducials).
    ///
    /// Examples:
    ///   rig calibrate pixel --sim
    ///   rig calibrate pixel --stage /dev/ttyUSB0 --camera /dev/video0 --plate-cert plate.toml
    ///
    /// Each session is a directory in --store (default ./rig-sessions): log.jsonl (every
    /// step, flushed as it happens), crops/ (every mark with its fitted centre drawn),
    /// results.json; with --sim also the simulator's certificate and sim-truth.json.
    ///
    #[command(verbatim_doc_comment, after_help = exit::TABLE)]
    Calibrate(calibrate_cmd::CalibrateArgs),
    /// Scan film by script: plan (nothing moves), run (pause with Ctrl-C, --resume after a
    /// pause, crash or kill), mosaic again.
    ///
    /// Examples:
    ///   rig scan plan scan.toml
    ///   rig scan --sim run scan.toml
    ///   rig scan --sim run scan.toml --resume
    ///   rig scan mosaic scans/photo-1
    ///
    /// The script (TOML; docs/scanning.md documents it) names the film, the interior-orientation
    /// session (default: the newest in --store), the regions in photo mm, the output
    /// resolution, overlap, frames per tile, filter and settle time. The scan directory
    /// holds script.toml, calibration.json, camera-cert.toml, manifest.json (the checkpoint,
    /// rewritten atomically after every tile), log.jsonl, flat.tiff, tiles/, and per region
    /// REGION.tiff (16-bit, photo coordinates) with REGION.json (the photo grid, interior
    /// orientation, camera certificate and sessions): what the matching core reads.
    ///
    #[command(verbatim_doc_comment, after_help = exit::TABLE)]
    Scan(scan_cmd::ScanArgs),
    /// The lab service: hold the stage and camera, run a queue of scans and moves, tell
    /// clients what happens, show the camera live in the browser.
    ///
    /// Examples:
    ///   rig serve --sim                        (then open http://127.0.0.1:7878/)
    ///   rig serve --stage /dev/ttyUSB0 --dialect grbl --camera /dev/video0
    ///   rig serve token add lab-pc --role operator --tokens tokens.toml
    ///   rig serve --sim --bind 0.0.0.0:7878 --tokens tokens.toml
    ///
    /// Everything the service was asked and did is in --data (journal: the queue, the history
    /// and the running item, synced before each answer; items/ID/: each item's files). Killed,
    /// it starts again with the running item interrupted at the front of the queue and the
    /// queue stopped until an operator starts it; a scan continues from its last tile. The
    /// API is at /api/v1 (GET /api/v1/openapi.json lists it); docs/service.md is the guide.
    #[command(verbatim_doc_comment, after_help = exit::TABLE)]
    Serve(serve_cmd::ServeArgs),
    /// The queue of a running `rig serve`: add, list, show, move, remove, clear, start, stop.
    ///
    /// Examples:
    ///   rig queue add scan film-12.toml
    ///   rig queue add move 120 80 --front
    ///   rig queue list
    ///   rig queue start
    ///
    #[command(verbatim_doc_comment, after_help = exit::TABLE)]
    Queue(client_cmd::QueueArgs),
    /// Control the item a `rig serve` runs: pause [--now], resume, stop, abort, halt.
    #[command(after_help = exit::TABLE)]
    Run(client_cmd::RunArgs),
    /// Follow a `rig serve`'s events (one line each; --json for scripts).
    #[command(after_help = exit::TABLE)]
    Events(client_cmd::EventsArgs),
    /// Run the simulated stage controller on a pseudo-terminal (same as `rig-sim`).
    ///
    /// Prints the pseudo-terminal's path on its first line (and links it at --stage-link), then
    /// serves the chosen dialect there until SIGTERM or Ctrl-C, when it writes its final truth
    /// and removes the link. Open that path with `rig stage --stage PATH --dialect ...` exactly
    /// as you would a real controller.
    ///
    /// Example:
    ///   rig sim --dialect grbl --time-scale 0 --truth truth.json --stage-link /tmp/stage &
    ///   rig stage --stage /tmp/stage --dialect grbl home
    ///
    /// `rig sim scene --out DIR` instead renders a stereo pair of the simulator's terrain
    /// with control and check points and the true elevation model: a ready matching project.
    #[command(verbatim_doc_comment)]
    Sim(SimCmd),
    /// Elevation models from photos: `rig dtm PROJECT.toml --out DIR`.
    ///
    /// A format-2 project (`format = 2`; see docs/elevation-models.md) names any number of photos as plain
    /// grey images with their cameras and orientations (or resected from control points, or
    /// approximate ones, from which the block is oriented first into DIR/orientation/ as `rig
    /// orient` does; or the rig's scans), the ground CRS, points and the DEM, and the matcher, `[matching]
    /// method`:
    ///   "sweep"  every overlapping pair swept along its epipolar lines, the heights merged
    ///            (seed 000)
    ///   "mgcm"   one reference photo's points matched into all the others at once, every
    ///            ray tested (seed 002); points.csv with every refused point and why
    ///   "oslsm"  heights, the terrain's reflectance and each photo's gain and offset in one
    ///            object-space adjustment (seed 001), from the sweep's model in coarse/ or
    ///            a DEM file; reflectance.tif, convergence.png
    /// A format-1 project (a scanned pair: `rig sim scene` writes one) is read as the format-2
    /// project `rig dtm upgrade` writes and swept as above.
    /// Film at its real size (9 000–19 000 px scans) is read at a pyramid level, streamed:
    /// `[dem] photo_level = "auto"` keeps two pixels a post (0: as scanned; report.json's
    /// photos_read says what was read), and a run too large for --max-memory or the sweep's
    /// limits is refused before a pixel is read.
    /// Outputs in DIR, each written whole or not at all (a killed run can be run again):
    ///   dem.tif      heights, Deflate float32 GeoTIFF in the project's CRS, nodata −9999
    ///   quality.tif  band 1 each height's standard deviation (m), band 2 its correlation
    ///   ortho.tif    orthophoto on the DEM grid (grey values of the most nadir photo)
    ///   points.ply   matched points (x, y, z, correlation, σ_z; CRS in a comment)
    ///   points.las   the same as LAS 1.2 with the CRS's GeoTIFF keys
    ///   hillshade.png, quality.png, error.png (with a reference): maps ≥ 800 px wide
    ///   report.json  what was done and found, with how far the σ agree with true errors
    ///   report.html  the figures, maps and files on one page
    ///
    /// On several machines (a Slurm array, GNU parallel; format 2): each sweeps one share,
    /// then one joins them; the result is the single run's, byte for byte:
    ///   rig dtm PROJECT.toml --tile I/N --out tiles/I      (I = 1 … N)
    ///   rig dtm merge tiles/* --out dtm
    ///
    /// Example:
    ///   rig sim scene --out scene && rig dtm scene/project.toml --out dtm
    ///
    #[command(verbatim_doc_comment, after_help = exit::TABLE)]
    Dtm(dtm_cmd::DtmArgs),
    /// Orient a block of frame photos by one bundle adjustment (aerotriangulation).
    ///
    /// From approximate orientations (a flight index map's: `position` and `angles_deg` with
    /// `position_sigma_m` and `angles_sigma_deg`; `angles_deg = [0, 0, 0]` for near-vertical) or
    /// none (resected from the points), at least three control points (`gcp`) for the whole
    /// block, and tie points (`tie`: image observations only). Check points (`cp`) are never
    /// used: intersected afterwards and compared. Robust weights and data snooping remove
    /// blunders; σ̂₀ rescales the measurements' σ once.
    ///
    /// Writes into DIR:
    ///   project.toml    the same project, every photo oriented (position, angles, sigma)
    ///   points.csv      every adjusted point's ground and σ (id,kind,x,y,z,sigma_x,…,rays)
    ///   covariance.csv  the orientations' covariance, correlated between photos, which
    ///                   `rig dtm` carries into every height's σ
    ///   report.json   σ̂₀, per-photo σ and residuals, check points, precision, blunders
    ///   report.html   the same with a residual-vector plot per photo
    ///
    /// Example:
    ///   rig orient block/project.toml --out oriented && rig dtm oriented/project.toml --out dtm
    ///   rig dtm block/project.toml --out dtm    # the same: orients first, into dtm/orientation/
    ///
    /// `[orientation] refraction = true` and `earth_curvature = true` in the project correct
    /// small-scale photos (docs/orientation.md says when they matter).
    ///
    /// `[orientation] self_calibration = ["focal", "principal_point", "k1", "k2"]` (any of
    /// them) estimates each [camera.NAME]'s interior with the block and writes it, with its σ,
    /// into the oriented project; a parameter the block cannot determine (the focal length
    /// over flat ground, say) is refused with what the block would need.
    ///
    #[command(verbatim_doc_comment, after_help = exit::TABLE)]
    Orient(orient_cmd::OrientArgs),
    /// Match photos outside a project: disparities of a rectified stereo pair.
    ///
    /// Example:
    ///   rig match pair left.png right.png --disparity 0 63 --out match
    ///
    #[command(verbatim_doc_comment, after_help = exit::TABLE)]
    Match(match_cmd::MatchArgs),
    /// Measure a mark (fiducial or cross) in images, to a hundredth of a pixel, with its σ.
    ///
    /// Where its centre is, with its standard deviation.
    ///
    /// The mark is described by a mark file (TOML) of primitives: dot {radius}, ring {radius,
    /// width} (the radius to the line's centre), bar {length, width, angle_deg} (full length,
    /// through the centre; a cross is two bars), spokes {count, from, to, width, angle0_deg}
    /// (radial, from `from` to `to`); sizes in px or µm (`units`), angles in degrees from +col
    /// toward +row (clockwise as shown); polarity dark_on_bright or bright_on_dark:
    ///
    ///   units = "px"
    ///   polarity = "dark_on_bright"
    ///   [[part]]
    ///   kind = "dot"
    ///   radius = 2.0
    ///   [[part]]
    ///   kind = "ring"
    ///   radius = 14.0
    ///   width = 2.0
    ///
    /// The mark is found by its edges (anywhere, or within --search px of --near), then least
    /// squares fits the drawn mark to the image's own pixels with as many geometric parameters as
    /// the mark determines: dots and rings shifts and scale (their rotation means nothing), lines
    /// in one direction add a rotation, lines in two or more directions the full affine. Where the
    /// frame cuts the matching window, its part in the image is used.
    ///
    /// Output: col, row with integer values at pixel centres ((0, 0) the centre of the top-left
    /// pixel), their σ in px (from each pixel's influence and the residuals' own
    /// autocovariance, so stripes and grain widen it as they widen the error), the mark's
    /// scale and rotation in the image (physical, also on non-square pixels; rotation null for
    /// marks without lines), the correlation, the blur found (or --blur), the iterations, and
    /// the gate's verdict: a mark is refused when the frame cuts it (--min-inside), its
    /// residuals show damage or a different mark (--max-outliers, --max-outlier-pixels), or
    /// its σ is above --max-sigma. Reasons: not_found, diverged, wandered, singular,
    /// left_window, low_contrast, cut, inverted, damaged, imprecise. Exit 0 whatever the verdicts
    /// (--strict: 12 when a mark is refused). The camera's stripe noise (field shift, column
    /// pattern) is estimated from each image off the mark and removed before the final match;
    /// --stripes-from FLAT takes it from a flat instead, --keep-stripes leaves it.
    ///
    /// Images: PNG or TIFF, grey or colour (turned grey as 0.299 R + 0.587 G + 0.114 B), 8/16-bit
    /// or float.
    ///
    /// Examples:
    ///   rig measure fid.png --mark corner.toml
    ///   rig measure scan.tif --mark cross.toml --near 1200,840 --search 30 --json
    ///   rig measure frames/*.png --mark ring.toml --pixel-um 10.19,10.96 --csv marks.csv
    ///
    #[command(verbatim_doc_comment, after_help = exit::TABLE)]
    Measure(measure_cmd::MeasureArgs),
    /// The settings in force (stage, dialect, camera) and where each comes from.
    ///
    /// Precedence: a flag, then the environment (RIG_STAGE, RIG_DIALECT, RIG_CAMERA), then
    /// the first file found of ./rig.toml and $XDG_CONFIG_HOME/rig/rig.toml (or
    /// ~/.config/rig/rig.toml), whose keys are stage, dialect and camera:
    ///   stage = "/dev/ttyUSB0"
    ///   dialect = "grbl"
    ///   camera = "/dev/video0"
    ///
    /// Examples:
    ///   rig config show
    ///   RIG_DIALECT=grbl rig config show --json
    #[command(verbatim_doc_comment, after_help = exit::TABLE)]
    Config(ConfigCmd),
    /// Shell completions for bash, zsh, fish, elvish or PowerShell, on standard output.
    ///
    /// Examples:
    ///   rig completions bash > ~/.local/share/bash-completion/completions/rig
    ///   rig completions zsh > ~/.zfunc/_rig      (with fpath+=~/.zfunc in ~/.zshrc)
    ///   rig completions fish > ~/.config/fish/completions/rig.fish
    #[command(verbatim_doc_comment)]
    Completions {
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
    /// The manual: rig(1) on standard output, or with --out a page for every command.
    ///
    /// Examples:
    ///   rig man | man -l -
    ///   rig man --out ~/.local/share/man/man1     (then `man rig-dtm`)
    #[command(verbatim_doc_comment)]
    Man {
        /// Write rig.1 and one page per command (rig-dtm.1, rig-stage-home.1, …) here.
        #[arg(long, value_name = "DIR")]
        out: Option<std::path::PathBuf>,
    },
}

/// `rig config`.
#[derive(Debug, Args)]
pub struct ConfigCmd {
    #[command(subcommand)]
    pub action: ConfigAction,
    #[command(flatten)]
    pub port: connect::StagePort,
    #[command(flatten)]
    pub camera: connect::CameraDevice,
    /// With --sim the commands ignore a configured stage and camera (the dialect still holds).
    #[command(flatten)]
    pub sim: connect::Simulated,
    #[command(flatten)]
    pub output: shared_args::JsonOutput,
}

#[derive(Debug, Subcommand)]
pub enum ConfigAction {
    /// Each setting, its value and its source, and the files looked at.
    Show,
}

/// The code for an error that ended a command: [`exit::USAGE`] for a flag or value our own
/// checks refused ([`usage::UsageError`]), the stage error's own where one caused it (a
/// timeout during a calibration exits 4 as in `rig stage`), otherwise [`exit::OTHER`].
pub fn exit_code_of(e: &anyhow::Error) -> i32 {
    if e.chain().any(|c| c.is::<usage::UsageError>()) {
        return exit::USAGE;
    }
    e.chain()
        .find_map(|c| c.downcast_ref::<rig::stage::StageError>())
        .map_or(exit::OTHER, |s| s.exit_code())
}

/// `rig completions` and `rig man`: generated from the same definitions as the parser, so they
/// cannot drift from it.
pub fn docs(command: &Command) -> anyhow::Result<i32> {
    use anyhow::Context;
    use clap::CommandFactory;
    use std::io::Write;
    let mut cmd = Cli::command();
    // Generated into memory first, then written: a closed pipe (`| head`) ends the command
    // quietly instead of panicking inside the generator.
    let mut text = Vec::new();
    let print = |text: &[u8]| match std::io::stdout().write_all(text) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(exit::OK),
        r => r.map(|_| exit::OK).context("writing to standard output"),
    };
    match command {
        Command::Completions { shell } => {
            clap_complete::generate(*shell, &mut cmd, "rig", &mut text);
            return print(&text);
        }
        Command::Man { out: None } => {
            clap_mangen::Man::new(cmd).render(&mut text)?;
            return print(&text);
        }
        Command::Man { out: Some(dir) } => {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
            clap_mangen::generate_to(cmd, dir)
                .with_context(|| format!("writing the pages into {}", dir.display()))?;
            println!("manual pages written to {}", dir.display());
        }
        _ => unreachable!("docs() is called for `completions` and `man` only"),
    }
    Ok(exit::OK)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    /// clap's own checks of every command's definition (names, conflicts, requirements),
    /// which it otherwise makes only when a path through them is parsed.
    #[test]
    fn the_command_line_definitions_are_consistent() {
        Cli::command().debug_assert();
    }

    /// The stage's codes are the table's, and they survive being wrapped with context.
    #[test]
    fn stage_errors_keep_their_code_through_context() {
        use rig::stage::StageError;
        let e = anyhow::Error::new(StageError::NotHomed).context("calibration: moving to cross 3");
        assert_eq!(exit_code_of(&e), exit::FAULT);
        assert_eq!(StageError::Cancelled.exit_code(), exit::INTERRUPTED);
        assert_eq!(exit_code_of(&anyhow::anyhow!("a file")), exit::OTHER);
    }
}
