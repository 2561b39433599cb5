//! The `rig-sim` command line, shared by the `rig-sim` binary and `rig sim`.

use crate::{serve, Dialect, FaultSpec, SimConfig};
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// Run the simulated stage controller on a pseudo-terminal until SIGTERM or Ctrl-C.
///
/// Prints the pseudo-terminal's path on the first line of standard output (and links it at
/// --stage-link), then serves the chosen dialect there. Open that path with `rig stage
/// --stage PATH --dialect ...` exactly as you would a real controller.
#[derive(Debug, clap::Args)]
pub struct SimArgs {
    /// Controller dialect to speak.
    #[arg(long, value_enum, default_value = "native")]
    pub dialect: Dialect,
    /// Make a symlink to the pseudo-terminal here (replaced if it is an old symlink).
    #[arg(long, value_name = "PATH")]
    pub stage_link: Option<PathBuf>,
    /// Wall-clock seconds per simulated second: 1 = real time, 0 = never wait.
    #[arg(long, default_value_t = 1.0, value_name = "S")]
    pub time_scale: f64,
    /// Seed for every random draw (noise, drift, faults): the same seed replays the same run.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Faults to inject, e.g. `drop=0.001,corrupt=0.001,reset=0.1`. Kinds: drop=P, corrupt=P,
    /// dup=P, delay=P:MS, stall=[x|y:]P, limit=P, reset=P, estop=P, disconnect=P (byte faults
    /// per byte, the others per move).
    #[arg(long, value_name = "SPEC", value_parser = parse_faults, default_value = "")]
    pub faults: FaultSpec,
    /// Write the truth (actual carriage position, faults injected) to this JSON file.
    #[arg(long, value_name = "PATH")]
    pub truth: Option<PathBuf>,
    /// Start as if already homed.
    #[arg(long)]
    pub start_homed: bool,
    /// Also serve the simulated camera on a Unix socket here (see sim/CAMERA_SOCKET.md); the
    /// host opens it as `--camera sim:PATH`.
    #[arg(long, value_name = "PATH")]
    pub camera_socket: Option<PathBuf>,
    /// Write the certificates that come with this world into DIR, as a manufacturer ships
    /// them: plate-cert.toml (the carriage plate's crosses) and, with --film, camera-cert.toml
    /// (the film camera's fiducials), for `rig calibrate --plate-cert / --camera-cert`.
    #[arg(long, value_name = "DIR")]
    pub certificates: Option<PathBuf>,
    /// Lay a film (an RC10-like frame with 8 fiducials and an aerial photo rendered from a
    /// DEM) on the carriage.
    #[arg(long)]
    pub film: bool,
    /// Which photo of the 2×2 block the film is: 1, 2 along the first strip (60 % overlap),
    /// 3, 4 along the second.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=4))]
    pub photo: u32,
    /// A perfect stage and frames that depend only on where they were taken (for comparing
    /// two runs byte for byte).
    #[arg(long)]
    pub repeatable: bool,
    /// The camera has square pixels (10.5 µm), not seed 002's 10.19 × 10.96 µm.
    #[arg(long)]
    pub square_pixels: bool,
    /// The film camera's fiducials are rings: corners a ring, a dot and four radial lines,
    /// mid-sides a ring and a dot.
    #[arg(long)]
    pub ring_fiducials: bool,
    /// Every fiducial of the form a mark file gives (units = "um"; as `rig measure` reads).
    #[arg(long, value_name = "MARK.toml")]
    pub fiducial_mark: Option<PathBuf>,
    /// Smudge dirt over these crosses' centres (comma-separated ids, 1–9).
    #[arg(long, value_name = "IDS", value_delimiter = ',')]
    pub dirty_crosses: Vec<u32>,
    /// Leave these fiducials off the film (comma-separated ids, 1–8).
    #[arg(long, value_name = "IDS", value_delimiter = ',')]
    pub missing_fiducials: Vec<u32>,
    /// GRBL only: a setting that differs from the simulated board's defaults, as `N=VALUE`
    /// (repeatable), e.g. `--grbl-setting 10=0` (WPos reports), `13=1` (inches), `23=3`
    /// (home toward the − switches; the switches are placed for it).
    #[arg(long, value_name = "N=VALUE", value_parser = parse_setting)]
    pub grbl_setting: Vec<(u32, f64)>,
    /// Native only: report a setting as this value whatever the controller does, `NAME=VALUE`
    /// (repeatable; names as in PROTOCOL.md, e.g. `MaxSpeed=0`, `TravelX=0`): a misconfigured
    /// controller, for testing the host.
    #[arg(long, value_name = "NAME=VALUE", value_parser = parse_native_setting)]
    pub native_setting: Vec<(firmware_protocol::SettingId, i32)>,
    /// Probability that a camera frame is lost on the way.
    #[arg(long, default_value_t = 0.0, value_name = "P")]
    pub camera_drop: f64,
}

