//! `supermvo run`: monocular VO on a KITTI-layout sequence, as the multi-process daemon
//! (stages over iceoryx2, under the supervisor) or in one process. Both give the same
//! trajectory; the report, plots and evaluation are the same.

use crate::record_cmd::InprocessRecording;
use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use std::path::{Path, PathBuf};
use supermvo_config::{Config, IngestMode, NetworkPlacement};
use supermvo_dataset::{Camera, GrayImage, Sequence, Trajectory};
use supermvo_eval::{evaluate, EvalOptions};
use supermvo_geometry::AlignmentKind;
use supermvo_pipeline::backend::{read_records, write_trajectories};
use supermvo_pipeline::supervisor::{default_bin_dir, SupervisorOptions};
use supermvo_pipeline::{features, loop_closing, matching, tracking};
use supermvo_vo::loops::{LoopCloser, ReportedPose};
use supermvo_vo::pipeline::VoPipeline;
use supermvo_vo::stage::Timed;
use supermvo_vo::tracker::{FrameInput, Tracker, TrackingState};

/// A run stopped by SIGINT (Ctrl-C) or SIGTERM after writing what it had: the CLI exits
/// with 130, as shells report an interrupted program.
#[derive(Debug, thiserror::Error)]
#[error("interrupted after {done} of {frames} frames; what was estimated is in {out}")]
pub struct Interrupted {
    done: usize,
    frames: usize,
    out: String,
}

/// How the pipeline runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Mode {
    /// One process per stage over shared memory, supervised (the daemon).
    Multiprocess,
    /// Every stage in this process, one frame after the other.
    Inprocess,
}

