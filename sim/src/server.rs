//! The simulator's main loop: the pty, the line faults, the firmware dialect and the stage
//! on a virtual clock, and the truth file.

use crate::camera::CameraConfig;
use crate::faults::{FaultSpec, LineFilter};
use crate::grbl::GrblFirmware;
use crate::native::NativeFirmware;
use crate::plate::Plate;
use crate::pty::Pty;
use crate::rng::Rng;
use crate::stage::{Stage, StageConfig, StageEvent};
use crate::truth::{write_atomic, StageTruth};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::sync::Mutex;
use std::time::{Duration, Instant};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Dialect {
    /// The rig's own binary protocol (firmware-protocol/PROTOCOL.md).
    Native,
    /// GRBL 1.1 G-code and real-time commands.
    Grbl,
}

impl Dialect {
    pub fn name(self) -> &'static str {
        match self {
            Dialect::Native => "native",
            Dialect::Grbl => "grbl",
        }
    }
}

#[derive(Debug, Clone)]
pub struct SimConfig {
    pub dialect: Dialect,
    /// Wall seconds per simulated second; 0 = never wait.
    pub time_scale: f64,
    pub seed: u64,
    pub faults: FaultSpec,
    pub truth: Option<PathBuf>,
    pub stage_link: Option<PathBuf>,
    /// Start as if homed before (for one-shot commands against an embedded simulator).
    pub start_homed: bool,
    /// GRBL settings that differ from the simulated board's defaults (`$N=value`, as an
    /// operator may have set them: `$10` report mask, `$13` inches, `$23` homing directions,
    /// or absurd values for hostile tests). `$23` also decides which end the board's homing
    /// switches are at.
    pub grbl_settings: Vec<(u32, f64)>,
    /// Native controller settings reported as these values instead of the real ones (hostile
    /// tests: `MaxSpeed` 0, `TravelX` 0, inverted soft limits).
    pub native_settings: Vec<(firmware_protocol::SettingId, i32)>,
    /// A film lies on the carriage.
    pub film: bool,
    /// Crosses of the plate with a smudge of dirt over their centre.
    pub dirty_crosses: Vec<u32>,
    /// Fiducials the film lacks (not exposed, torn off); the certificate still lists them.
    pub missing_fiducials: Vec<u32>,
    /// Which photo of the 2×2 block the film is (1, 2 along the first strip; 3, 4 the second).
    pub photo: u32,
    /// The camera has square pixels (10.5 µm) instead of seed 002's 10.19 × 10.96 µm.
    pub square_pixels: bool,
    /// The film camera's fiducials are rings: corners a ring, a dot and four radial lines,
    /// mid-sides a ring and a dot (instead of rings and dots with a line).
    pub ring_fiducials: bool,
    /// Every fiducial of this form (a mark file in µm).
    pub fiducial_mark: Option<crate::marks::SimMark>,
    /// A perfect stage (no repeatability noise, switch noise or drift) and frames that depend
    /// only on where the stage stands and how many were taken there: two runs that visit the
    /// same places see the same pixels, so a resumed scan can be compared byte for byte.
    pub repeatable: bool,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            dialect: Dialect::Native,
            time_scale: 1.0,
            seed: 1,
            faults: FaultSpec::default(),
            truth: None,
            stage_link: None,
            start_homed: false,
            grbl_settings: Vec::new(),
            native_settings: Vec::new(),
            film: false,
            dirty_crosses: Vec::new(),
            missing_fiducials: Vec::new(),
            photo: 1,
            square_pixels: false,
            ring_fiducials: false,
            fiducial_mark: None,
            repeatable: false,
        }
    }
}

enum Firmware {
    Native(NativeFirmware),
    Grbl(GrblFirmware),
}

impl Firmware {
    fn on_bytes(&mut self, b: &[u8], s: &mut Stage, out: &mut Vec<u8>) {
        match self {
            Firmware::Native(f) => f.on_bytes(b, s, out),
            Firmware::Grbl(f) => f.on_bytes(b, s, out),
        }
    }
    fn on_event(&mut self, e: StageEvent, s: &mut Stage, out: &mut Vec<u8>) {
        match self {
            Firmware::Native(f) => f.on_event(e, s, out),
            Firmware::Grbl(f) => f.on_event(e, s, out),
        }
    }
    fn next_event_time(&self) -> Option<f64> {
        match self {
            Firmware::Native(f) => f.next_event_time(),
            Firmware::Grbl(f) => f.next_event_time(),
        }
    }
    fn on_time(&mut self, s: &Stage, out: &mut Vec<u8>) {
        if let Firmware::Native(f) = self {
            f.on_time(s, out)
        }
    }
    fn state_name(&self, s: &Stage) -> String {
        match self {
            Firmware::Native(f) => f.state_name(s),
            Firmware::Grbl(f) => f.state_name(s),
        }
    }
}

