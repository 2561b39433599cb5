//! The `rig` binary.

mod cli;

use clap::Parser;
use cli::{Cli, Command};

fn main() {
    let cli = Cli::parse();
    if !serves_clients(&cli.command) {
        quiet_on_closed_pipe();
    }
    cli::init_logging(&cli.verbosity);
    limit_simd_from_env();
    let code = match cli.command {
        Command::Stage(a) => cli::stage_cmd::run(a),
        Command::Camera(a) => cli::camera_cmd::run(a),
        Command::Calibrate(a) => cli::calibrate_cmd::run(a),
        Command::Scan(a) => cli::scan_cmd::run(a),
        Command::Serve(a) => cli::serve_cmd::run(a),
        Command::Queue(a) => cli::client_cmd::queue(a),
        Command::Run(a) => cli::client_cmd::run(a),
        Command::Events(a) => cli::client_cmd::events(a),
        Command::Sim(cli::SimCmd {
            action: Some(cli::SimAction::Scene(a)),
            ..
        }) => cli::scene::run(&a),
        Command::Sim(a) => rig_sim::cli::run(a.serve)
            .map(|_| 0)
            .map_err(anyhow::Error::from),
        Command::Dtm(a) => cli::dtm_cmd::run(a),
        Command::Orient(a) => cli::orient_cmd::run(a),
        Command::Match(a) => cli::match_cmd::run(a),
        Command::Measure(a) => cli::measure_cmd::run(a),
        Command::Demo(a) => cli::demo::run(&a),
        Command::Config(c) => match c.action {
            cli::ConfigAction::Show => cli::config::show(
                c.port.stage.as_ref(),
                c.port.dialect,
                c.camera.device.as_ref(),
                c.output.json,
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

/// The servers (`rig serve`, `rig sim`) keep SIGPIPE ignored, as Rust leaves it: a client that
/// vanishes while a reply is written is an error on that connection, never the end of the
/// service (hyper writes with `writev`, which raises SIGPIPE where `send` would not).
fn serves_clients(c: &Command) -> bool {
    match c {
        Command::Serve(a) => a.action.is_none(),
        Command::Sim(cli::SimCmd { action, .. }) => action.is_none(),
        _ => false,
    }
}

/// A closed pipe (`rig … | head`) ends the program quietly, as it ends any Unix tool, instead of
/// a panic at the next print. The commands print before or after motion, never during it, and
/// a scan ended so resumes from its checkpoint.
fn quiet_on_closed_pipe() {
    // SAFETY: called first thing after parsing the arguments, before any other thread exists; SIG_DFL is a valid
    // disposition for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// `RIG_SIMD=baseline|avx2|avx512` caps the instruction set the hot loops are built for (all
/// give the same numbers; to compare them, or to rule one out on a suspect machine).
fn limit_simd_from_env() {
    use rig::simd::Level;
    let Ok(v) = std::env::var("RIG_SIMD") else {
        return;
    };
    if v.trim().is_empty() {
        return;
    }
    match Level::parse(&v) {
        Some(l) => rig::simd::limit(l),
        None => {
            eprintln!(
                "rig: RIG_SIMD={v:?} is not one of {}; unset it to use the best this CPU has",
                Level::NAMES
            );
            std::process::exit(rig::exit::USAGE);
        }
    }
}
