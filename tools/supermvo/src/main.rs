//! `supermvo`: the SuPerMVO command-line tool.

/// `println!` for the CLI: a closed stdout (`supermvo ... | head`) ends the program quietly,
/// as Unix tools do, instead of panicking.
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        if let Err(e) = writeln!(std::io::stdout().lock(), $($arg)*) {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                std::process::exit(0);
            }
        }
    }};
}

mod bench_cmd;
mod daemon_cmd;
mod eval_cmd;
mod features_cmd;
mod graph_cmd;
mod models_cmd;
mod record_cmd;
mod run_cmd;
mod synth_cmd;
mod traj_cmd;

use clap::{Parser, Subcommand};

/// `--top-k` of every command: the range the configuration allows (`pipeline.top_k`), so a
/// value is refused the same way wherever it is typed, naming the flag.
fn keypoint_count(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if (64..=8192).contains(&n) => Ok(n),
        _ => Err(format!("'{s}' is not a keypoint count from 64 to 8192")),
    }
}

/// A whole-number flag within the range the configuration allows for its key, refused at
/// the flag (clap names it) rather than later under the configuration key.
fn count_in<const LO: usize, const HI: usize>(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if (LO..=HI).contains(&n) => Ok(n),
        _ => Err(format!("'{s}' is not a whole number from {LO} to {HI}")),
    }
}

/// A fraction flag in [0, 1].
fn fraction(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if (0.0..=1.0).contains(&x) => Ok(x),
        _ => Err(format!("'{s}' is not a number from 0 to 1")),
    }
}
/// `--image-scale`: the range of `pipeline.image_scale`, refused at the flag.
fn image_scale(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if supermvo_config::IMAGE_SCALE_RANGE.contains(&x) => Ok(x),
        _ => Err(format!("'{s}' is not a scale from 0.25 to 1")),
    }
}
use std::process::ExitCode;

#[derive(Debug, Parser)]
#[command(name = "supermvo", version, about = "Monocular visual odometry with learned features", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run monocular VO on a KITTI-layout sequence: as supervised processes over shared
    /// memory (default) or in one process.
    Run(run_cmd::RunArgs),
    /// Evaluate estimated trajectories against ground truth (APE, RPE, KITTI metric, plots).
    Eval(eval_cmd::EvalArgs),
    /// Obtain and list ONNX Runtime and the learned models.
    Models(models_cmd::ModelsArgs),
    /// Detect keypoints in an image with a learned extractor and print or save them.
    Features(features_cmd::FeaturesArgs),
    /// Pose-graph optimisation of g2o files.
    Graph(graph_cmd::GraphArgs),
    /// Benchmarks (medians of repeated calls), e.g. of the learned front end.
    Bench(bench_cmd::BenchArgs),
    /// Attach to a running pipeline read-only: rates, latencies, tracking state, pose.
    Monitor(daemon_cmd::MonitorArgs),
    /// List the nodes and services of running pipelines.
    Inspect(daemon_cmd::InspectArgs),
    /// Record a running pipeline as MCAP (Foxglove schemas), read only, until its end.
    Record(record_cmd::RecordArgs),
    /// Serve a running pipeline live to Foxglove over its WebSocket protocol.
    View(record_cmd::ViewArgs),
    /// Render a synthetic driving sequence with exact ground truth (KITTI layout).
    Synth(synth_cmd::SynthArgs),
    /// Inspect a trajectory file and convert it between KITTI and TUM (as evo_traj does).
    Traj(traj_cmd::TrajArgs),
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("SUPERMVO_LOG")
                .unwrap_or_else(|_| "warn".into()),
        )
        .with_ansi(supermvo_pipeline::common::colour_on_stderr())
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Eval(args) => eval_cmd::run(&args),
        Command::Run(args) => run_cmd::run(&args),
        Command::Models(args) => models_cmd::run(&args),
        Command::Features(args) => features_cmd::run(&args),
        Command::Bench(args) => bench_cmd::run(&args),
        Command::Graph(args) => graph_cmd::run(&args),
        Command::Monitor(args) => daemon_cmd::monitor(&args),
        Command::Inspect(args) => daemon_cmd::inspect_cmd(&args),
        Command::Record(args) => record_cmd::record(&args),
        Command::View(args) => record_cmd::view(&args),
        Command::Synth(args) => synth_cmd::run(&args),
        Command::Traj(args) => traj_cmd::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.is::<run_cmd::Interrupted>() => {
            eprintln!("{e}");
            ExitCode::from(130)
        }
        Err(e) => {
            eprintln!("error: {}", supermvo_pipeline::common::error_line(&e));
            ExitCode::from(2)
        }
    }
}