/// Arguments of `supermvo run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Sequence: a KITTI (`.../sequences/NN`), EuRoC or TUM folder, a folder of images, or
    /// a video file (decoded by ffmpeg; docs/usage.md).
    seq_dir: PathBuf,
    /// Ground-truth poses (KITTI format) [default: ../../poses/NN.txt if present].
    #[arg(long)]
    gt: Option<PathBuf>,
    /// Output directory.
    #[arg(long, default_value = "out/run")]
    out: PathBuf,
    /// Multi-process daemon or a single process.
    #[arg(long, value_enum, default_value_t = Mode::Multiprocess)]
    mode: Mode,
    /// Configuration file (see config/default.toml); the options below override it.
    #[arg(long, conflicts_with = "profile")]
    config: Option<PathBuf>,
    /// A built-in configuration: `realtime` (10 Hz on two cores: the daemon in real time
    /// with a smaller front end; config/realtime.toml); the options below override it.
    #[arg(long, value_parser = clap::builder::PossibleValuesParser::new(Config::PROFILES.map(|(n, _)| n)))]
    profile: Option<String>,
    /// Front end: xfeat-lighterglue (learned, the default), aliked-lightglue (learned, more
    /// accurate, slower), orb (classical baseline) or superpoint-superglue (official weights
    /// exported locally) [pipeline.frontend].
    #[arg(long)]
    frontend: Option<String>,
    /// Where the networks run: cpu, or cuda (falls back to the CPU with a warning)
    /// [pipeline.device].
    #[arg(long, value_enum)]
    device: Option<crate::features_cmd::DeviceArg>,
    /// Keypoints per frame, 64-8192 [config: pipeline.top_k].
    #[arg(long, value_parser = crate::keypoint_count)]
    top_k: Option<usize>,
    /// Keypoints the matcher and loop closing are given, the strongest of each frame's
    /// top-k; 0: all [pipeline.matcher_top_k].
    #[arg(long, value_parser = crate::count_in::<0, 8192>)]
    matcher_top_k: Option<usize>,
    /// Keyframes in the local bundle-adjustment window, 0 disables it [pipeline.ba_window].
    #[arg(long, value_parser = crate::count_in::<0, 30>)]
    ba_window: Option<usize>,
    /// New keyframe below this fraction of the reference keyframe's tracked landmarks, 0
    /// off [pipeline.keyframe_ratio].
    #[arg(long, value_parser = crate::fraction)]
    keyframe_ratio: Option<f64>,
    /// Frames in a row tried against the kept map after tracking fails, before a new map is
    /// started; 0 starts one at once [pipeline.relocalisation_frames].
    #[arg(long, value_parser = crate::count_in::<0, 100>)]
    relocalisation_frames: Option<usize>,
    /// Camera file (ORB-SLAM3 / OpenCV YAML or EuRoC sensor.yaml) with intrinsics and lens
    /// distortion; needed for TUM and image folders without camera.yaml, and replaces
    /// KITTI's calib.txt and EuRoC's sensor.yaml [pipeline.camera].
    #[arg(long)]
    camera: Option<PathBuf>,
    /// Run the matcher only for keyframes and frames that projection does not track (faster;
    /// see docs/vo.md) [pipeline.match_every_frame = false].
    #[arg(long)]
    keyframe_matching: bool,
    /// Report the radial lens coefficient k1 that the local BAs ask for beyond the
    /// calibration (changes no pose) [pipeline.lens_check].
    #[arg(long)]
    lens_check: bool,
    /// Learn the radial lens coefficient k1 the calibration misses while driving (the
    /// default; in process and in the lossless daemon) [pipeline.lens_self_calibration].
    #[arg(long, overrides_with = "no_lens_self_calibration")]
    lens_self_calibration: bool,
    /// See through the calibration only: learn no lens while driving
    /// [pipeline.lens_self_calibration = false].
    #[arg(long)]
    no_lens_self_calibration: bool,
    /// Seed of the tracker's RANSAC sampling; 0 gives the reported runs [pipeline.seed].
    #[arg(long)]
    seed: Option<u64>,
    /// Process at most this many frames [pipeline.max_frames].
    #[arg(long)]
    max_frames: Option<usize>,
    /// Replay at the dataset's frame rate, dropping (and reporting) what the pipeline cannot
    /// take, instead of lossless back-pressure [pipeline.mode = "realtime"].
    #[arg(long)]
    realtime: bool,
    /// Feature-extraction worker processes [pipeline.features_workers].
    #[arg(long, value_parser = crate::count_in::<1, 8>)]
    workers: Option<usize>,
    /// Pipeline name of the daemon [pipeline.name].
    #[arg(long)]
    name: Option<String>,
    /// Replay the sequence this many times [pipeline.loops].
    #[arg(long, value_parser = crate::count_in::<1, 100000>)]
    loops: Option<usize>,
    /// Odometry only: no loop closure [pipeline.loop_closure = false].
    #[arg(long)]
    no_loop_closure: bool,
    /// No progress display (as in `eval` and `synth`: -q drops what is not a result; the
    /// summary, the evaluation and errors still print).
    #[arg(long, short)]
    quiet: bool,
    #[command(flatten)]
    recording: crate::record_cmd::RunRecordArgs,
}

impl RunArgs {
    /// The effective configuration: file (or defaults), then command-line overrides.
    fn config(&self) -> Result<Config> {
        let mut cfg = match (&self.config, &self.profile) {
            (Some(p), _) => Config::load(p)?,
            (None, Some(name)) => Config::profile(name)?,
            (None, None) => Config::default(),
        };
        let p = &mut cfg.pipeline;
        if let Some(v) = self.top_k {
            p.top_k = v;
        }
        if let Some(v) = self.matcher_top_k {
            p.matcher_top_k = v;
        }
        if let Some(v) = self.ba_window {
            p.ba_window = v;
        }
        if let Some(v) = self.keyframe_ratio {
            p.keyframe_ratio = v;
        }
        if let Some(v) = self.relocalisation_frames {
            p.relocalisation_frames = v;
        }
        if self.keyframe_matching {
            p.match_every_frame = false;
        }
        if self.lens_check {
            p.lens_check = true;
        }
        if self.lens_self_calibration {
            p.lens_self_calibration = true;
        }
        if self.no_lens_self_calibration {
            p.lens_self_calibration = false;
        }
        if let Some(c) = &self.camera {
            // absolute, so the daemon's stages find it whatever their directory
            p.camera = Some(
                std::fs::canonicalize(c)
                    .with_context(|| format!("--camera {}: not found", c.display()))?,
            );
        }
        if let Some(v) = self.max_frames {
            p.max_frames = v;
        }
        if let Some(v) = self.seed {
            p.seed = v;
        }
        if let Some(v) = self.workers {
            p.features_workers = v;
        }
        if let Some(v) = &self.name {
            p.name = v.clone();
        }
        if let Some(v) = self.loops {
            p.loops = v;
        }
        if self.no_loop_closure {
            p.loop_closure = false;
        }
        if let Some(d) = self.device {
            p.device = d.into();
        }
        if let Some(f) = &self.frontend {
            p.frontend = f.parse().map_err(anyhow::Error::msg)?;
        }
        if self.realtime {
            p.mode = IngestMode::Realtime;
        }
        cfg.validate()?;
        Ok(cfg)
    }
}

