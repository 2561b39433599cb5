//! An item's task is checked when it is added or edited, before anything is queued: a move
//! within the soft limits, a scan whose script parses and whose plan stays within them (with
//! the calibration it would scan with). A task refused here never reaches the hardware.

use super::devices::Settings;
use super::queue::Task;
use crate::coords::CarriageUm;
use crate::scan::{ScanCalibration, ScanScript};
use crate::stage::SoftLimits;
use std::path::Path;

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
