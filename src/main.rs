//! The `rig` binary.

mod cli;

use clap::Parser;
use cli::{Cli, Command};

fn main() {
    let cli = Cli::parse();
    cli::init_logging(&cli.verbosity);
    let code = match cli.command {
        Command::Stage(a) => cli::stage_cmd::run(a),
        Command::Camera(a) => cli::camera_cmd::run(a),
        Command::Calibrate(a) => cli::calibrate_cmd::run(a),
        Command::Scan(a) => cli::scan_cmd::run(a),
        Command::Sim(cli::SimCmd {
            action: Some(cli::SimAction::Scene(a)),
            ..
        }) => cli::scene_cmd::run(&a),
        Command::Sim(a) => rig_sim::cli::run(a.serve)
            .map(|_| 0)
            .map_err(anyhow::Error::from),
        Command::Dtm(a) => cli::dtm_cmd::run(a),
        Command::Demo(a) => cli::demo_cmd::run(&a),
        Command::Config(c) => match c.action {
            cli::ConfigAction::Show => cli::config::show(
                c.port.stage.as_ref(),
                c.port.dialect,
                c.camera.device.as_ref(),
                c.json,
            ),
        },
        c @ (Command::Completions { .. } | Command::Man { .. }) => cli::docs(&c),
    };
    match code {
        Ok(c) => std::process::exit(c),
        Err(e) => {
            eprintln!("rig: {e:#}");
            std::process::exit(cli::exit_code_of(&e));
        }
    }
}
