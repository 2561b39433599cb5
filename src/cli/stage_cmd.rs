//! `rig stage`: drive the X/Y stages.

use super::usage::{usage_bail, OrUsage};
use anyhow::Context;
use clap::{Args, Subcommand};
use rig::coords::CarriageUm;
use rig::stage::{
    self, Approach, Dialect, DriverOptions, LinkOptions, Stage, StageError, TimeoutPolicy,
};
use serde_json::json;
use signal_hook::consts::SIGINT;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

/// Options of `rig stage` (its help text is on `Command::Stage`).
#[derive(Debug, Args)]
pub struct StageArgs {
    #[command(flatten)]
    pub port: super::connect::StagePort,
    /// The simulator: a controller of the chosen dialect, started homed.
    #[command(flatten)]
    pub sim: super::connect::Simulated,
    /// Simulator: wall seconds per simulated second (0 = no waiting).
    #[arg(
        long,
        default_value_t = 0.2,
        value_name = "S",
        requires = "sim",
        global = true
    )]
    pub sim_time_scale: f64,
    /// Simulator: faults to inject (see `rig sim --help`).
    #[arg(long, value_name = "SPEC", requires = "sim", global = true)]
    pub sim_faults: Option<String>,
    /// Simulator: write its truth file here when done.
    #[arg(long, value_name = "PATH", requires = "sim", global = true)]
    pub sim_truth: Option<PathBuf>,
    /// Simulator (GRBL): a board setting other than the default, `N=VALUE`, repeatable
    /// (e.g. `10=0` WPos reports, `13=1` inches, `23=3` homing toward the − switches).
    #[arg(long, value_name = "N=VALUE", value_parser = rig_sim::cli::parse_setting, requires = "sim", global = true)]
    pub sim_grbl_setting: Vec<(u32, f64)>,
    /// Simulator (native): report a setting as this value, `NAME=VALUE`, repeatable (e.g.
    /// `MaxSpeed=0`): a misconfigured controller.
    #[arg(long, value_name = "NAME=VALUE", value_parser = rig_sim::cli::parse_native_setting, requires = "sim", global = true)]
    pub sim_native_setting: Vec<(firmware_protocol::SettingId, i32)>,
    #[command(flatten)]
    pub output: super::shared_args::JsonOutput,
    /// Direction every target is finally approached from, to take out backlash: `+`, `-`,
    /// or `none`.
    #[arg(long, default_value = "+", value_parser = ["+", "-", "none"], global = true)]
    pub approach: String,
    /// How far before the target the approach starts, µm (more than the backlash).
    #[arg(long, default_value_t = 50.0, value_name = "UM", global = true)]
    pub overshoot_um: f64,
    /// Largest accepted difference between target and reported position, µm.
    #[arg(long, default_value_t = 2.0, value_name = "UM", global = true)]
    pub tolerance_um: f64,
    /// Move speed, mm/s (default: the controller's maximum).
    #[arg(long, value_name = "MM_S", global = true)]
    pub speed: Option<f64>,
    /// Motion timeout = expected duration × this + --timeout-margin.
    #[arg(long, default_value_t = 1.5, global = true)]
    pub timeout_factor: f64,
    /// Seconds added to every motion timeout.
    #[arg(long, default_value_t = 2.0, value_name = "S", global = true)]
    pub timeout_margin: f64,
    /// Absolute cap on any one wait, s (a motion, a homing cycle): whatever the controller's
    /// rates say, no wait is longer (and none is longer than its expected time plus 60 s).
    #[arg(long, default_value_t = 600.0, value_name = "S", global = true)]
    pub timeout: f64,
    /// Record every byte on the line, both ways, as JSON Lines.
    #[arg(long, value_name = "FILE", global = true)]
    pub wire_log: Option<PathBuf>,
    #[command(subcommand)]
    pub action: Action,
}

#[derive(Debug, Subcommand)]
pub enum Action {
    /// Where the carriage is and what the controller is doing.
    Status,
    /// What the controller is: identity, travel, soft limits, speed, acceleration.
    Info,
    /// Home both axes (seek the switches, set the reference).
    Home,
    /// Move to X Y (mm), approached from one direction, position verified.
    Move {
        #[arg(allow_negative_numbers = true)]
        x: f64,
        #[arg(allow_negative_numbers = true)]
        y: f64,
        /// X and Y are offsets from the current position.
        #[arg(long)]
        relative: bool,
    },
    /// Jog by DX DY (mm) at a gentle speed, clipped to the soft limits.
    Jog {
        #[arg(allow_negative_numbers = true)]
        dx: f64,
        #[arg(allow_negative_numbers = true)]
        dy: f64,
        /// Jog speed, mm/s.
        #[arg(long = "jog-speed", default_value_t = 2.0, value_name = "MM_S")]
        jog_speed: f64,
    },
    /// Stop the stages and say how: a decelerating stop (GRBL: feed hold), escalated to a
    /// reset (position lost) if the controller does not confirm it in time. Exit 9 if even that
    /// is not confirmed.
    Stop,
    /// Read the controller's settings and say what to change for the rig (GRBL: `$22=1`
    /// homing, `$20=1` soft limits, `$21=1` hard limits, …). Moves nothing.
    #[command(visible_alias = "doctor")]
    CheckSetup,
    /// Stop at once (the position may be lost: home afterwards).
    Estop,
}

