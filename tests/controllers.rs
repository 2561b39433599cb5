//! The tests that wait on simulated controllers, in one binary run by the waiting harness
//! (`common/waiting.rs`): the GRBL and native protocols as documented, stops that leave a board
//! usable, the fault matrix, and `rig stage` from the command line.

mod common;
#[path = "common/fake_grbl.rs"]
mod fake_grbl;

#[path = "controllers/fault_matrix.rs"]
mod fault_matrix;
#[path = "controllers/grbl_documented.rs"]
mod grbl_documented;
#[path = "controllers/grbl_interface.rs"]
mod grbl_interface;
#[path = "controllers/grbl_stop.rs"]
mod grbl_stop;
#[path = "controllers/hostile_stage.rs"]
mod hostile_stage;
#[path = "controllers/native_interface.rs"]
mod native_interface;
#[path = "controllers/stage_cli.rs"]
mod stage_cli;

fn main() {
    common::waiting::run(&[
        ("fault_matrix", fault_matrix::TESTS),
        ("grbl_documented", grbl_documented::TESTS),
        ("grbl_interface", grbl_interface::TESTS),
        ("grbl_stop", grbl_stop::TESTS),
        ("hostile_stage", hostile_stage::TESTS),
        ("native_interface", native_interface::TESTS),
        ("stage_cli", stage_cli::TESTS),
    ])
}
