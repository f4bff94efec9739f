//! The supervisor process (see `supermvo_pipeline::supervisor`).

use clap::Parser;
use std::path::PathBuf;
use supermvo_pipeline::common::{load_config, main_with};
use supermvo_pipeline::supervisor::{default_bin_dir, run, SupervisorOptions};

/// Runs the SuPerMVO pipeline as supervised processes over iceoryx2.
#[derive(Debug, Parser)]
#[command(version)]
struct Cli {
    /// Configuration file (see config/default.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Sequence directory (KITTI layout).
    #[arg(long)]
    seq: PathBuf,
    /// Output directory.
    #[arg(long, default_value = "out/daemon")]
    out: PathBuf,
    /// No live summary.
    #[arg(long, short)]
    quiet: bool,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    main_with("supervisor", || {
        let config = load_config(cli.config.as_deref())?;
        let m = run(&SupervisorOptions {
            config,
            seq: cli.seq.clone(),
            out: cli.out.clone(),
            bin_dir: default_bin_dir(),
            quiet: cli.quiet,
        })?;
        println!("{}", serde_json::to_string_pretty(&m)?);
        Ok(())
    })
}
