//! `supermvo run`: monocular VO on a KITTI-layout sequence, in process.

use anyhow::{bail, Context, Result};
use clap::Args;
use std::path::PathBuf;
use supermvo_dataset::{write_trajectory, GrayImage, KittiSequence, Trajectory, TrajectoryFormat};
use supermvo_eval::{evaluate, EvalOptions};
use supermvo_geometry::AlignmentKind;
use supermvo_inference::lighterglue::{LightGlue, LightGlueConfig};
use supermvo_inference::models;
use supermvo_inference::xfeat::{XFeat, XFeatConfig};
use supermvo_vo::stage::Timed;
use supermvo_vo::tracker::{
    output_pose, FrameInput, Tracker, TrackerConfig, TrackingState, VoPipeline,
};

/// Arguments of `supermvo run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Sequence directory (`.../sequences/NN` with calib.txt, times.txt, image_0/).
    seq_dir: PathBuf,
    /// Ground-truth poses (KITTI format) [default: ../../poses/NN.txt if present].
    #[arg(long)]
    gt: Option<PathBuf>,
    /// Output directory.
    #[arg(long, default_value = "out/run")]
    out: PathBuf,
    /// Front end (only xfeat-lighterglue is built so far).
    #[arg(long, default_value = "xfeat-lighterglue")]
    frontend: String,
    /// Keypoints per frame.
    #[arg(long, default_value_t = 1024)]
    top_k: usize,
    /// Keyframes in the local bundle-adjustment window (0 disables it).
    #[arg(long, default_value_t = 6)]
    ba_window: usize,
    /// Process at most this many frames.
    #[arg(long)]
    max_frames: Option<usize>,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
}

/// Runs `supermvo run`.
pub fn run(args: &RunArgs) -> Result<()> {
    if args.frontend != "xfeat-lighterglue" {
        bail!(
            "front end '{}' is not available yet; use xfeat-lighterglue",
            args.frontend
        );
    }
    let seq = KittiSequence::open(&args.seq_dir)?;
    let n = args
        .max_frames
        .unwrap_or(seq.images.len())
        .min(seq.images.len());
    let first = GrayImage::load(&seq.images[0])?;
    // the principal point must lie inside the image: catches calibration/image mismatches
    if seq.calib.cx <= 0.0
        || seq.calib.cx >= first.width as f64
        || seq.calib.cy <= 0.0
        || seq.calib.cy >= first.height as f64
    {
        bail!(
            "{}: principal point ({}, {}) lies outside the {}x{} images; calib.txt does not belong to these images",
            seq.dir.join("calib.txt").display(), seq.calib.cx, seq.calib.cy, first.width, first.height
        );
    }
    let xfeat = XFeat::new(
        &models::model_path("xfeat"),
        XFeatConfig {
            top_k: args.top_k,
            ..Default::default()
        },
    )?;
    let lg = LightGlue::new(
        &models::model_path("lighterglue"),
        "lighterglue",
        LightGlueConfig::default(),
    )?;
    let tracker = Tracker::new(
        seq.calib,
        TrackerConfig {
            local_ba_window: args.ba_window,
            ..TrackerConfig::default()
        },
    );
    let mut tracker = Timed::new(VoPipeline::new(Box::new(xfeat), Box::new(lg), tracker));
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let bar = if args.quiet {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(n as u64)
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} frames  {per_sec}  {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let mut outputs = Vec::with_capacity(n);
    for i in 0..n {
        let image = match GrayImage::load(&seq.images[i]) {
            Ok(img) if img.width == first.width && img.height == first.height => img,
            Ok(img) => {
                tracing::warn!(
                    "frame {i}: {}x{} differs from {}x{}; skipped",
                    img.width,
                    img.height,
                    first.width,
                    first.height
                );
                continue;
            }
            Err(e) => {
                tracing::warn!("frame {i}: {e}; skipped");
                continue;
            }
        };
        let out = tracker.call(FrameInput {
            index: i,
            stamp: seq.times[i],
            image,
        })?;
        bar.set_message(format!("{:?}, {} landmarks", out.state, out.landmarks));
        bar.inc(1);
        outputs.push(out);
    }
    bar.finish_and_clear();
    // trajectory of the frames with a pose
    let est: Vec<_> = outputs
        .iter()
        .filter_map(|o| output_pose(o).map(|p| (o.stamp, p)))
        .collect();
    let traj = Trajectory {
        stamps: Some(est.iter().map(|e| e.0).collect()),
        poses: est.iter().map(|e| e.1).collect(),
        quaternions: None,
    };
    write_trajectory(
        &args.out.join("trajectory.tum.txt"),
        TrajectoryFormat::Tum,
        &traj,
    )?;
    if est.len() == n {
        write_trajectory(
            &args.out.join("trajectory.kitti.txt"),
            TrajectoryFormat::Kitti,
            &traj,
        )?;
    }
    let lost = outputs
        .iter()
        .filter(|o| o.state == TrackingState::Lost)
        .count();
    let mut report = serde_json::json!({
        "sequence": seq.dir, "frames": n, "estimated": est.len(), "lost": lost,
        "timing_ms": {"tracking_median": tracker.median_ms(), "per_frame": tracker.durations_ms()},
        "frames_detail": outputs,
    });
    let gt_path = args.gt.clone().or_else(|| seq.default_ground_truth());
    if let Some(gt_path) = gt_path {
        let mut gt = seq.read_ground_truth(&gt_path)?;
        gt.poses.truncate(n);
        if let Some(s) = gt.stamps.as_mut() {
            s.truncate(n);
        }
        let opts = EvalOptions {
            align: AlignmentKind::Sim3,
            t_max_diff: 0.001,
            ..Default::default()
        };
        match evaluate(&gt, &traj, &opts) {
            Ok(ev) => {
                outln!(
                    "{}: {} of {n} frames estimated, {lost} lost; APE RMSE after Sim(3) {:.3} m over {:.1} m of path",
                    seq.name(), est.len(), ev.report.ape.trans.rmse, ev.report.reference_length_m
                );
                report["eval"] = serde_json::to_value(&ev.report)?;
                supermvo_eval::plot::write_all(&args.out, &[("supermvo".to_string(), ev)])?;
            }
            Err(e) => outln!("{}: evaluation not possible: {e}", seq.name()),
        }
    }
    std::fs::write(
        args.out.join("report.json"),
        serde_json::to_string_pretty(&report)?,
    )?;
    outln!(
        "median tracking time {:.1} ms per frame; results in {}",
        tracker.median_ms(),
        args.out.display()
    );
    Ok(())
}