/// The simulated world the stage firmware and the camera share: the camera renders what lies
/// under the lens where the stage really is.
pub struct World {
    pub stage: Mutex<Stage>,
    pub camera: CameraConfig,
    pub plate: Plate,
    /// The film of this world (when it has one), on the carriage or lifted off.
    pub film: Option<crate::film::Film>,
    /// The film lies on the carriage (an operator lays and lifts it by hand: see
    /// [`World::film_on_carriage`]).
    pub film_laid: Arc<std::sync::atomic::AtomicBool>,
    pub seed: u64,
    pub time_scale: f64,
    /// See [`SimConfig::repeatable`].
    pub repeatable: bool,
}

impl World {
    pub fn new(cfg: &SimConfig) -> Arc<World> {
        let mut rng = Rng::new(cfg.seed);
        let mut stage_cfg = if cfg.dialect == Dialect::Grbl {
            let mask = cfg
                .grbl_settings
                .iter()
                .rev()
                .find(|(k, _)| *k == 23)
                .map_or(0.0, |(_, v)| *v);
            StageConfig::grbl(&mut rng, crate::grbl::homing_dirs(mask))
        } else {
            StageConfig::native(&mut rng)
        };
        if cfg.repeatable {
            stage_cfg.repeat_sigma_um = 0.0;
            stage_cfg.switch_sigma_um = 0.0;
            stage_cfg.drift_um_per_h = [0.0; 2];
        }
        // Drawn after the stage, so the stage of a seed is the same with or without a camera.
        let mut camera = CameraConfig::new(&mut rng);
        if cfg.square_pixels {
            camera.affine = crate::camera::PixelToCarriage::square();
        }
        let mut plate = Plate::new(&mut rng);
        // Drawn whether loaded or not, so a seed's world is the same either way.
        let mut film = crate::film::Film::rc10(&mut rng, cfg.photo);
        if cfg.ring_fiducials {
            film = film.with_ring_fiducials();
        }
        if let Some(m) = &cfg.fiducial_mark {
            film = film.with_mark(m.clone());
        }
        for id in &cfg.dirty_crosses {
            if let Some(c) = plate.crosses.iter().find(|c| c.id == *id) {
                // Off the centre, so that it would pull a match that used it.
                plate
                    .dirt
                    .push([c.true_um[0] + 35.0, c.true_um[1] + 25.0, 70.0, 0.25]);
            }
        }
        for f in film.fiducials.iter_mut() {
            f.missing = cfg.missing_fiducials.contains(&f.id);
        }
        // Rendering the photo over the terrain takes a moment: only when the film is loaded.
        let film = cfg.film.then(|| film.with_aerial(cfg.seed));
        let stage = Stage::new(stage_cfg, cfg.faults.clone(), cfg.seed, cfg.start_homed);
        Arc::new(World {
            stage: Mutex::new(stage),
            camera,
            plate,
            film_laid: Arc::new(std::sync::atomic::AtomicBool::new(film.is_some())),
            film,
            seed: cfg.seed,
            time_scale: cfg.time_scale,
            repeatable: cfg.repeatable,
        })
    }

    /// The film the camera sees: the world's film while it is laid on the carriage (lifted, the
    /// plate's crosses show again).
    pub fn film_on_carriage(&self) -> Option<&crate::film::Film> {
        self.film
            .as_ref()
            .filter(|_| self.film_laid.load(std::sync::atomic::Ordering::SeqCst))
    }

    /// The stage, even if a thread panicked while holding it (the state is plain data).
    pub fn stage(&self) -> std::sync::MutexGuard<'_, Stage> {
        self.stage.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// A simulator running on a thread of this process (what `rig --sim` uses).
pub struct EmbeddedSim {
    pub world: Arc<World>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<std::io::Result<()>>>,
    pub port: PathBuf,
}

impl EmbeddedSim {
    pub fn start(cfg: SimConfig) -> std::io::Result<EmbeddedSim> {
        let stop = Arc::new(AtomicBool::new(false));
        let (tx, rx) = std::sync::mpsc::channel();
        let s2 = stop.clone();
        let world = World::new(&cfg);
        let w2 = world.clone();
        let thread = std::thread::Builder::new()
            .name("rig-sim".into())
            .spawn(move || {
                serve(&cfg, &w2, &s2, |p| {
                    let _ = tx.send(p.to_path_buf());
                })
            })?;
        match rx.recv_timeout(Duration::from_secs(5)) {
            Ok(port) => Ok(EmbeddedSim {
                world,
                stop,
                thread: Some(thread),
                port,
            }),
            Err(_) => {
                stop.store(true, Ordering::SeqCst);
                let err = thread.join().ok().and_then(|r| r.err());
                Err(err.unwrap_or_else(|| std::io::Error::other("simulator did not start")))
            }
        }
    }

    /// Stops the simulator and writes its final truth.
    pub fn shutdown(mut self) -> std::io::Result<()> {
        self.stop_inner()
    }

