//! The one table of exit codes of the `rig` command, the same for every subcommand (docs/cli.md,
//! "Exit codes"; `rig --help`). The stage's errors map onto it (`StageError::exit_code`), and
//! keep their code whichever command met them (`cli::exit_code_of`).

/// Done.
pub const OK: i32 = 0;
/// Any other error: the message says what and where.
pub const OTHER: i32 = 1;
/// Bad usage: a flag, a value or a missing argument, refused by the parser or by the
/// command's own check (`cli::usage`).
pub const USAGE: i32 = 2;
/// Refused before anything moved: a target or a scan plan outside the soft limits.
pub const OUTSIDE_LIMITS: i32 = 3;
/// No answer, or a motion took too long (the stages were stopped).
pub const TIMEOUT: i32 = 4;
/// A fault or alarm of the stage, or not homed.
pub const FAULT: i32 = 5;
/// The position check after a move failed (the stages were stopped).
pub const POSITION: i32 = 6;
/// The port cannot be opened, is busy, or the link died.
pub const PORT: i32 = 7;
/// The controller refused a command, speaks another protocol, or reports a setting out of
/// range.
pub const REFUSED: i32 = 8;
/// A stop was not confirmed: the motion may go on. Go to the machine.
pub const STOP_NOT_CONFIRMED: i32 = 9;
/// `rig calibrate history` found drift.
pub const DRIFT: i32 = 10;
/// A scan paused (Ctrl-C once): continue it with `--resume`.
pub const PAUSED: i32 = 11;
/// `rig dtm --strict`: the run warned (heights piled at a bound of the range, few matched):
/// its outputs are written but doubtful; `rig measure --strict`: a mark was refused.
pub const DOUBTFUL: i32 = 12;
/// Interrupted by Ctrl-C (the stages were stopped).
pub const INTERRUPTED: i32 = 130;

/// The table as `--help` shows it.
pub const TABLE: &str = "Exit codes (every command):
  0 done                         6 position check failed (stages stopped)
  1 any other error              7 port cannot be opened, busy, or the link died
  2 bad usage                    8 controller refused a command or a setting
  3 outside the soft limits      9 a stop NOT confirmed: the motion may go on
    (nothing moved)             10 calibration history found drift
  4 no answer or timeout        11 scan paused: continue with --resume
    (stages stopped)            12 --strict: the run warned
  5 stage fault, alarm or      130 Ctrl-C (stages stopped)
    not homed";

#[cfg(test)]
mod tests {
    use super::*;

    /// Every code in the table is written in it once.
    #[test]
    fn the_table_names_every_code() {
        for c in [
            OK,
            OTHER,
            USAGE,
            OUTSIDE_LIMITS,
            TIMEOUT,
            FAULT,
            POSITION,
            PORT,
            REFUSED,
        ] {
            assert!(TABLE.contains(&format!(" {c} ")), "{c}");
        }
        for c in [STOP_NOT_CONFIRMED, DRIFT, PAUSED, DOUBTFUL, INTERRUPTED] {
            assert!(TABLE.contains(&format!("{c} ")), "{c}");
        }
    }
}
