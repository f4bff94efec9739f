//! The ingest stage process (see `supermvo_services::ingest`).

use clap::Parser;
use supermvo_services::common::{main_with, StageArgs};

/// SuPerMVO ingest stage; started by the supervisor.
#[derive(Debug, Parser)]
#[command(version)]
struct Cli {
    #[command(flatten)]
    args: StageArgs,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    main_with("ingest", || supermvo_services::ingest::run(&cli.args))
}