/// The motion options, checked; an error is bad usage (exit code 2).
fn options(a: &StageArgs) -> Result<DriverOptions, String> {
    let dir = match a.approach.as_str() {
        "+" => 1.0,
        "-" => -1.0,
        _ => 0.0,
    };
    // (written so that NaN fails too)
    let checks = [
        (
            "--overshoot-um",
            a.overshoot_um,
            a.overshoot_um >= 0.0 && a.overshoot_um < 10_000.0,
            "0 to 10000 µm",
        ),
        (
            "--tolerance-um",
            a.tolerance_um,
            a.tolerance_um > 0.0 && a.tolerance_um < 1000.0,
            "above 0 and below 1000 µm",
        ),
        (
            "--timeout-factor",
            a.timeout_factor,
            a.timeout_factor >= 1.0 && a.timeout_factor < 100.0,
            "1 to 100",
        ),
        (
            "--timeout-margin",
            a.timeout_margin,
            a.timeout_margin >= 0.0 && a.timeout_margin < 3600.0,
            "0 to 3600 s",
        ),
        (
            "--timeout",
            a.timeout,
            a.timeout >= 1.0 && a.timeout <= 86_400.0,
            "1 to 86400 s",
        ),
        (
            "--speed",
            a.speed.unwrap_or(1.0),
            a.speed.is_none_or(|v| v > 0.0 && v < 10_000.0),
            "above 0 mm/s",
        ),
    ];
    for (name, value, ok, range) in checks {
        if !ok {
            return Err(format!("{name} {value} is out of range: use {range}"));
        }
    }
    Ok(DriverOptions {
        approach: Approach {
            direction: [dir, dir],
            overshoot_um: a.overshoot_um,
        },
        // Both range-checked above.
        timeouts: TimeoutPolicy {
            factor: a.timeout_factor,
            margin: stage::secs(a.timeout_margin),
            cap: stage::secs(a.timeout),
        },
        tolerance_um: a.tolerance_um,
        speed_um_s: a.speed.map(|s| s * 1000.0),
        limits: a.port.limits,
    })
}

fn status_json(st: &stage::StageStatus) -> serde_json::Value {
    json!({
        "x_mm": st.position.x_mm(),
        "y_mm": st.position.y_mm(),
        "state": st.state,
        "controller_state": st.controller_state,
        "homed": st.homed,
        "limit_switches": st.limit_switches,
        "fault": st.fault,
    })
}

/// The result of one action: a JSON document and its text rendering.
struct Outcome {
    json: serde_json::Value,
    text: String,
}

