//! `supermvo traj`: inspect and convert trajectory files, as `evo_traj` does.

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use std::path::PathBuf;
use supermvo_dataset::{read_times, read_trajectory, write_trajectory, TrajectoryFormat};

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum FormatArg {
    Kitti,
    Tum,
    Euroc,
}

impl FormatArg {
    fn format(self) -> TrajectoryFormat {
        match self {
            Self::Kitti => TrajectoryFormat::Kitti,
            Self::Tum => TrajectoryFormat::Tum,
            Self::Euroc => TrajectoryFormat::Euroc,
        }
    }
}

/// Arguments of `supermvo traj`.
#[derive(Debug, Args)]
pub struct TrajArgs {
    /// Trajectory file.
    input: PathBuf,
    /// Its format.
    #[arg(long, value_enum, default_value = "kitti")]
    format: FormatArg,
    /// Timestamps of a KITTI file, one a line (a KITTI `times.txt`), needed to write it as TUM.
    #[arg(long)]
    times: Option<PathBuf>,
    /// Write the trajectory in this format (`kitti` or `tum`) to `--out`.
    #[arg(long, value_enum, requires = "out")]
    to: Option<FormatArg>,
    /// Output file of the conversion.
    #[arg(long, requires = "to")]
    out: Option<PathBuf>,
}

pub fn run(args: &TrajArgs) -> Result<()> {
    let mut traj = read_trajectory(&args.input, args.format.format())
        .with_context(|| format!("reading {}", args.input.display()))?;
    if let Some(times) = &args.times {
        let t = read_times(times)?;
        if t.len() != traj.len() {
            bail!(
                "{}: {} timestamps for the {} poses of {}",
                times.display(),
                t.len(),
                traj.len(),
                args.input.display()
            );
        }
        traj.stamps = Some(t);
    }
    print_info(&args.input, &traj);
    let (Some(to), Some(out)) = (args.to, &args.out) else {
        return Ok(());
    };
    if to == FormatArg::Euroc {
        bail!("--to euroc is not written (EuRoC CSV is a ground-truth format); use kitti or tum");
    }
    if to == FormatArg::Tum && traj.stamps.is_none() {
        bail!(
            "{} has no timestamps: give --times TIMES.txt to write it as TUM",
            args.input.display()
        );
    }
    write_trajectory(out, to.format(), &traj)
        .with_context(|| format!("writing {}", out.display()))?;
    outln!("wrote {} ({:?}, {} poses)", out.display(), to, traj.len());
    Ok(())
}

fn print_info(path: &std::path::Path, traj: &supermvo_dataset::Trajectory) {
    outln!(
        "{}: {} poses, path length {:.3} m",
        path.display(),
        traj.len(),
        traj.path_length()
    );
    if let Some(s) = traj.stamps.as_ref().filter(|s| !s.is_empty()) {
        let (first, last) = (s[0], s[s.len() - 1]);
        let rate = if last > first {
            (s.len() - 1) as f64 / (last - first)
        } else {
            0.0
        };
        outln!(
            "  time {first:.6} to {last:.6} s ({:.3} s, {rate:.2} Hz)",
            last - first
        );
    }
    if let (Some(a), Some(b)) = (traj.poses.first(), traj.poses.last()) {
        outln!(
            "  first position {:.3} {:.3} {:.3}, last {:.3} {:.3} {:.3}",
            a.t.x,
            a.t.y,
            a.t.z,
            b.t.x,
            b.t.y,
            b.t.z
        );
    }
}