/// Checks that the calibration belongs to the images (principal point inside them).
fn check_calibration(seq: &Sequence) -> Result<GrayImage> {
    let first = seq.load_frame(0)?;
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
    Ok(first)
}

/// Runs `supermvo run`.
pub fn run(args: &RunArgs) -> Result<()> {
    let cfg = args.config()?;
    if args.mode == Mode::Inprocess && cfg.pipeline.loops > 1 {
        bail!(
            "--loops {} (pipeline.loops) replays the sequence through the daemon only; drop --mode inprocess, or use --loops 1",
            cfg.pipeline.loops
        );
    }
    let mut seq = Sequence::open_with_camera(&args.seq_dir, cfg.pipeline.camera.as_deref())?;
    let lens = features::keypoint_lens(&cfg.pipeline, &mut seq);
    check_calibration(&seq)?;
    let n = match cfg.pipeline.max_frames {
        0 => seq.len(),
        m => m.min(seq.len()),
    };
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    clear_previous_run(&args.out)?;
    let (traj, mut report, interrupted) = match args.mode {
        Mode::Inprocess => run_inprocess(args, &cfg, (&seq, lens), n)?,
        Mode::Multiprocess => run_multiprocess(args, &cfg, &seq)?,
    };
    let est = traj.poses.len();
    let lost = report["lost"].as_u64().unwrap_or(0);
    let frames = report["frames"].as_u64().map_or(n, |f| f as usize);
    let unposed = report["unposed_frames"].as_array().map_or(0, |u| u.len());
    outln!(
        "{}: {est} of {frames} frames posed, {lost} lost{}",
        seq.name(),
        if unposed > 0 && est > 0 {
            format!(
                "; trajectory.kitti.txt repeats the last pose for the {unposed} unposed (listed in report.json)"
            )
        } else {
            String::new()
        }
    );
    let gt_path = args.gt.clone().or_else(|| seq.default_ground_truth());
    match (gt_path, cfg.pipeline.loops) {
        (Some(gt_path), 1) if est > 0 => {
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
                        "{}: APE RMSE after Sim(3) {:.3} m over {:.1} m of path (ground truth {})",
                        seq.name(),
                        ev.report.ape.trans.rmse,
                        ev.report.reference_length_m,
                        gt_path.display()
                    );
                    report["eval"] = serde_json::to_value(&ev.report)?;
                    supermvo_plot::write_all(&args.out, &[("supermvo".to_string(), ev)])?;
                }
                Err(e) => outln!("{}: evaluation not possible: {e}", seq.name()),
            }
        }
        (Some(_), 1) => {}
        (Some(_), _) => outln!("{}: not evaluated (the sequence was replayed)", seq.name()),
        (None, _) => outln!(
            "{}: not evaluated: no ground truth at {} (give --gt POSES.txt)",
            seq.name(),
            seq.ground_truth_candidate()
                .map_or_else(|| "../../poses".into(), |p| p.display().to_string())
        ),
    }
    std::fs::write(
        args.out.join("report.json"),
        serde_json::to_string_pretty(&report)?,
    )?;
    outln!("results in {}", args.out.display());
    if interrupted {
        return Err(Interrupted {
            done: frames,
            frames: n,
            out: args.out.display().to_string(),
        }
        .into());
    }
    if est == 0 || est * 10 < frames {
        bail!(
            "only {est} of {frames} frames were posed: check that calib.txt belongs to these images, that consecutive images overlap, and that they are not blank; what was estimated is in {}",
            args.out.display()
        );
    }
    Ok(())
}

