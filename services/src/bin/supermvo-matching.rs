//! The matching stage process (see `supermvo_services::matching`).

use clap::Parser;
use supermvo_services::common::{main_with, StageArgs};

/// SuPerMVO matching stage; started by the supervisor.
#[derive(Debug, Parser)]
#[command(version)]
struct Cli {
    #[command(flatten)]
    args: StageArgs,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    main_with("matching", || supermvo_services::matching::run(&cli.args))
}
