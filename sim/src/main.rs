use clap::Parser;

#[derive(Parser)]
#[command(
    name = "rig-sim",
    version,
    about = "The rig's simulated stage controller on a real pseudo-terminal"
)]
struct Cli {
    #[command(flatten)]
    args: rig_sim::cli::SimArgs,
}

fn main() {
    let cli = Cli::parse();
    if let Err(e) = rig_sim::cli::run(cli.args) {
        eprintln!("rig-sim: {e}");
        std::process::exit(1);
    }
}