/// Removes what an earlier run wrote into `out` (its trajectories, report, records, figures
/// and logs), so that a reused output folder (the default `out/run` is shared by every run)
/// holds only this run's results; other files stay.
fn clear_previous_run(out: &Path) -> Result<()> {
    const WRITTEN: [&str; 11] = [
        "trajectory.tum.txt",
        "trajectory.kitti.txt",
        "report.json",
        "frames.csv",
        "metrics.json",
        "processes.json",
        "config.toml",
        "loops.json",
        "keyframes.bin",
        "trajectory_xz.png",
        "xyz.png",
    ];
    let mut cleared = 0;
    for entry in std::fs::read_dir(out).with_context(|| format!("reading {}", out.display()))? {
        let path = entry?.path();
        let name = path
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or_default();
        let ours = WRITTEN.contains(&name)
            || name == "rpy.png"
            || (name.starts_with("ape_") && name.ends_with(".png"));
        if ours {
            std::fs::remove_file(&path)
                .with_context(|| format!("removing the earlier run's {}", path.display()))?;
            cleared += 1;
        } else if name == "logs" && path.is_dir() {
            std::fs::remove_dir_all(&path)
                .with_context(|| format!("removing the earlier run's {}", path.display()))?;
            cleared += 1;
        }
    }
    if cleared > 0 {
        tracing::info!("{}: replaced an earlier run's results", out.display());
    }
    Ok(())
}