/// `N=VALUE` with N a setting number and VALUE any number GRBL would store.
pub fn parse_setting(s: &str) -> Result<(u32, f64), String> {
    let (k, v) = s
        .trim_start_matches('$')
        .split_once('=')
        .ok_or_else(|| format!("`{s}`: expected N=VALUE, e.g. 23=3"))?;
    let k: u32 = k
        .trim()
        .parse()
        .map_err(|_| format!("`{s}`: setting number `{k}` is not 0..=4294967295"))?;
    let v: f64 = v
        .trim()
        .parse()
        .map_err(|_| format!("`{s}`: value `{v}` is not a number"))?;
    Ok((k, v))
}

/// `NAME=VALUE` with NAME a native setting (`MaxSpeed`, `SoftMinX`, …) and VALUE an i32.
pub fn parse_native_setting(s: &str) -> Result<(firmware_protocol::SettingId, i32), String> {
    use firmware_protocol::SettingId;
    let (k, v) = s
        .split_once('=')
        .ok_or_else(|| format!("`{s}`: expected NAME=VALUE, e.g. MaxSpeed=0"))?;
    let id = SettingId::ALL
        .iter()
        .find(|id| format!("{id:?}").eq_ignore_ascii_case(k.trim()))
        .ok_or_else(|| {
            let names: Vec<String> = SettingId::ALL.iter().map(|i| format!("{i:?}")).collect();
            format!("`{k}` is not a native setting; one of {}", names.join(", "))
        })?;
    let v: i32 = v
        .trim()
        .parse()
        .map_err(|_| format!("`{v}` is not an integer in -2147483648..=2147483647"))?;
    Ok((*id, v))
}

fn parse_faults(s: &str) -> Result<FaultSpec, String> {
    FaultSpec::parse(s).map_err(|e| e.to_string())
}

/// Runs until SIGTERM/SIGINT; the truth file is complete when this returns.
pub fn run(args: SimArgs) -> std::io::Result<()> {
    if !(args.time_scale >= 0.0 && args.time_scale.is_finite()) {
        return Err(std::io::Error::other(format!(
            "--time-scale {} must be 0 or more",
            args.time_scale
        )));
    }
    let stop = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register(signal_hook::consts::SIGTERM, stop.clone())?;
    signal_hook::flag::register(signal_hook::consts::SIGINT, stop.clone())?;
    let cfg = SimConfig {
        dialect: args.dialect,
        time_scale: args.time_scale,
        seed: args.seed,
        faults: args.faults,
        truth: args.truth,
        stage_link: args.stage_link,
        start_homed: args.start_homed,
        grbl_settings: args.grbl_setting,
        native_settings: args.native_setting,
        film: args.film,
        dirty_crosses: args.dirty_crosses,
        missing_fiducials: args.missing_fiducials,
        photo: args.photo,
        square_pixels: args.square_pixels,
        ring_fiducials: args.ring_fiducials,
        fiducial_mark: match &args.fiducial_mark {
            Some(p) => Some(crate::marks::SimMark::load(p).map_err(std::io::Error::other)?),
            None => None,
        },
        repeatable: args.repeatable,
    };
    let world = crate::server::World::new(&cfg);
    if let Some(dir) = &args.certificates {
        let write = |name: &str, text: String| {
            let p = dir.join(name);
            std::fs::create_dir_all(dir)
                .and_then(|_| std::fs::write(&p, text))
                .map_err(|e| std::io::Error::new(e.kind(), format!("writing {}: {e}", p.display())))
        };
        write(
            "plate-cert.toml",
            crate::certificates::plate_certificate(&world.plate, world.seed),
        )?;
        if let Some(film) = &world.film {
            write(
                "camera-cert.toml",
                crate::certificates::camera_certificate(film, world.seed),
            )?;
        }
    }
    if !(0.0..=0.5).contains(&args.camera_drop) {
        return Err(std::io::Error::other(format!(
            "--camera-drop {} must be between 0 and 0.5",
            args.camera_drop
        )));
    }
    let _camera = match &args.camera_socket {
        Some(p) => Some(crate::camera_socket::serve_camera(
            world.clone(),
            p,
            args.camera_drop,
        )?),
        None => None,
    };
    serve(&cfg, &world, &stop, |p| {
        use std::io::Write;
        println!("{}", p.display());
        let _ = std::io::stdout().flush();
    })
}
