//! Options several commands take, declared once: `--json` and the session store `--store`.
//! (The connection options are `connect`'s.)

use clap::Args;
use std::path::PathBuf;

/// `--json`: machine-readable output for scripts.
#[derive(Debug, Clone, Copy, Args)]
pub struct JsonOutput {
    /// Print JSON on standard output instead of text: the command's results, report or status
    /// as one document (`rig measure` with several images: an array; `rig stage`'s errors as
    /// {"error": {"kind", "message"}}); the exit code says how it ended.
    #[arg(long, global = true)]
    pub json: bool,
}

/// `--store DIR`: where calibration sessions are kept.
#[derive(Debug, Clone, Args)]
pub struct SessionStore {
    /// Where calibration sessions are kept: each calibration writes one there, `rig calibrate
    /// history` compares them, and a scan whose script names no interior session takes the
    /// newest there.
    #[arg(
        long,
        value_name = "DIR",
        default_value = "rig-sessions",
        global = true
    )]
    pub store: PathBuf,
}