    fn stop_inner(&mut self) -> std::io::Result<()> {
        self.stop.store(true, Ordering::SeqCst);
        match self.thread.take() {
            Some(t) => t
                .join()
                .map_err(|_| std::io::Error::other("simulator thread panicked"))?,
            None => Ok(()),
        }
    }
}

impl Drop for EmbeddedSim {
    fn drop(&mut self) {
        let _ = self.stop_inner();
    }
}

/// Runs the stage controller of `world` until `stop` is set. `ready` gets the slave path once
/// it can be opened. The world's stage is locked for each turn of the loop, never while
/// waiting for input.
pub fn serve(
    cfg: &SimConfig,
    world: &World,
    stop: &AtomicBool,
    ready: impl FnOnce(&Path),
) -> std::io::Result<()> {
    let stage = world.stage();
    let mut line = LineFilter::new(cfg.faults.clone(), cfg.seed);
    let mut pty = Some(Pty::open(cfg.stage_link.as_deref())?);
    let mut out = Vec::new();
    let mut fw = match cfg.dialect {
        Dialect::Native => {
            let mut fw = NativeFirmware::new(&stage, (cfg.seed as u32) ^ 0x5151);
            fw.reported = cfg.native_settings.clone();
            Firmware::Native(fw)
        }
        Dialect::Grbl => Firmware::Grbl(GrblFirmware::new(&stage, &cfg.grbl_settings, &mut out)),
    };
    ready(&pty.as_ref().unwrap().slave_path);

    let write_truth = |stage: &Stage,
                       fw: &Firmware,
                       line: &LineFilter,
                       disconnected: bool|
     -> std::io::Result<()> {
        if let Some(p) = &cfg.truth {
            let t = StageTruth::from_stage(
                stage,
                cfg.dialect.name(),
                cfg.seed,
                cfg.time_scale,
                fw.state_name(stage),
                &line.counts,
                disconnected,
            );
            // The stage's truth, and the world the camera sees: its parameters, the
            // pixel→carriage affine and the plate's crosses where they really are.
            let mut v = serde_json::to_value(&t)?;
            v["camera"] = serde_json::to_value(&world.camera)?;
            v["plate"] = serde_json::to_value(&world.plate)?;
            v["film"] = serde_json::to_value(world.film_on_carriage())?;
            write_atomic(p, &v)?;
        }
        Ok(())
    };
    write_truth(&stage, &fw, &line, false)?;
    drop(stage);

    let wall0 = Instant::now();
    let mut last_truth = Instant::now();
    let mut dirty = false;
    let mut disconnected = false;
    let mut buf = [0u8; 4096];
    let mut events = Vec::new();
    while !stop.load(Ordering::SeqCst) {
        let stage = world.stage();
        // Output first, so replies leave before the clock jumps.
        if !out.is_empty() {
            line.outgoing(&out);
            out.clear();
        }
        if let Some(p) = &pty {
            let ready_bytes = line.ready(Instant::now());
            if !ready_bytes.is_empty() {
                let n = p.write(&ready_bytes)?;
                line.unwrite(&ready_bytes[n..]);
            }
        }
        let next_t = match (stage.next_event_time(), fw.next_event_time()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        let wait_ms = if line.has_pending() {
            // Held back by a delay fault: until it ends (input wakes the wait sooner); else
            // the terminal took only part of them: a millisecond for it to drain. (Polling
            // at once here spun a core for the whole delay.)
            match line.held_until() {
                Some(t) => {
                    let us = t.saturating_duration_since(Instant::now()).as_micros();
                    us.div_ceil(1000).min(20) as i32
                }
                None => 1,
            }
        } else if next_t.is_some() && cfg.time_scale == 0.0 {
            0
        } else if next_t.is_some() {
            1
        } else {
            20
        };
        let mut got_input = false;
        drop(stage);
        let readable = pty.as_ref().is_some_and(|p| p.wait_readable(wait_ms));
        let mut stage = world.stage();
        if let Some(p) = &pty {
            if readable {
                let n = p.read(&mut buf)?;
                if n > 0 {
                    got_input = true;
                    let bytes = line.incoming(&buf[..n]);
                    fw.on_bytes(&bytes, &mut stage, &mut out);
                    dirty = true;
                }
            }
        } else {
            std::thread::sleep(Duration::from_millis(wait_ms.max(1) as u64));
        }
        // Advance the virtual clock.
        let target_t = if cfg.time_scale > 0.0 {
            wall0.elapsed().as_secs_f64() / cfg.time_scale
        } else if got_input || !out.is_empty() {
            stage.t
        } else {
            next_t.unwrap_or(stage.t).max(stage.t)
        };
        let fw_t = fw.next_event_time();
        let now = stage.t;
        stage.advance(
            fw_t.map_or(target_t, |f| f.min(target_t).max(now)),
            &mut events,
        );
        if fw_t.is_some_and(|f| f <= target_t) {
            fw.on_time(&stage, &mut out);
            stage.advance(target_t, &mut events);
        }
        for e in events.drain(..) {
            dirty = true;
            if e == StageEvent::Disconnect {
                // The line goes dead: the host's next read fails.
                pty = None;
                disconnected = true;
                continue;
            }
            fw.on_event(e, &mut stage, &mut out);
        }
        if dirty && (!stage.is_busy() || last_truth.elapsed() > Duration::from_millis(200)) {
            write_truth(&stage, &fw, &line, disconnected)?;
            last_truth = Instant::now();
            dirty = false;
        }
    }
    let stage = world.stage();
    write_truth(&stage, &fw, &line, disconnected)
}
