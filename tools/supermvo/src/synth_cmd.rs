//! `supermvo synth`: render a synthetic driving sequence in the KITTI layout.

use anyhow::{bail, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use supermvo_synth::preset::PRESETS;
use supermvo_synth::render::CameraModel;
use supermvo_synth::Sequence;

#[derive(Debug, Args)]
pub struct SynthArgs {
    /// World and drive: urban-loop (a block driven 1.15 times, for loop closure), highway
    /// (fast, little texture), dynamic (many moving cars and people), lighting (exposure
    /// changes).
    #[arg(long, value_parser = clap::builder::PossibleValuesParser::new(PRESETS))]
    preset: String,
    /// Root of the KITTI layout to write: DIR/sequences/PRESET/ and DIR/poses/PRESET.txt.
    #[arg(long)]
    out: PathBuf,
    /// Number of frames (10 Hz); the preset's default if not given.
    #[arg(long)]
    frames: Option<usize>,
    /// Seed of the world's layout, textures and sensor noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Image scale relative to KITTI's 1241x376 (intrinsics scale with it).
    #[arg(long, default_value_t = 1.0)]
    scale: f64,
    /// Rendering threads (default: every core).
    #[arg(long)]
    threads: Option<usize>,
    /// Render again even if an identical sequence is already there.
    #[arg(long)]
    force: bool,
    /// Render through a lens: radtan (radial-tangential, k1 -0.25 k2 0.06 p1 5e-4 p2 -3e-4),
    /// fisheye (equidistant, k1..k4 0.02 -0.01 0.005 -0.001) or fov (field of view, omega
    /// 0.9, TUM monoVO's model); the lens is written to
    /// camera.yaml beside calib.txt, which `supermvo run` then uses.
    #[arg(long, value_enum, default_value = "none")]
    distortion: LensArg,
    /// No progress bar (as in `run` and `eval`: -q drops what is not a result; what was
    /// written and errors still print).
    #[arg(long, short)]
    quiet: bool,
}

/// `--distortion`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LensArg {
    /// A pinhole camera.
    None,
    /// Radial-tangential.
    Radtan,
    /// Equidistant (fisheye).
    Fisheye,
    /// Field of view (TUM monoVO's model).
    Fov,
}

impl LensArg {
    fn distortion(self) -> supermvo_dataset::Distortion {
        match self {
            Self::None => supermvo_dataset::Distortion::None,
            Self::Radtan => supermvo_dataset::Distortion::RadTan([-0.25, 0.06, 5e-4, -3e-4, 0.0]),
            Self::Fisheye => {
                supermvo_dataset::Distortion::Equidistant([0.02, -0.01, 0.005, -0.001])
            }
            Self::Fov => supermvo_dataset::Distortion::Fov(0.9),
        }
    }
}

pub fn run(args: &SynthArgs) -> Result<()> {
    if !(args.scale > 0.05 && args.scale <= 4.0) {
        bail!("--scale must be in (0.05, 4], got {}", args.scale);
    }
    let k = CameraModel::kitti();
    let camera = CameraModel {
        width: (k.width as f64 * args.scale).round() as usize,
        height: (k.height as f64 * args.scale).round() as usize,
        fx: k.fx * args.scale,
        fy: k.fy * args.scale,
        cx: k.cx * args.scale,
        cy: k.cy * args.scale,
    };
    let seq = Sequence::new(&args.preset, args.seed, args.frames, camera)?
        .with_distortion(args.distortion.distortion());
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let bar = if args.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(seq.frames as u64)
    };
    bar.set_style(
        ProgressStyle::with_template(
            "render {prefix} [{bar:30}] {pos}/{len} frames {per_sec} eta {eta}",
        )
        .context("progress template")?
        .progress_chars("=> "),
    );
    bar.set_prefix(args.preset.clone());
    let started = std::time::Instant::now();
    let written = seq.write(&args.out, threads, args.force, &|done| {
        bar.set_position(done as u64)
    })?;
    bar.finish_and_clear();
    let secs = started.elapsed().as_secs_f64();
    if written.reused {
        outln!(
            "{}: {} frames already rendered with the same preset, seed and size; reused (--force renders again)",
            written.sequence_dir.display(),
            seq.frames
        );
    } else {
        outln!(
            "{}: {} frames {}x{} rendered in {:.1} s ({:.1} frames/s on {} threads), path {:.0} m",
            written.sequence_dir.display(),
            seq.frames,
            camera.width,
            camera.height,
            secs,
            seq.frames as f64 / secs,
            threads,
            seq.path_length()
        );
    }
    outln!("ground truth: {}", written.poses.display());
    Ok(())
}
