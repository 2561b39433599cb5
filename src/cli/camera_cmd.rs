//! `rig camera`: look at the camera, and grab averaged, stripe-filtered frames.

use super::usage::{usage_bail, OrUsage};
use anyhow::Context;
use clap::{Args, Subcommand};
use rig::camera::{Camera, SimCamera};
use rig::coords::CarriageUm;
use rig::digitise::{capture, output, stretch};
use rig::stage::{self, DriverOptions};
use serde_json::json;
use std::path::PathBuf;
use std::time::Duration;

/// Options of `rig camera` (its help text is on `Command::Camera`).
#[derive(Debug, Args)]
pub struct CameraArgs {
    #[command(flatten)]
    pub camera: super::connect::CameraDevice,
    /// The simulator: a camera over a simulated, homed stage.
    #[command(flatten)]
    pub sim: super::connect::Simulated,
    /// Simulator: lay a film (8 fiducials, a textured picture) on the carriage.
    #[arg(long, requires = "sim", global = true)]
    pub sim_film: bool,
    /// Simulator: probability that a frame is lost on the way.
    #[arg(
        long,
        default_value_t = 0.0,
        value_name = "P",
        requires = "sim",
        global = true
    )]
    pub sim_frame_drop: f64,
    #[command(flatten)]
    pub output: super::shared_args::JsonOutput,
    #[command(subcommand)]
    pub action: CameraAction,
}

#[derive(Debug, Subcommand)]
pub enum CameraAction {
    /// The V4L2 cameras on this machine.
    List,
    /// What the camera is: size, bit depth, formats, exposure and gain.
    Info,
    /// Average N frames, remove the stripe noise, stretch, write a 16-bit TIFF and a JSON sidecar.
    Grab {
        /// Frames to average (the seed used 32).
        #[arg(long, default_value_t = 32)]
        frames: u32,
        /// Keep the stripe noise (no field-shift or column-pattern removal).
        #[arg(long)]
        no_filter: bool,
        /// Clip percentiles of the contrast stretch, LOW,HIGH; `none` keeps the grey levels
        /// linear (scaled to 16 bits).
        #[arg(long, default_value = "0.1,99.9", value_name = "LOW,HIGH|none")]
        stretch: String,
        /// Exposure, ms.
        #[arg(long, value_name = "MS")]
        exposure: Option<f64>,
        /// Gain, or `auto`.
        #[arg(long, value_name = "GAIN|auto")]
        gain: Option<String>,
        /// Simulator: drive the stage here first, X,Y mm (default: the plate's central cross).
        #[arg(long, value_name = "X,Y", requires = "sim")]
        at: Option<String>,
        /// Output TIFF (named .tif or .tiff: the file is a 16-bit TIFF whatever its name); the
        /// sidecar is written beside it with the extension .json.
        #[arg(short, long, value_name = "FILE.tiff", value_parser = tiff_path)]
        output: PathBuf,
    },
}

/// An output path named for what it holds: a TIFF.
fn tiff_path(s: &str) -> Result<PathBuf, String> {
    let p = PathBuf::from(s);
    let ext = p
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("tif" | "tiff") => Ok(p),
        _ => Err(format!(
            "`{s}`: the grab is a 16-bit TIFF; name it FILE.tif or FILE.tiff"
        )),
    }
}

pub fn parse_pair(s: &str, what: &str) -> anyhow::Result<(f64, f64)> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .or_usage(|| format!("{what} `{s}`: expected two numbers A,B"))?;
    if v.len() != 2 || !v.iter().all(|x| x.is_finite()) {
        usage_bail!("{what} `{s}`: expected two numbers A,B");
    }
    Ok((v[0], v[1]))
}

/// `rig camera list`.
#[cfg(feature = "v4l2")]
fn list(as_json: bool) -> anyhow::Result<i32> {
    let devs = rig::camera::v4l2::list_devices();
    if as_json {
        println!(
            "{}",
            json!(devs
                .iter()
                .map(|(p, n)| json!({"device": p, "name": n}))
                .collect::<Vec<_>>())
        );
    } else if devs.is_empty() {
        println!("no V4L2 cameras found (is one plugged in, and may this user open /dev/video*?)");
    } else {
        for (p, n) in devs {
            println!("{p}  {n}");
        }
    }
    Ok(0)
}

