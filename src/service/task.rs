//! An item's task is checked when it is added or edited, before anything is queued: a move
//! within the soft limits, a scan whose script parses and whose plan stays within them (with
//! the calibration it would scan with), a calibration's numbers in range and its certificate
//! at hand. A task refused here never reaches the hardware.

use super::devices::Settings;
use super::queue::Task;
use crate::coords::CarriageUm;
use crate::scan::{ScanCalibration, ScanScript};
use crate::stage::SoftLimits;
use std::path::{Path, PathBuf};

/// The longest scan script taken, bytes.
pub const MAX_SCRIPT: usize = 256 << 10;

#[derive(Debug, thiserror::Error)]
pub enum TaskError {
    #[error("{field}: {message}")]
    Invalid { field: String, message: String },
    #[error(transparent)]
    Stage(#[from] crate::stage::StageError),
    #[error(transparent)]
    Script(#[from] crate::scan::script::ScriptError),
    #[error(transparent)]
    Scan(#[from] crate::scan::ScanError),
    #[error(transparent)]
    Plan(#[from] crate::scan::plan::PlanError),
}

fn invalid(field: &str, message: impl Into<String>) -> TaskError {
    TaskError::Invalid {
        field: field.into(),
        message: message.into(),
    }
}

/// A name for a folder: 1 to 64 of `A–Z a–z 0–9 . _ -`, not starting with a dot (so no `..`,
/// no `/`, nothing hidden).
pub fn check_name(field: &str, name: &str) -> Result<(), TaskError> {
    let ok = (1..=64).contains(&name.len())
        && !name.starts_with('.')
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'.' || b == b'_' || b == b'-');
    if ok {
        Ok(())
    } else {
        Err(invalid(
            field,
            format!("{name:?} is not a plain name: use 1 to 64 letters, digits, '.', '_' or '-', not starting with '.'"),
        ))
    }
}

/// Checks `task` against the stage's soft limits and the service's settings.
pub fn check(task: &Task, limits: &SoftLimits, settings: &Settings) -> Result<(), TaskError> {
    match task {
        Task::Home => Ok(()),
        Task::Move { x_mm, y_mm } => {
            for (f, v) in [("x_mm", x_mm), ("y_mm", y_mm)] {
                if !v.is_finite() {
                    return Err(invalid(f, "a finite number of millimetres"));
                }
            }
            Ok(limits.check(CarriageUm::from_mm(*x_mm, *y_mm))?)
        }
        Task::Scan { name, script } => {
            check_name("name", name)?;
            if script.len() > MAX_SCRIPT {
                return Err(invalid(
                    "script",
                    format!("{} bytes; at most {MAX_SCRIPT}", script.len()),
                ));
            }
            let s = ScanScript::parse(script, Path::new("script.toml"))?;
            let cal = ScanCalibration::for_script(&s, &settings.store, Some(limits))?;
            crate::scan::plan(&s, &cal, settings.max_memory_mib)?;
            Ok(())
        }
        Task::CalibratePixel {
            frames,
            grid,
            pixel_um,
            plate_cert,
            ..
        } => {
            check_frames(*frames)?;
            if !(2..=15).contains(grid) {
                return Err(invalid("grid", format!("{grid}: use 2 to 15")));
            }
            for v in pixel_um {
                if !(v.is_finite() && (0.1..=1000.0).contains(v)) {
                    return Err(invalid("pixel_um", format!("{v}: use 0.1 to 1000 µm")));
                }
            }
            check_certificate("plate_cert", plate_cert, settings)
        }
        Task::CalibrateInterior {
            frames,
            film_centre_mm,
            pixel_session,
            camera_cert,
        } => {
            check_frames(*frames)?;
            for v in film_centre_mm {
                if !v.is_finite() {
                    return Err(invalid("film_centre_mm", "finite millimetres"));
                }
            }
            limits.check(CarriageUm::from_mm(film_centre_mm[0], film_centre_mm[1]))?;
            // Without a name, the newest pixel session when the item runs: an earlier item of
            // the queue may be the one that makes it.
            if let Some(d) = pixel_session {
                let dir = session_in_store(d, settings).map_err(|m| invalid("pixel_session", m))?;
                crate::calibrate::documents::pixel_transform(&dir)
                    .map_err(|e| invalid("pixel_session", e.to_string()))?;
            }
            check_certificate("camera_cert", camera_cert, settings)
        }
    }
}

fn check_frames(frames: u32) -> Result<(), TaskError> {
    match frames {
        1..=1024 => Ok(()),
        _ => Err(invalid("frames", format!("{frames}: use 1 to 1024"))),
    }
}

/// A certificate must be named on real hardware (the simulator has its own).
fn check_certificate(
    field: &str,
    name: &Option<PathBuf>,
    settings: &Settings,
) -> Result<(), TaskError> {
    match name {
        None if settings.sim => Ok(()),
        None => Err(invalid(
            field,
            "name the certificate: a file in the service's --certificates folder (docs/calibration.md shows its format)",
        )),
        Some(n) => certificate_path(n, settings)
            .map(|_| ())
            .map_err(|m| invalid(field, m)),
    }
}

/// A certificate named by an item: a plain file name in `rig serve --certificates DIR`, never
/// a path (a client must not make the service read any file it can).
pub fn certificate_path(name: &Path, settings: &Settings) -> Result<PathBuf, String> {
    let Some(dir) = &settings.certificates else {
        return Err(
            "this service takes no certificates by name: start it with --certificates DIR".into(),
        );
    };
    let plain = name
        .to_str()
        .filter(|n| check_name("certificate", n).is_ok());
    match plain {
        Some(n) if dir.join(n).is_file() => Ok(dir.join(n)),
        Some(n) => Err(format!("no certificate {n:?} in {}", dir.display())),
        None => Err(format!(
            "{:?}: a certificate is named by its file name in the --certificates folder",
            name
        )),
    }
}

/// A pixel session named by an item: a session's folder name in the store.
pub fn session_in_store(name: &Path, settings: &Settings) -> Result<PathBuf, String> {
    match name.to_str().filter(|n| check_name("session", n).is_ok()) {
        Some(n) if settings.store.join(n).is_dir() => Ok(settings.store.join(n)),
        Some(n) => Err(format!("no session {n:?} in {}", settings.store.display())),
        None => Err(format!(
            "{:?}: a session is named by its folder's name in the store",
            name
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_that_could_leave_the_folder_are_refused() {
        for bad in [
            "",
            "..",
            "../x",
            "a/b",
            ".hidden",
            "a\\b",
            "a b",
            "x\0",
            &"a".repeat(65),
        ] {
            assert!(check_name("name", bad).is_err(), "{bad:?}");
        }
        for good in ["film-12", "roll_3.b", "A"] {
            check_name("name", good).unwrap();
        }
    }
}
