//! What an item does on the hardware thread: a home, a move, a scan (as `rig scan run`, into
//! the item's own folder, continued from its manifest on every later attempt), a calibration
//! (`calibration`).

use super::devices::{position_json, Ended, Look, Ran, Rig};
use super::events::{Bus, Kind};
use super::queue::{ItemId, Task};
use crate::coords::CarriageUm;
use crate::scan::run::{Outcome, Progress, Reopen, RunOptions, ScanRig};
use crate::scan::{ScanCalibration, ScanDir, ScanError, ScanScript};
use serde_json::json;
use std::path::Path;
use std::sync::Mutex;
use std::time::Duration;

/// The script's copy in the item's folder, and the scan's folder beside it.
pub const SCRIPT: &str = "script.toml";
pub const SCAN: &str = "scan";

/// Runs `task` of item `id` (its files in `dir`). Interruptions are mapped by the caller.
pub fn run(rig: &mut Rig, id: ItemId, task: &Task, dir: &Path) -> Ran {
    let r = match task {
        Task::Home => rig
            .dev
            .stage
            .home()
            .map(|p| Some(json!({"position": position_json(p)})))
            .map_err(|e| e.to_string()),
        Task::Move { x_mm, y_mm } => rig
            .dev
            .stage
            .move_to(CarriageUm::from_mm(*x_mm, *y_mm))
            .map(|p| Some(json!({"position": position_json(p)})))
            .map_err(|e| match e {
                crate::stage::StageError::NotHomed => super::devices::NOT_HOMED.to_string(),
                e => e.to_string(),
            }),
        Task::Scan { script, .. } => scan(rig, id, script, dir),
        Task::CalibratePixel { .. } | Task::CalibrateInterior { .. } => {
            super::calibration::run(rig, id, task).map(Some)
        }
    };
    if let Ok(p) = rig.dev.stage.position() {
        rig.bus.position(position_json(p), true);
    }
    match r {
        Ok(Some(result)) => Ran {
            ended: Ended::Done,
            message: None,
            result: Some(result),
        },
        // Paused at a tile boundary.
        Ok(None) => Ran {
            ended: Ended::Paused,
            message: None,
            result: None,
        },
        Err(message) => Ran {
            ended: Ended::Failed,
            message: Some(message),
            result: None,
        },
    }
}

/// The scan of a script's text into `dir/scan`: planned and begun on the first attempt,
/// continued from its manifest on later ones (a resumed scan takes its last tile again and
/// checks that the film did not move). `Ok(None)`: paused at a tile boundary.
fn scan(
    rig: &mut Rig,
    id: ItemId,
    text: &str,
    dir: &Path,
) -> Result<Option<serde_json::Value>, String> {
    let out = dir.join(SCAN);
    let script_path = dir.join(SCRIPT);
    let r = (|| -> Result<Option<serde_json::Value>, ScanError> {
        std::fs::create_dir_all(dir)?;
        if !script_path.exists() {
            crate::atomic::write_with(&script_path, |w| {
                std::io::Write::write_all(w, text.as_bytes())
            })?;
        }
        let mut s = ScanScript::parse(text, &script_path)
            .map_err(|e| std::io::Error::other(e.to_string()))?;
        s.out_dir = out.clone();
        let check = Reopen {
            limits: rig.settings.limits,
            max_memory_mib: rig.settings.max_memory_mib,
        };
        let mut sd = if out.join(crate::scan::manifest::MANIFEST).exists() {
            ScanDir::resume(&out, s, &check)?
        } else {
            let cal =
                ScanCalibration::for_script(&s, &rig.settings.store, rig.settings.limits.as_ref())?;
            let p = crate::scan::plan(&s, &cal, rig.settings.max_memory_mib)?;
            ScanDir::create(&out, s, cal, p)?
        };
        let bus = rig.bus;
        let last_look = rig.last_look;
        let tiles = out.clone();
        let mut progress = |p: Progress| {
            bus.publish(
                Kind::Progress,
                json!({"item": id, "step": p.done, "of": p.total, "tile": p.tile, "seconds_left": p.eta_s}),
            );
            if !p.tile.is_empty() && bus.clients() > 0 {
                preview(bus, last_look, &tiles, p.tile);
            }
        };
        // Homed at the start, and again after a halt or a restart left the stage unhomed.
        let home = sd.manifest.done() == 0 || !rig.dev.stage.status()?.homed;
        let outcome = crate::scan::run::run(
            &mut sd,
            &mut ScanRig {
                stage: rig.dev.stage.as_mut(),
                camera: rig.dev.camera.as_mut(),
            },
            &RunOptions {
                home,
                pause: &rig.control.pause,
                frame_timeout: Duration::from_secs(5),
            },
            &mut progress,
        );
        match outcome {
            Ok(Outcome::Complete { photos }) => Ok(Some(json!({
                "dir": out,
                "manifest": out.join(crate::scan::manifest::MANIFEST),
                "tiles": sd.manifest.tiles.len(),
                "photos": photos,
            }))),
            Ok(Outcome::Paused { .. }) => Ok(None),
            Err(e) => {
                let _ = sd.log.stop("interrupted", Some(&e.to_string()));
                Err(e)
            }
        }
    })();
    r.map_err(|e| e.to_string())
}

/// The newest tile as the live view's frame, and a preview event naming it.
fn preview(bus: &Bus, last: &Mutex<Option<Look>>, dir: &Path, tile: &str) {
    let path = dir.join(crate::scan::run::tile_file(tile));
    if let Ok(img) = crate::digitise::output::read_tiff16_f32(&path) {
        super::devices::show(bus, last, &img, json!({"tile": tile}));
    }
}
