//! The simulator's truth file: where the carriage really is and what was done to it. Written
//! atomically (temporary file, then rename), so a reader never sees half a document.

use crate::faults::{FaultSpec, LineFaultCounts};
use crate::stage::{InjectedFault, Stage, StageConfig};
use serde::Serialize;
use std::io::Write;
use std::path::Path;

#[derive(Serialize)]
pub struct StageTruth<'a> {
    pub dialect: &'a str,
    pub seed: u64,
    pub time_scale: f64,
    pub virtual_time_s: f64,
    /// Physical configuration: travel, steps, backlash, noise, drift, switches.
    pub config: &'a StageConfig,
    pub faults_requested: &'a FaultSpec,
    /// Where the carriage is, µm, in carriage coordinates (0..travel), drift included.
    pub carriage_um: [f64; 2],
    /// What the controller believes (its logical position), µm, in its own frame.
    pub controller_logical_um: [f64; 2],
    pub homed: bool,
    pub controller_state: String,
    pub busy: bool,
    /// Extremes the carriage reached since it was last homed, µm: [[x_min, x_max], [y_min, y_max]].
    pub excursion_um: Option<[[f64; 2]; 2]>,
    /// Every motion target the controller accepted, in carriage coordinates, µm.
    pub accepted_targets_um: Vec<[f64; 2]>,
    pub moves_completed: u64,
    pub injected_faults: &'a [InjectedFault],
    pub line_faults: &'a LineFaultCounts,
    pub disconnected: bool,
}

impl<'a> StageTruth<'a> {
    #[allow(clippy::too_many_arguments)]
    pub fn from_stage(
        stage: &'a Stage,
        dialect: &'a str,
        seed: u64,
        time_scale: f64,
        controller_state: String,
        line_faults: &'a LineFaultCounts,
        disconnected: bool,
    ) -> Self {
        StageTruth {
            dialect,
            seed,
            time_scale,
            virtual_time_s: stage.t,
            config: &stage.cfg,
            faults_requested: &stage.faults,
            carriage_um: [stage.carriage_true(0), stage.carriage_true(1)],
            controller_logical_um: [stage.logical(0), stage.logical(1)],
            homed: stage.homed,
            controller_state,
            busy: stage.is_busy(),
            excursion_um: stage.excursion,
            accepted_targets_um: stage
                .accepted_targets
                .iter()
                .map(|t| {
                    [
                        t[0] + stage.logical_to_carriage(0),
                        t[1] + stage.logical_to_carriage(1),
                    ]
                })
                .collect(),
            moves_completed: stage.moves_done,
            injected_faults: &stage.injected,
            line_faults,
            disconnected,
        }
    }
}

/// Writes `value` as pretty JSON to `path` atomically: the document made in memory and
/// written in one call (token by token into the file it was half a million writes on a long
/// calibration's truth, on the stage server's thread, enough to make it miss its answers
/// under load).
pub fn write_atomic<T: Serialize>(path: &Path, value: &T) -> std::io::Result<()> {
    let tmp = path.with_extension("json.tmp");
    let mut text = serde_json::to_vec_pretty(value)?;
    text.push(b'\n');
    {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(&text)?;
        f.sync_data()?;
    }
    std::fs::rename(&tmp, path)
}
