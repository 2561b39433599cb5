//! The hardware options shared by the commands that drive stage and camera together
//! (`rig calibrate`, `rig scan run`): the stage's port and dialect and the camera, or the
//! built-in simulator and its knobs.

use super::usage::usage_bail;
use anyhow::Context;
use clap::Args;
use rig::camera::{Camera, SimCamera};
use rig::coords::CarriageUm;
use rig::stage::{self, Dialect, DriverOptions, LinkOptions, SoftLimits, Stage};
use std::path::PathBuf;

/// The stage controller on a serial port: every command that drives the stage takes it so.
#[derive(Debug, Args)]
pub struct StagePort {
    /// Serial port of the stage controller (e.g. /dev/ttyUSB0, or the path `rig sim` prints).
    /// Without the flag: RIG_STAGE, then rig.toml (`rig config show`).
    #[arg(long, value_name = "PATH", conflicts_with = "sim", global = true)]
    pub stage: Option<PathBuf>,
    /// Controller dialect on that port: native (the rig's firmware, the default) or grbl
    /// (GRBL 1.1). Without the flag: RIG_DIALECT, then rig.toml (`rig config show`).
    #[arg(long, value_enum, global = true)]
    pub dialect: Option<Dialect>,
    /// Tighter soft limits, mm: XMIN,XMAX,YMIN,YMAX (intersected with the controller's; a scan
    /// is planned within them too).
    #[arg(
        long,
        value_name = "MM,MM,MM,MM",
        value_parser = parse_limits,
        global = true,
        allow_hyphen_values = true
    )]
    pub limits: Option<SoftLimits>,
}

/// The camera: every command that takes frames names it so.
#[derive(Debug, Args)]
pub struct CameraDevice {
    /// Camera: /dev/videoN (needs the `v4l2` build feature) or sim:SOCKET (a running
    /// `rig sim --camera-socket SOCKET`). Without the flag: RIG_CAMERA, then rig.toml.
    #[arg(
        id = "camera",
        long = "camera",
        value_name = "DEVICE",
        conflicts_with = "sim",
        global = true
    )]
    pub device: Option<String>,
}

/// The built-in simulator in place of the hardware, and its seed.
#[derive(Debug, Args)]
pub struct Simulated {
    /// Use the built-in simulator instead of hardware (what it simulates: the command's help
    /// says).
    #[arg(id = "sim", long = "sim", global = true)]
    pub on: bool,
    /// Simulator: random seed.
    #[arg(
        id = "sim_seed",
        long = "sim-seed",
        default_value_t = 1,
        requires = "sim",
        global = true
    )]
    pub seed: u64,
}

/// Stage and camera together (`rig calibrate`, `rig scan run`), or the simulator of both.
#[derive(Debug, Args)]
pub struct ConnectArgs {
    #[command(flatten)]
    pub port: StagePort,
    #[command(flatten)]
    pub camera: CameraDevice,
    /// The simulator: stage, camera, plate and film; it writes its own certificates and keeps
    /// its truth beside the results as sim-truth.json.
    #[command(flatten)]
    pub sim: Simulated,
    /// Simulator: wall seconds per simulated second (0 = no waiting).
    #[arg(
        long,
        default_value_t = 0.0,
        value_name = "S",
        requires = "sim",
        global = true
    )]
    pub sim_time_scale: f64,
    /// Simulator: smudge dirt over these crosses' centres (ids, comma-separated).
    #[arg(
        long,
        value_name = "IDS",
        value_delimiter = ',',
        requires = "sim",
        global = true
    )]
    pub sim_dirty_crosses: Vec<u32>,
    /// Simulator: leave these fiducials off the film (ids, comma-separated).
    #[arg(
        long,
        value_name = "IDS",
        value_delimiter = ',',
        requires = "sim",
        global = true
    )]
    pub sim_missing_fiducials: Vec<u32>,
    /// Simulator: which photo of the 2×2 block lies on the carriage (1, 2 along the first
    /// strip with 60 % overlap; 3, 4 along the second).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=4), requires = "sim", global = true)]
    pub sim_photo: u32,
    /// Simulator: a perfect stage and frames that depend only on where they were taken, so
    /// that two runs can be compared byte for byte.
    #[arg(long, requires = "sim", global = true)]
    pub sim_repeatable: bool,
    /// Simulator: the camera has square pixels (10.5 µm), not seed 002's 10.19 × 10.96 µm.
    #[arg(long, requires = "sim", global = true)]
    pub sim_square_pixels: bool,
    /// Simulator: the film camera's fiducials are rings (corners with four radial lines).
    #[arg(long, requires = "sim", global = true)]
    pub sim_ring_fiducials: bool,
    /// Simulator: every fiducial of the form a mark file gives (units = "um").
    #[arg(long, value_name = "MARK.toml", requires = "sim", global = true)]
    pub sim_fiducial_mark: Option<std::path::PathBuf>,
}

fn driver_options(a: &ConnectArgs) -> DriverOptions {
    DriverOptions {
        limits: a.port.limits,
        ..Default::default()
    }
}

pub struct Hardware {
    pub sim: Option<rig_sim::EmbeddedSim>,
    pub stage: Box<dyn Stage>,
    pub camera: Box<dyn Camera>,
}

/// What is left to close once the stage and camera are taken out of [`Hardware`]: the
/// simulator, if any.
pub struct Rest {
    sim: Option<rig_sim::EmbeddedSim>,
}