fn progress_bar(quiet: bool, n: usize) -> indicatif::ProgressBar {
    let bar = if quiet {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(n as u64)
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} frames  {per_sec}  {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar
}

type Networks = (
    Box<dyn supermvo_inference::Extractor + Send>,
    Box<dyn supermvo_inference::Matcher + Send>,
);

/// The networks behind the disk cache named by `SUPERMVO_NETWORK_CACHE`, when it is set (for
/// tracker studies that re-run the same clips; `supermvo_inference::cache`), else as given.
fn network_cache((extractor, matcher): Networks, p: &supermvo_config::PipelineConfig) -> Networks {
    // set but empty counts as unset (not as the current directory)
    let Some(dir) = std::env::var_os("SUPERMVO_NETWORK_CACHE").filter(|d| !d.is_empty()) else {
        return (extractor, matcher);
    };
    use supermvo_inference::cache::Cached;
    let mut tag = format!(
        "{:?} top_k={} subpixel={} width={} depth={}",
        p.frontend, p.top_k, p.subpixel_keypoints, p.width_confidence, p.depth_confidence
    );
    if let Some(k) = p.matcher_keypoints() {
        tag += &format!(" matcher_top_k={k}");
    }
    if p.image_scale != 1.0 {
        tag += &format!(" scale={}", p.image_scale);
    }
    let dir = PathBuf::from(dir);
    (
        Box::new(Cached::new(extractor, &dir, &tag)),
        Box::new(Cached::new(matcher, &dir, &tag)),
    )
}

fn run_inprocess(
    args: &RunArgs,
    cfg: &Config,
    (seq, lens): (&Sequence, Option<Camera>),
    n: usize,
) -> Result<(Trajectory, serde_json::Value, bool)> {
    let p = &cfg.pipeline;
    let tracker = Tracker::new(seq.calib, tracking::tracker_config(p));
    let loops = p
        .loop_closure
        .then(|| LoopCloser::new(seq.calib, loop_closing::loop_config(p)));
    let mut recording = match &args.recording.record {
        Some(path) => Some(InprocessRecording::create(path, args.recording.options())?),
        None => None,
    };
    let networks = (
        features::extractor(p, NetworkPlacement::Alternating)?,
        matching::matcher(p, NetworkPlacement::Alternating)?,
    );
    let (extractor, matcher) = network_cache(networks, p);
    let extractor = features::with_lens(extractor, lens);
    let mut pipeline = VoPipeline::new(extractor, matcher, tracker, loops);
    if recording.is_some() {
        pipeline = pipeline.keep_views();
    }
    let mut vo = Timed::new(pipeline);
    let first = seq.load_frame(0)?;
    let bar = progress_bar(args.quiet, n);
    let mut outputs = Vec::with_capacity(n);
    // every pose as reported, with the loop corrections applied when it was
    let mut reported = Vec::with_capacity(n);
    // Ctrl-C (or SIGTERM) ends the loop after the frame in hand; what was estimated is
    // written as after a complete run
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, std::sync::atomic::Ordering::SeqCst))
        .context("installing the Ctrl-C handler")?;
    let mut interrupted_at = None;
    for i in 0..n {
        if stop.load(std::sync::atomic::Ordering::SeqCst) {
            interrupted_at = Some(i);
            break;
        }
        let image = match seq.load_frame(i) {
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
        // the recording draws the undistorted keypoints: on the pinhole image
        let recorded_image = recording
            .as_ref()
            .map(|_| seq.pinhole_view(&image).unwrap_or_else(|| image.clone()));
        let applied = vo.inner().loop_closer().map_or(0, |c| c.corrections());
        let out = vo.call(FrameInput {
            index: i,
            stamp: seq.times[i],
            image,
        })?;
        reported.extend(out.poses().map(|(frame, t_world_cam)| ReportedPose {
            frame,
            t_world_cam,
            corrections: applied,
        }));
        if let Some(r) = recording.as_mut() {
            let view = vo.inner_mut().take_view();
            let ms = vo.durations_ms().last().copied().unwrap_or(f64::NAN);
            let loops = vo.inner().loop_closer().map_or(&[][..], |c| c.loops());
            r.frame(&out, recorded_image.as_ref(), view.as_ref(), ms, loops);
        }
        bar.set_message(format!("{:?}, {} landmarks", out.state, out.landmarks));
        bar.inc(1);
        outputs.push(out);
    }
    bar.finish_and_clear();
    if let Some(r) = recording {
        r.finish()?;
    }
    let closer = vo.inner().loop_closer();
    // every frame's pose (moved by the loop corrections when loops are closed), by index
    let posed: std::collections::BTreeMap<usize, supermvo_geometry::Pose> = match closer {
        Some(c) => c.trajectory(reported).into_iter().collect(),
        None => outputs.iter().flat_map(|o| o.poses()).collect(),
    };
    let loops = closer.map_or(&[][..], |c| c.loops());
    if let Some(reason) = closer.and_then(|c| c.disabled_reason()) {
        outln!("loop closure off: {reason}");
    } else if closer.is_some() {
        outln!("loops closed: {}", loops.len());
    }
    let n = interrupted_at.unwrap_or(n);
    let frames: Vec<(f64, Option<supermvo_geometry::Pose>)> = (0..n)
        .map(|i| (seq.times[i], posed.get(&i).copied()))
        .collect();
    let unposed = write_trajectories(&args.out, &frames)?;
    let traj = Trajectory {
        stamps: Some(posed.keys().map(|&i| seq.times[i]).collect()),
        poses: posed.values().copied().collect(),
        quaternions: None,
    };
    let lost = outputs
        .iter()
        .filter(|o| o.state == TrackingState::Lost)
        .count();
    outln!(
        "median time per frame {:.1} ms (extraction, matching and tracking in one process)",
        vo.median_ms()
    );
    let lens = vo.inner().tracker().lens_residual();
    if let Some(l) = &lens {
        outln!("{}", lens_summary(l, &cfg.pipeline));
    }
    let report = serde_json::json!({
        "mode": "inprocess",
        "interrupted_at_frame": interrupted_at,
        "sequence": seq.dir, "frames": n, "estimated": traj.poses.len(), "lost": lost,
        "unposed_frames": unposed,
        "timing_ms": {"frame_median": vo.median_ms(), "per_frame": vo.durations_ms()},
        "peak_rss_kb": supermvo_pipeline::common::peak_rss_kb(),
        "loops": loops,
        "lens_residual": lens,
        "frames_detail": outputs,
    });
    Ok((traj, report, interrupted_at.is_some()))
}