#[cfg(not(feature = "v4l2"))]
fn list(_as_json: bool) -> anyhow::Result<i32> {
    anyhow::bail!("this rig was built without the V4L2 backend; rebuild with `cargo build --release --features v4l2` (needs libclang) to list cameras")
}

/// Runs `rig camera`; returns the exit code.
pub fn run(a: CameraArgs) -> anyhow::Result<i32> {
    if let CameraAction::List = a.action {
        return list(a.output.json);
    }
    let cfg = super::config::resolve(None, None, a.camera.device.as_ref())?;
    if cfg.camera.value.is_none() && !a.sim.on {
        eprintln!("rig camera: name a camera with --camera DEVICE (/dev/videoN or sim:SOCKET; or RIG_CAMERA, or rig.toml: see `rig config show`), or use --sim");
        return Ok(rig::exit::USAGE);
    }
    let (sim, mut cam): (_, Box<dyn Camera>) = if a.sim.on {
        if !(0.0..=0.5).contains(&a.sim_frame_drop) {
            usage_bail!(
                "--sim-frame-drop {} is out of range: use 0 to 0.5",
                a.sim_frame_drop
            );
        }
        let s = rig_sim::EmbeddedSim::start(rig_sim::SimConfig {
            time_scale: 0.0,
            seed: a.sim.seed,
            start_homed: true,
            film: a.sim_film,
            ..Default::default()
        })
        .context("starting the built-in simulator")?;
        let c = SimCamera::new(s.world.clone(), a.sim_frame_drop);
        (Some(s), Box::new(c))
    } else {
        let Some(dev) = cfg.camera.value.clone() else {
            unreachable!("checked above: a camera, or --sim");
        };
        (None, super::connect::open_device(&dev)?)
    };
    let code = match &a.action {
        CameraAction::List => unreachable!("handled above"),
        CameraAction::Info => {
            let info = cam.info();
            let formats = cam.formats()?;
            if a.output.json {
                println!("{}", json!({"camera": info, "formats": formats}));
            } else {
                println!(
                    "{} ({}): {}×{} px, {} bit, exposure {} ms, gain {}",
                    info.name,
                    info.driver,
                    info.width,
                    info.height,
                    info.bit_depth,
                    info.exposure_ms.map_or("?".into(), |e| format!("{e}")),
                    info.gain.map_or("auto".into(), |g| format!("{g}"))
                );
                for f in formats {
                    println!(
                        "  {} {}×{} {} bit{}",
                        f.fourcc,
                        f.width,
                        f.height,
                        f.bit_depth,
                        f.refused
                            .map(|r| format!(" (refused: {r})"))
                            .unwrap_or_default()
                    );
                }
            }
            0
        }
        CameraAction::Grab {
            frames,
            no_filter,
            stretch: st,
            exposure,
            gain,
            at,
            output,
        } => {
            if *frames == 0 || *frames > 4096 {
                usage_bail!("--frames {frames} is out of range: use 1 to 4096");
            }
            if let Some(ms) = exposure {
                if !(*ms > 0.0 && *ms < 10_000.0) {
                    usage_bail!(
                        "--exposure {ms} is out of range: use more than 0 and less than 10000 ms"
                    );
                }
                cam.set_exposure_ms(*ms)?;
            }
            if let Some(g) = gain {
                let g = if g == "auto" {
                    None
                } else {
                    Some(
                        g.parse::<f64>()
                            .ok()
                            .filter(|v| v.is_finite() && *v > 0.0 && *v <= 1000.0)
                            .with_context(|| {
                                format!(
                                    "--gain `{g}`: a number above 0 and at most 1000, or `auto`"
                                )
                            })?,
                    )
                };
                cam.set_gain(g)?;
            }
            let clip = if st == "none" {
                None
            } else {
                Some(parse_pair(st, "--stretch")?)
            };
            if let Some((lo, hi)) = clip {
                if !(0.0 <= lo && lo < hi && hi <= 100.0) {
                    usage_bail!("--stretch {lo},{hi}: need 0 ≤ LOW < HIGH ≤ 100");
                }
            }
            // With the simulator, put something under the lens.
            let mut stage_mm = None;
            if let Some(s) = &sim {
                let (x, y) = match at {
                    Some(p) => parse_pair(p, "--at")?,
                    None => {
                        let c = s.world.plate.crosses[4].nominal_um;
                        (c[0] / 1000.0, c[1] / 1000.0)
                    }
                };
                let mut st = stage::open(
                    &s.port,
                    stage::Dialect::Native,
                    DriverOptions::default(),
                    &Default::default(),
                )?;
                let p = st.move_to(CarriageUm::from_mm(x, y))?;
                stage_mm = Some([p.x_mm(), p.y_mm()]);
            }
            let info = cam.info();
            let tty = !a.output.json && std::io::IsTerminal::is_terminal(&std::io::stderr());
            // Frames from before the command (or before the stage stood at --at) are set aside.
            let settled = cam.now()?;
            let cap = capture(
                cam.as_mut(),
                *frames,
                !*no_filter,
                Duration::from_secs(5),
                Some(settled),
                |i| {
                    if tty {
                        eprint!("\rframes {i}/{frames}");
                    }
                },
            )?;
            if tty {
                eprintln!();
            }
            let (av, img, stripes) = (cap.averaged, cap.image, cap.stripes);
            let (px, mapping) = match clip {
                Some((lo, hi)) => {
                    let (px, s) = stretch(&img, lo, hi);
                    (
                        px,
                        json!({"kind": "stretch", "low_dn": s.low, "high_dn": s.high, "low_percentile": lo, "high_percentile": hi}),
                    )
                }
                None => {
                    let k = 65535.0 / ((1u64 << info.bit_depth) - 1) as f32;
                    (
                        img.data
                            .iter()
                            .map(|&v| (v * k).round().clamp(0.0, 65535.0) as u16)
                            .collect(),
                        json!({"kind": "linear", "dn_per_output": 1.0 / k}),
                    )
                }
            };
            output::write_tiff16(output, info.width, info.height, &px)
                .with_context(|| format!("writing {}", output.display()))?;
            let noise: f64 =
                av.std.data.iter().map(|&v| v as f64).sum::<f64>() / av.std.data.len() as f64;
            let sidecar = json!({
                "image": output.file_name().map(|f| f.to_string_lossy().to_string()),
                "width": info.width, "height": info.height,
                "source_bit_depth": info.bit_depth,
                "frames": av.frames,
                "dropped_frames": cam.dropped(),
                "exposure_ms": info.exposure_ms,
                "gain": info.gain,
                "camera": info.name,
                "stage_position_mm": stage_mm,
                "mean_frame_noise_dn": noise,
                "stripes": stripes,
                "grey_mapping": mapping,
            });
            let side = output.with_extension("json");
            output::write_json(&side, &sidecar)
                .with_context(|| format!("writing {}", side.display()))?;
            if a.output.json {
                println!("{sidecar}");
            } else {
                println!(
                    "{}: {} frames averaged ({} dropped), {}; sidecar {}",
                    output.display(),
                    av.frames,
                    cam.dropped(),
                    match &stripes {
                        Some(s) => format!(
                            "field shift {:.2} DN and a {}-px column pattern of {:.2} DN removed",
                            s.field_offset,
                            s.column_period.map_or("no".into(), |p| p.to_string()),
                            s.column_amplitude
                        ),
                        None => "not filtered".into(),
                    },
                    side.display()
                );
            }
            0
        }
    };
    if let Some(s) = sim {
        s.shutdown().context("stopping the built-in simulator")?;
    }
    Ok(code)
}
