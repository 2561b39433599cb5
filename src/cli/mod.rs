//! The `rig` command line.

pub mod stage_cmd;

use clap::{Parser, Subcommand};

/// The rig: digitise and calibrate aerial film on a camera over motorised X/Y stages.
///
/// Every hardware command runs against real hardware (`--stage PATH`) or against the
/// built-in simulator (`--sim`), which behaves like the hardware and knows the truth.
#[derive(Debug, Parser)]
#[command(name = "rig", version, propagate_version = true, max_term_width = 100)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Drive the X/Y stages: status, home, move, jog, stop.
    Stage(stage_cmd::StageArgs),
    /// Run the simulated stage controller on a pseudo-terminal (same as `rig-sim`).
    Sim(rig_sim::cli::SimArgs),
}