fn run_multiprocess(
    args: &RunArgs,
    cfg: &Config,
    seq: &Sequence,
) -> Result<(Trajectory, serde_json::Value, bool)> {
    // ONNX Runtime and the models, checked here before any stage starts: a missing one is
    // one clear error (as in process) instead of stages failing and being restarted
    drop(
        features::extractor(&cfg.pipeline, NetworkPlacement::SideBySide)
            .context("checking the front end before starting the daemon")?,
    );
    drop(
        matching::matcher(&cfg.pipeline, NetworkPlacement::SideBySide)
            .context("checking the front end before starting the daemon")?,
    );
    let recording = match &args.recording.record {
        Some(path) => Some(crate::record_cmd::DaemonRecording::start(
            &cfg.pipeline.name,
            path,
            args.recording.options(),
        )?),
        None => None,
    };
    let metrics = supermvo_pipeline::supervisor::run(&SupervisorOptions {
        config: cfg.clone(),
        seq: seq.dir.clone(),
        out: args.out.clone(),
        bin_dir: default_bin_dir(),
        quiet: args.quiet,
    })?;
    if let Some(r) = recording {
        r.finish()?;
    }
    let records = read_records(&args.out.join("frames.csv"))?;
    let est: Vec<_> = records
        .iter()
        .filter_map(|r| r.t_world_cam.map(|p| (r.stamp, p)))
        .collect();
    let traj = Trajectory {
        stamps: Some(est.iter().map(|e| e.0).collect()),
        poses: est.iter().map(|e| e.1).collect(),
        quaternions: None,
    };
    let lost = records
        .iter()
        .filter(|r| r.state == supermvo_messages::PoseMsg::LOST)
        .count();
    let unposed: Vec<usize> = records
        .iter()
        .filter(|r| r.status != "end")
        .enumerate()
        .filter(|(_, r)| r.t_world_cam.is_none())
        .map(|(i, _)| i)
        .collect();
    let e2e = &metrics.end_to_end_ms;
    outln!(
        "{} frames in {:.1} s ({:.1} fps); capture to pose p50 {:.0} ms, p99 {:.0} ms; {} restarts",
        metrics.frames.values().sum::<usize>(),
        metrics.duration_s,
        metrics.fps,
        e2e.p50,
        e2e.p99,
        metrics.restarts.len()
    );
    if !metrics.stage_cpu_ms.is_empty() {
        let per_stage: Vec<String> = metrics
            .stage_cpu_ms
            .iter()
            .map(|(k, v)| format!("{k} {:.1}", v.mean))
            .collect();
        let sum: f64 = metrics.stage_cpu_ms.values().map(|v| v.mean).sum();
        outln!(
            "CPU per frame (core-ms, mean): {}; sum {sum:.1} (two cores give a frame 200 at 10 Hz)",
            per_stage.join(", ")
        );
    }
    let loops: serde_json::Value = std::fs::read_to_string(args.out.join("loops.json"))
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or_else(|| serde_json::json!([]));
    if cfg.pipeline.loop_closure {
        outln!("loops closed: {}", loops.as_array().map_or(0, |l| l.len()));
    }
    let lens: Option<supermvo_vo::tracker::LensResidual> =
        std::fs::read_to_string(args.out.join(supermvo_pipeline::tracking::LENS_FILE))
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok());
    if let Some(l) = &lens {
        outln!("{}", lens_summary(l, &cfg.pipeline));
    }
    let report = serde_json::json!({
        "mode": "multiprocess",
        "interrupted": metrics.interrupted,
        "loops": loops,
        "lens_residual": lens,
        "sequence": seq.dir, "frames": records.iter().filter(|r| r.status != "end").count(),
        "estimated": est.len(), "lost": lost,
        "unposed_frames": unposed,
        "metrics": metrics,
        "frames_detail": records,
    });
    Ok((traj, report, metrics.interrupted))
}

/// The run's summary line about the lens (`--lens-check`, `--lens-self-calibration`).
fn lens_summary(
    l: &supermvo_vo::tracker::LensResidual,
    p: &supermvo_config::PipelineConfig,
) -> String {
    let turning = match l.turning_k1 {
        Some(k1) => format!(
            "the turning windows read a radial k1 of {k1:+.4} beyond the calibration ({} windows)",
            l.turning_windows
        ),
        None => "no window turned enough to read the lens".to_string(),
    };
    if !p.lens_self_calibration {
        return format!("lens check: {turning}");
    }
    if l.learnt_k1 != 0.0 {
        return format!(
            "lens self-calibration: learnt a radial k1 of {:+.4} beyond the calibration from {} turning windows",
            l.learnt_k1, l.turning_windows
        );
    }
    format!(
        "lens self-calibration: nothing learnt, {turning}; it corrects {} or more",
        p.lens_min_k1
    )
}
