//! The backend stage process (see `supermvo_services::backend`).

use clap::Parser;
use supermvo_services::common::{main_with, StageArgs};

/// SuPerMVO backend stage; started by the supervisor.
#[derive(Debug, Parser)]
#[command(version)]
struct Cli {
    #[command(flatten)]
    args: StageArgs,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    main_with("backend", || supermvo_services::backend::run(&cli.args))
}
