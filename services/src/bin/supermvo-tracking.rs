//! The tracking stage process (see `supermvo_services::tracking`).

use clap::Parser;
use supermvo_services::common::{main_with, StageArgs};

/// SuPerMVO tracking stage; started by the supervisor.
#[derive(Debug, Parser)]
#[command(version)]
struct Cli {
    #[command(flatten)]
    args: StageArgs,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    main_with("tracking", || supermvo_services::tracking::run(&cli.args))
}
