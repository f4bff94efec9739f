//! The features stage process (see `supermvo_services::features`).

use clap::Parser;
use supermvo_services::common::{main_with, StageArgs};

/// SuPerMVO features stage; started by the supervisor.
#[derive(Debug, Parser)]
#[command(version)]
struct Cli {
    #[command(flatten)]
    args: StageArgs,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    main_with("features", || supermvo_services::features::run(&cli.args))
}