fn act(stage: &mut dyn Stage, action: &Action) -> Result<Outcome, StageError> {
    Ok(match action {
        Action::Status => {
            let st = stage.status()?;
            let text = format!(
                "{} at X {:.4} mm, Y {:.4} mm{}{}{}",
                st.controller_state,
                st.position.x_mm(),
                st.position.y_mm(),
                if st.homed {
                    ""
                } else {
                    " (not homed: `rig stage home` references it)"
                },
                if st.limit_switches.is_empty() {
                    String::new()
                } else {
                    format!(", limit switch {} closed", st.limit_switches)
                },
                st.fault
                    .as_ref()
                    .map(|f| format!(", fault: {f}"))
                    .unwrap_or_default()
            );
            Outcome {
                json: status_json(&st),
                text,
            }
        }
        Action::Info => {
            let i = stage.info().clone();
            let l = stage.limits();
            let text = format!(
                "{} ({})\ntravel      {:.3} × {:.3} mm\nsoft limits X {:.3}..{:.3} mm, Y {:.3}..{:.3} mm\nmax speed   {:.2} mm/s, acceleration {:.1} mm/s²\nresolution  {} µm{}",
                i.identity, i.dialect, i.travel.x_mm(), i.travel.y_mm(), l.min.x_mm(), l.max.x_mm(), l.min.y_mm(), l.max.y_mm(),
                i.max_speed_um_s / 1000.0, i.accel_um_s2 / 1000.0, i.resolution_um,
                i.notes.iter().map(|n| format!("\nnote: {n}")).collect::<String>()
            );
            let json = json!({
                "identity": i.identity, "dialect": i.dialect,
                "travel_mm": [i.travel.x_mm(), i.travel.y_mm()],
                "soft_limits_mm": {"x": [l.min.x_mm(), l.max.x_mm()], "y": [l.min.y_mm(), l.max.y_mm()]},
                "max_speed_mm_s": i.max_speed_um_s / 1000.0, "accel_mm_s2": i.accel_um_s2 / 1000.0,
                "resolution_um": i.resolution_um, "notes": i.notes,
            });
            Outcome { json, text }
        }
        Action::Home => {
            let p = stage.home()?;
            let st = stage.status()?;
            Outcome {
                text: format!("homed; carriage at {p}"),
                json: status_json(&st),
            }
        }
        Action::Move { x, y, relative } => {
            let p = if *relative {
                stage.move_by(CarriageUm::from_mm(*x, *y))?
            } else {
                stage.move_to(CarriageUm::from_mm(*x, *y))?
            };
            let st = stage.status()?;
            let mut j = status_json(&st);
            j["verified_x_mm"] = json!(p.x_mm());
            j["verified_y_mm"] = json!(p.y_mm());
            Outcome {
                text: format!("at {p} (verified)"),
                json: j,
            }
        }
        Action::Jog { dx, dy, jog_speed } => {
            if jog_speed.is_nan() || *jog_speed <= 0.0 {
                return Err(StageError::Rejected {
                    command: "jog".into(),
                    reason: "--jog-speed must be positive".into(),
                });
            }
            let p = stage.jog(CarriageUm::from_mm(*dx, *dy), jog_speed * 1000.0)?;
            let st = stage.status()?;
            Outcome {
                text: format!("jogged to {p}"),
                json: status_json(&st),
            }
        }
        Action::Stop => {
            let stopped = stage.stop()?;
            Outcome {
                text: stopped_text(&stopped),
                json: stopped_json(&stopped),
            }
        }
        Action::CheckSetup => {
            let i = stage.info().clone();
            let mut text = format!("{} ({})\n", i.identity, i.dialect);
            for (k, v) in &i.settings {
                text.push_str(&format!("  {k:<5} = {v}\n"));
            }
            if i.advice.is_empty() {
                text.push_str("nothing to change: the set-up is what the rig needs");
            } else {
                for a in &i.advice {
                    text.push_str(&format!("{}: now {}; {}\n", a.setting, a.now, a.todo));
                }
            }
            if i.dialect == "grbl" {
                text.push_str(
                    "\nBuild options (config.h) the rig needs: HOMING_CYCLE_0 homes X and Y only \
                     (no Z switch: GRBL's default cycle starts with Z and fails with ALARM:9), \
                     HOMING_FORCE_SET_ORIGIN off (machine zero on the homing switch).",
                );
            }
            for n in &i.notes {
                text.push_str(&format!("\nnote: {n}"));
            }
            let json = json!({
                "identity": i.identity, "dialect": i.dialect, "settings": i.settings,
                "advice": i.advice, "notes": i.notes,
            });
            Outcome {
                text: text.trim_end().to_string(),
                json,
            }
        }
        Action::Estop => {
            stage.emergency_stop()?;
            let st = stage.status()?;
            Outcome {
                text: "emergency stop: home before moving again".into(),
                json: status_json(&st),
            }
        }
    })
}

/// What a stop did, in words.
fn stopped_text(s: &stage::Stopped) -> String {
    let mut t = s.action.describe().to_string();
    if let Some(p) = s.position {
        t.push_str(&format!("; at {p}"));
    }
    if let Some(f) = &s.fault {
        t.push_str(&format!(
            "; the controller is in a fault: {f} (clear it, then home)"
        ));
    }
    t
}

fn stopped_json(s: &stage::Stopped) -> serde_json::Value {
    let mut j = json!({"action": s.action, "done": s.action.describe(), "fault": s.fault});
    if let Some(p) = s.position {
        j["x_mm"] = json!(p.x_mm());
        j["y_mm"] = json!(p.y_mm());
    }
    j
}