impl Rest {
    /// Stops the simulator (it writes its truth file); call after the stage and camera are
    /// dropped.
    pub fn close(self) -> anyhow::Result<()> {
        match self.sim {
            Some(s) => s.shutdown().context("stopping the built-in simulator"),
            None => Ok(()),
        }
    }
}

impl Hardware {
    /// The stage and camera to own elsewhere (the service's hardware thread), and the rest.
    pub fn split(self) -> (Box<dyn Stage>, Box<dyn Camera>, Rest) {
        (self.stage, self.camera, Rest { sim: self.sim })
    }

    /// Closes the hardware; the simulator writes its truth file.
    pub fn close(mut self) -> anyhow::Result<()> {
        if let Some(s) = self.sim.take() {
            drop(self);
            s.shutdown().context("stopping the built-in simulator")?;
        }
        Ok(())
    }
}

/// Opens the stage and camera, or starts the simulator (with a film on the carriage if
/// `film`; writing its truth to `truth` when it stops).
pub fn connect(
    a: &ConnectArgs,
    truth: Option<PathBuf>,
    film: bool,
    link: &LinkOptions,
) -> anyhow::Result<Hardware> {
    let cfg = super::config::resolve(
        a.port.stage.as_ref(),
        a.port.dialect,
        a.camera.device.as_ref(),
    )?;
    tracing::info!(
        stage = ?cfg.stage.value, stage_from = %cfg.stage.source,
        dialect = ?cfg.dialect(), dialect_from = %cfg.dialect.source,
        camera = ?cfg.camera.value, sim = a.sim.on,
        "connecting"
    );
    if a.sim.on {
        if a.sim_time_scale.is_nan() || a.sim_time_scale < 0.0 {
            usage_bail!("--sim-time-scale must be 0 or more");
        }
        let s = rig_sim::EmbeddedSim::start(rig_sim::SimConfig {
            time_scale: a.sim_time_scale,
            seed: a.sim.seed,
            dialect: match cfg.dialect() {
                Dialect::Native => rig_sim::Dialect::Native,
                Dialect::Grbl => rig_sim::Dialect::Grbl,
            },
            truth,
            film,
            start_homed: false,
            dirty_crosses: a.sim_dirty_crosses.clone(),
            missing_fiducials: a.sim_missing_fiducials.clone(),
            photo: a.sim_photo,
            square_pixels: a.sim_square_pixels,
            ring_fiducials: a.sim_ring_fiducials,
            fiducial_mark: match &a.sim_fiducial_mark {
                Some(p) => Some(rig_sim::marks::SimMark::load(p).map_err(anyhow::Error::msg)?),
                None => None,
            },
            repeatable: a.sim_repeatable,
            ..Default::default()
        })
        .context("starting the built-in simulator")?;
        let stage = stage::open(&s.port, cfg.dialect(), driver_options(a), link)?;
        let camera = Box::new(SimCamera::new(s.world.clone(), 0.0));
        return Ok(Hardware {
            sim: Some(s),
            stage,
            camera,
        });
    }
    let (Some(port), Some(cam)) = (&cfg.stage.value, &cfg.camera.value) else {
        usage_bail!("name the stage and the camera (--stage PATH --dialect native|grbl --camera DEVICE, or RIG_STAGE, RIG_DIALECT, RIG_CAMERA, or rig.toml: see `rig config show`), or use --sim");
    };
    let stage = stage::open(port, cfg.dialect(), driver_options(a), link)
        .with_context(|| format!("opening the stage at {}", port.display()))?;
    let camera = open_device(cam)?;
    Ok(Hardware {
        sim: None,
        stage,
        camera,
    })
}

/// Opens a camera by name: `sim:SOCKET` (a running `rig-sim --camera-socket`) or a device path.
pub fn open_device(dev: &str) -> anyhow::Result<Box<dyn Camera>> {
    match dev.strip_prefix("sim:") {
        Some(path) => Ok(Box::new(rig::camera::socket::SocketCamera::open(path)?)),
        None => open_v4l2(dev),
    }
}

#[cfg(feature = "v4l2")]
fn open_v4l2(dev: &str) -> anyhow::Result<Box<dyn Camera>> {
    Ok(Box::new(rig::camera::v4l2::V4l2Camera::open(dev)?))
}

#[cfg(not(feature = "v4l2"))]
fn open_v4l2(dev: &str) -> anyhow::Result<Box<dyn Camera>> {
    anyhow::bail!("camera {dev}: this rig was built without the V4L2 backend; rebuild with `cargo build --release --features v4l2` (needs libclang), or use --sim")
}

pub fn parse_limits(s: &str) -> Result<SoftLimits, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| {
            x.trim()
                .parse::<f64>()
                .map_err(|_| format!("`{x}` is not a number"))
        })
        .collect::<Result<_, _>>()?;
    if v.len() != 4 {
        return Err("expected XMIN,XMAX,YMIN,YMAX in mm".into());
    }
    if v.iter().any(|x| !x.is_finite()) {
        return Err("the limits must be numbers (not nan or inf)".into());
    }
    if v[0] >= v[1] || v[2] >= v[3] {
        return Err("each minimum must be below its maximum".into());
    }
    Ok(SoftLimits {
        min: CarriageUm::from_mm(v[0], v[2]),
        max: CarriageUm::from_mm(v[1], v[3]),
    })
}