/// A one-line "working…" indicator on stderr while a slow action runs, only on an interactive
/// terminal (never in scripts, never with --json).
struct Progress {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Progress {
    fn start(label: &'static str, show: bool) -> Progress {
        use std::io::{IsTerminal, Write};
        use std::sync::atomic::{AtomicBool, Ordering};
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let thread = (show && std::io::stderr().is_terminal()).then(|| {
            let stop = stop.clone();
            std::thread::spawn(move || {
                let t0 = std::time::Instant::now();
                let spin = ['|', '/', '-', '\\'];
                let mut i = 0;
                while !stop.load(Ordering::Relaxed) {
                    std::thread::sleep(Duration::from_millis(100));
                    if t0.elapsed() > Duration::from_millis(500) {
                        eprint!(
                            "\r{} {label}… {:.1} s ",
                            spin[i % 4],
                            t0.elapsed().as_secs_f64()
                        );
                        let _ = std::io::stderr().flush();
                        i += 1;
                    }
                }
                if i > 0 {
                    eprint!("\r{:width$}\r", "", width = label.len() + 16);
                }
            })
        });
        Progress { stop, thread }
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn label(a: &Action) -> &'static str {
    match a {
        Action::Home => "homing",
        Action::Move { .. } => "moving",
        Action::Jog { .. } => "jogging",
        Action::Stop => "stopping",
        _ => "talking to the controller",
    }
}

/// Runs `rig stage`; returns the process exit code.
pub fn run(a: StageArgs) -> anyhow::Result<i32> {
    let cfg = super::config::resolve(a.port.stage.as_ref(), a.port.dialect, None)?;
    if cfg.stage.value.is_none() && !a.sim.on {
        eprintln!("rig stage: name the controller with --stage PATH (and --dialect native|grbl), or use --sim");
        return Ok(rig::exit::USAGE);
    }
    let opts = match options(&a) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("rig stage: {e}");
            return Ok(rig::exit::USAGE);
        }
    };
    let mut sim = None;
    let port = if a.sim.on {
        let faults = match &a.sim_faults {
            Some(s) => rig_sim::FaultSpec::parse(s).or_usage(|| format!("--sim-faults `{s}`"))?,
            None => rig_sim::FaultSpec::default(),
        };
        if a.sim_time_scale.is_nan() || a.sim_time_scale < 0.0 {
            usage_bail!("--sim-time-scale must be 0 or more");
        }
        let cfg = rig_sim::SimConfig {
            dialect: match cfg.dialect() {
                Dialect::Native => rig_sim::Dialect::Native,
                Dialect::Grbl => rig_sim::Dialect::Grbl,
            },
            time_scale: a.sim_time_scale,
            seed: a.sim.seed,
            faults,
            truth: a.sim_truth.clone(),
            stage_link: None,
            start_homed: true,
            grbl_settings: a.sim_grbl_setting.clone(),
            native_settings: a.sim_native_setting.clone(),
            ..Default::default()
        };
        let s = rig_sim::EmbeddedSim::start(cfg).context("starting the built-in simulator")?;
        let p = s.port.clone();
        sim = Some(s);
        p
    } else {
        match cfg.stage.value.clone() {
            Some(p) => p,
            None => unreachable!("checked above: a port, or --sim"),
        }
    };
    // Ctrl-C: the waiting read gives up, the stages decelerate to a stop, and we exit 130. A
    // second Ctrl-C ends the program at once.
    let cancel = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register_conditional_shutdown(SIGINT, 130, cancel.clone())?;
    signal_hook::flag::register(SIGINT, cancel.clone())?;
    let link = LinkOptions {
        wire_log: a.wire_log.clone(),
        cancel: Some(cancel),
        position: None,
    };
    let progress = Progress::start(label(&a.action), !a.output.json);
    // Stopping takes a controller as an earlier program left it (held, moving, busy).
    let open = match a.action {
        Action::Stop | Action::Estop => stage::open_to_stop,
        _ => stage::open,
    };
    let mut after_cancel = None;
    let result = open(&port, cfg.dialect(), opts, &link).and_then(|mut s| {
        let r = act(s.as_mut(), &a.action);
        if matches!(r, Err(StageError::Cancelled)) {
            // Wait for the deceleration to end before letting go of the line, and say how the
            // stages came to rest (a stop that is not confirmed is an error of its own).
            match s.stop() {
                Ok(stopped) => after_cancel = Some(stopped),
                Err(e) => {
                    return Err(StageError::StopFailed {
                        cause: Box::new(StageError::Cancelled),
                        why: e.to_string(),
                    })
                }
            }
        }
        r
    });
    drop(progress);
    // The command's own error comes first; the simulator's shutdown only adds to it.
    if let Some(s) = sim {
        if let Err(e) = s.shutdown() {
            if result.is_ok() {
                return Err(e).context("stopping the built-in simulator");
            }
            eprintln!("rig stage: note: stopping the built-in simulator also failed: {e}");
        }
    }
    match result {
        Ok(o) => {
            if a.output.json {
                println!("{}", o.json);
            } else {
                println!("{}", o.text);
            }
            Ok(0)
        }
        Err(e) => {
            if a.output.json {
                let mut j = json!({"error": {"kind": e.kind(), "message": e.to_string()}});
                if let Some(s) = &after_cancel {
                    j["stopped"] = stopped_json(s);
                }
                println!("{j}");
            }
            if let Some(s) = &after_cancel {
                eprintln!("rig stage: stopped: {}", stopped_text(s));
            }
            eprintln!("rig stage: {e}");
            Ok(e.exit_code())
        }
    }
}
