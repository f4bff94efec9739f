//! `supermvo bench frontend`: per-call timings of the learned front end (medians).

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;
use std::time::Instant;
use supermvo_inference::lighterglue::{normalize_keypoints, LightGlue, LightGlueConfig};
use supermvo_inference::xfeat::{resize_bilinear, XFeat, XFeatConfig};
use supermvo_inference::{models, Extractor, GrayImage, Matcher};

/// Arguments of `supermvo bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    command: BenchCommand,
}

#[derive(Debug, Subcommand)]
enum BenchCommand {
    /// One hop of an image and of keypoints: iceoryx2 between processes vs a crossbeam
    /// channel between threads (p50, p99).
    Ipc {
        /// Hops per payload and transport (after 20 warm-up hops).
        #[arg(long, default_value_t = 1000)]
        samples: usize,
    },
    /// The receiving process of `bench ipc` (started by it).
    #[command(hide = true)]
    IpcEcho {
        /// Benchmark name.
        #[arg(long)]
        name: String,
    },
    /// Matches and 5-point RANSAC inliers on every consecutive pair of KITTI sequences.
    Matching {
        /// Sequence directories (`.../sequences/NN`).
        #[arg(required = true)]
        sequences: Vec<PathBuf>,
        /// Keypoints per frame, 64-8192.
        #[arg(long, default_value_t = 2048, value_parser = crate::keypoint_count)]
        top_k: usize,
        /// RANSAC threshold, pixels.
        #[arg(long, default_value_t = 1.0)]
        threshold_px: f64,
        /// RANSAC confidence.
        #[arg(long, default_value_t = 0.999)]
        confidence: f64,
        /// Write per-pair rows (seq, frame, matches, inliers) as CSV here.
        #[arg(long)]
        csv: Option<PathBuf>,
        /// Front end: xfeat-lighterglue, aliked-lightglue, orb or superpoint-superglue.
        #[arg(long, default_value = "xfeat-lighterglue")]
        frontend: String,
        /// XFeat keypoints at sub-pixel precision (`pipeline.subpixel_keypoints`).
        #[arg(long)]
        subpixel_keypoints: bool,
        /// XFeat on the frame resized by this factor, 0.25-1 (`pipeline.image_scale`).
        #[arg(long, default_value_t = 1.0, value_parser = crate::image_scale)]
        image_scale: f64,
        /// Also measure each match's distance from its epipolar line under the true motion
        /// (the sequence's `../../poses/NN.txt`), by the matcher's score: the keypoints' own
        /// error, with no estimated pose in it.
        #[arg(long)]
        ground_truth: bool,
    },
    /// The VO back of the pipeline without the networks: features and matches of a sequence
    /// are computed once, then the tracker (and the loop closer) replay them; medians per
    /// frame and per local bundle-adjustment window beside the networks' own time.
    Tracking {
        /// Sequence directory (`.../sequences/NN`).
        seq_dir: PathBuf,
        /// Frames to use (from the first).
        #[arg(long, default_value_t = 160)]
        frames: usize,
        /// Replays of the tracker over the recorded inputs.
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        /// Front end: xfeat-lighterglue, aliked-lightglue, orb or superpoint-superglue.
        #[arg(long, default_value = "xfeat-lighterglue")]
        frontend: String,
    },
    /// XFeat extraction and LighterGlue matching on two consecutive frames (and ALIKED and
    /// LightGlue when fetched).
    Frontend {
        /// First image; the second is the next frame (or the same image again).
        image_a: PathBuf,
        /// Second image.
        image_b: PathBuf,
        /// Timed calls per measurement (after 3 warm-up calls).
        #[arg(long, default_value_t = 15)]
        runs: usize,
        /// ONNX Runtime intra-op threads.
        #[arg(long, default_value_t = 2)]
        threads: usize,
        /// Write the matcher's inputs (normalised keypoints and descriptors at each keypoint
        /// count, raw little-endian f32) here, so another runtime can be timed on the same data.
        #[arg(long)]
        dump: Option<PathBuf>,
        /// Timed calls per ALIKED / LightGlue measurement (at most --runs; measured only when
        /// `supermvo models fetch aliked lightglue` has run).
        #[arg(long, default_value_t = 5)]
        aliked_runs: usize,
    },
}

fn median_ms(mut f: impl FnMut() -> Result<()>, runs: usize) -> Result<f64> {
    for _ in 0..3 {
        f()?;
    }
    let mut t = Vec::with_capacity(runs);
    for _ in 0..runs {
        let s = Instant::now();
        f()?;
        t.push(s.elapsed().as_secs_f64() * 1e3);
    }
    t.sort_by(f64::total_cmp);
    Ok(t[t.len() / 2])
}

/// Runs `supermvo bench`; prints one JSON object of medians in milliseconds.
pub fn run(args: &BenchArgs) -> Result<()> {
    let (image_a, image_b, runs, threads, dump, aliked_runs) = match &args.command {
        BenchCommand::Ipc { samples } => {
            let exe = std::env::current_exe()?;
            let rows = supermvo_pipeline::bench_ipc::run(&exe, (*samples).max(10))?;
            for r in &rows {
                outln!(
                    "{:<38} {:<40} {:>8} B  p50 {:>8.1} us  p99 {:>8.1} us",
                    r.transport,
                    r.payload,
                    r.bytes,
                    r.p50_us,
                    r.p99_us
                );
            }
            outln!("{}", serde_json::to_string(&rows)?);
            return Ok(());
        }
        BenchCommand::IpcEcho { name } => return supermvo_pipeline::bench_ipc::echo(name),
        BenchCommand::Tracking {
            seq_dir,
            frames,
            repeats,
            frontend,
        } => return tracking(seq_dir, *frames, (*repeats).max(1), frontend),
        BenchCommand::Frontend {
            image_a,
            image_b,
            runs,
            threads,
            dump,
            aliked_runs,
        } => (image_a, image_b, runs, threads, dump, aliked_runs),
        BenchCommand::Matching {
            sequences,
            top_k,
            threshold_px,
            confidence,
            csv,
            frontend,
            subpixel_keypoints,
            image_scale,
            ground_truth,
        } => {
            return matching(
                sequences,
                (frontend, *top_k, *subpixel_keypoints, *image_scale),
                (*threshold_px, *confidence),
                csv.as_deref(),
                *ground_truth,
            );
        }
    };
    if *runs == 0 {
        bail!("--runs must be at least 1");
    }
    let (a, b) = (GrayImage::load(image_a)?, GrayImage::load(image_b)?);
    let mut result = serde_json::Map::new();
    let mut xfeat = XFeat::new(
        &models::model_path("xfeat"),
        XFeatConfig {
            top_k: 2048,
            threads: *threads,
            ..Default::default()
        },
    )?;
    let (w, h) = ((a.width / 32) * 32, (a.height / 32) * 32);
    let input = resize_bilinear(&a, w, h);
    result.insert(
        "xfeat_network_ms".into(),
        median_ms(|| Ok(xfeat.with_raw(&input, h, w, |_| ())?), *runs)?.into(),
    );
    result.insert(
        "xfeat_extract_ms".into(),
        median_ms(|| Ok(xfeat.extract(&a).map(|_| ())?), *runs)?.into(),
    );
    let mut lg = LightGlue::new(
        &models::model_path("lighterglue"),
        "lighterglue",
        LightGlueConfig {
            threads: *threads,
            ..Default::default()
        },
    )?;
    // the same model with pruning switched off: the peer the pruned runs are compared with
    let mut lg_full = LightGlue::new(
        &models::model_path("lighterglue"),
        "lighterglue",
        LightGlueConfig {
            threads: *threads,
            width_confidence: -1.0,
            ..Default::default()
        },
    )?;
    // and with early stopping on (LightGlue's depth_confidence 0.95) as well as pruning
    let mut lg_depth = LightGlue::new(
        &models::model_path("lighterglue"),
        "lighterglue",
        LightGlueConfig {
            threads: *threads,
            depth_confidence: 0.95,
            ..Default::default()
        },
    )?;
    if let Some(dir) = dump {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        // the network inputs, so that the Python peer runs on exactly these pixels
        write_f32(&dir.join("xfeat_input.f32"), &input)?;
        let frame: Vec<f32> = a.data.iter().map(|&v| v as f32 / 255.0).collect();
        write_f32(&dir.join("frame_a.f32"), &frame)?;
    }
    for k in [1024usize, 2048] {
        let mut x = XFeat::new(
            &models::model_path("xfeat"),
            XFeatConfig {
                top_k: k,
                threads: *threads,
                ..Default::default()
            },
        )?;
        let (fa, fb) = (x.extract(&a)?, x.extract(&b)?);
        result.insert(format!("keypoints_{k}"), (fa.len().min(fb.len())).into());
        if let Some(dir) = dump {
            dump_matcher_inputs(dir, &format!("lighterglue_{k}"), &fa, &fb)?;
            result.insert(format!("dim_{k}"), fa.dim.into());
            result.insert(
                format!("sizes_{k}"),
                serde_json::json!([fa.len(), fb.len()]),
            );
        }
        let kept = lg.assignment(&fa, &fb)?;
        result.insert(
            format!("lighterglue_{k}_kept"),
            serde_json::json!([kept.kept0.len(), kept.kept1.len()]),
        );
        result.insert(
            format!("lighterglue_{k}_network_ms"),
            median_ms(|| Ok(lg.assignment(&fa, &fb).map(|_| ())?), *runs)?.into(),
        );
        result.insert(
            format!("lighterglue_{k}_network_unpruned_ms"),
            median_ms(|| Ok(lg_full.assignment(&fa, &fb).map(|_| ())?), *runs)?.into(),
        );
        result.insert(
            format!("lighterglue_{k}_early_stop_layers"),
            lg_depth.assignment(&fa, &fb)?.layers.into(),
        );
        result.insert(
            format!("lighterglue_{k}_network_early_stop_ms"),
            median_ms(|| Ok(lg_depth.assignment(&fa, &fb).map(|_| ())?), *runs)?.into(),
        );
        result.insert(
            format!("lighterglue_{k}_match_ms"),
            median_ms(|| Ok(lg.match_features(&fa, &fb).map(|_| ())?), *runs)?.into(),
        );
        let (full, pruned, early) = (
            lg_full.match_features(&fa, &fb)?,
            lg.match_features(&fa, &fb)?,
            lg_depth.match_features(&fa, &fb)?,
        );
        let common = |m: &supermvo_inference::Matches| {
            m.pairs.iter().filter(|p| full.pairs.contains(p)).count()
        };
        result.insert(
            format!("lighterglue_{k}_matches"),
            serde_json::json!({"pruned": pruned.pairs.len(), "unpruned": full.pairs.len(),
                "common": common(&pruned), "early_stop": early.pairs.len(),
                "early_stop_common": common(&early)}),
        );
    }
    if models::model_path("aliked").is_file() && models::model_path("lightglue").is_file() {
        aliked_lightglue(
            &a,
            &b,
            *threads,
            (*runs).min(*aliked_runs).max(1),
            dump.as_deref(),
            &mut result,
        )?;
    }
    result.insert("input_size".into(), serde_json::json!([w, h]));
    result.insert("frame_size".into(), serde_json::json!([a.width, a.height]));
    result.insert("threads".into(), (*threads).into());
    outln!("{}", serde_json::Value::Object(result));
    Ok(())
}

/// Writes a matcher's inputs for `fa` and `fb` (normalised keypoints, descriptors) as raw
/// little-endian f32 files `dir/{prefix}_{kpts0,kpts1,desc0,desc1}.f32`.
fn dump_matcher_inputs(
    dir: &std::path::Path,
    prefix: &str,
    fa: &supermvo_inference::Features,
    fb: &supermvo_inference::Features,
) -> Result<()> {
    for (name, data) in [
        ("kpts0", normalize_keypoints(fa)),
        ("kpts1", normalize_keypoints(fb)),
        ("desc0", fa.descriptors.clone()),
        ("desc1", fb.descriptors.clone()),
    ] {
        write_f32(&dir.join(format!("{prefix}_{name}.f32")), &data)?;
    }
    Ok(())
}

/// Writes `data` as raw little-endian f32.
fn write_f32(path: &std::path::Path, data: &[f32]) -> Result<()> {
    let raw: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
    std::fs::write(path, raw).with_context(|| format!("cannot write {}", path.display()))
}

/// ALIKED (the whole graph at the image's size; Rust adds the u8 -> f32 conversion and the
/// score threshold) and LightGlue at 1024 and 2048 requested keypoints, with LightGlue's
/// default pruning and early stopping and without either; `runs` calls each (they take
/// seconds on a small CPU).
fn aliked_lightglue(
    a: &GrayImage,
    b: &GrayImage,
    threads: usize,
    runs: usize,
    dump: Option<&std::path::Path>,
    result: &mut serde_json::Map<String, serde_json::Value>,
) -> Result<()> {
    use supermvo_inference::aliked::{Aliked, AlikedConfig};
    let open = |width_confidence, depth_confidence| {
        LightGlue::new(
            &models::model_path("lightglue"),
            "lightglue",
            LightGlueConfig {
                threads,
                width_confidence,
                depth_confidence,
                ..Default::default()
            },
        )
    };
    let (mut lg, mut lg_full) = (open(0.99, 0.95)?, open(-1.0, -1.0)?);
    result.insert("aliked_runs".into(), runs.into());
    for k in [1024usize, 2048] {
        let mut al = Aliked::new(
            &models::model_path("aliked"),
            AlikedConfig {
                top_k: k,
                threads,
                ..Default::default()
            },
        )?;
        if k == 2048 {
            result.insert(
                "aliked_extract_ms".into(),
                median_ms(|| Ok(al.extract(a).map(|_| ())?), runs)?.into(),
            );
        }
        let (fa, fb) = (al.extract(a)?, al.extract(b)?);
        result.insert(
            format!("aliked_{k}_sizes"),
            serde_json::json!([fa.len(), fb.len()]),
        );
        if let Some(dir) = dump {
            dump_matcher_inputs(dir, &format!("lightglue_{k}"), &fa, &fb)?;
        }
        let layers = lg.assignment(&fa, &fb)?.layers;
        result.insert(format!("lightglue_{k}_layers"), layers.into());
        result.insert(
            format!("lightglue_{k}_network_ms"),
            median_ms(|| Ok(lg.assignment(&fa, &fb).map(|_| ())?), runs)?.into(),
        );
        result.insert(
            format!("lightglue_{k}_network_full_ms"),
            median_ms(|| Ok(lg_full.assignment(&fa, &fb).map(|_| ())?), runs)?.into(),
        );
        let (m, full) = (
            lg.match_features(&fa, &fb)?,
            lg_full.match_features(&fa, &fb)?,
        );
        result.insert(
            format!("lightglue_{k}_matches"),
            serde_json::json!({"adaptive": m.pairs.len(), "full": full.pairs.len(),
                "common": m.pairs.iter().filter(|p| full.pairs.contains(p)).count()}),
        );
    }
    Ok(())
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        f64::NAN
    } else {
        v[v.len() / 2]
    }
}

/// XFeat + LighterGlue on consecutive frames, then 5-point RANSAC: a Markdown table row
/// per sequence (median and mean of matches, inliers, inlier ratio).
fn matching(
    sequences: &[PathBuf],
    (frontend, top_k, subpixel_keypoints, image_scale): (&str, usize, bool, f64),
    (threshold_px, confidence): (f64, f64),
    csv: Option<&std::path::Path>,
    ground_truth: bool,
) -> Result<()> {
    use supermvo_dataset::Sequence;
    use supermvo_geometry::essential::RansacConfig;
    use supermvo_vo::pairs::{epipolar_distances_px, essential_inliers};
    // the front end exactly as the pipeline builds it
    let pipeline = supermvo_config::PipelineConfig {
        frontend: frontend.parse().map_err(anyhow::Error::msg)?,
        top_k,
        subpixel_keypoints,
        image_scale,
        ..Default::default()
    };
    let mut xfeat = supermvo_pipeline::features::extractor(
        &pipeline,
        supermvo_config::NetworkPlacement::Alternating,
    )?;
    let mut lg = supermvo_pipeline::matching::matcher(
        &pipeline,
        supermvo_config::NetworkPlacement::Alternating,
    )?;
    let ransac = RansacConfig {
        threshold_px,
        confidence,
        ..Default::default()
    };
    let mut rows = String::from("seq,frame,matches,inliers\n");
    outln!("| seq | pairs | matches (median / mean) | inliers (median / mean) | inlier ratio (median / mean) |");
    outln!("|---|---|---|---|---|");
    let mut errors = Vec::new();
    for dir in sequences {
        let seq = Sequence::open(dir)?;
        let k = seq.calib;
        let truth = if ground_truth {
            let path = seq.default_ground_truth().with_context(|| {
                format!(
                    "--ground-truth: no poses for {} at {}; put the KITTI poses there",
                    seq.name(),
                    seq.ground_truth_candidate()
                        .map_or_else(|| "../../poses".into(), |p| p.display().to_string())
                )
            })?;
            Some(seq.read_ground_truth(&path)?.poses)
        } else {
            None
        };
        let (mut ms, mut is, mut rs) = (Vec::new(), Vec::new(), Vec::new());
        let mut seq_errors = Vec::new();
        let mut prev = xfeat.extract(&GrayImage::load(&seq.images[0])?)?;
        for (i, path) in seq.images.iter().enumerate().skip(1) {
            let cur = xfeat.extract(&GrayImage::load(path)?)?;
            let m = lg.match_features(&prev, &cur)?;
            if let Some(t) = &truth {
                let t_cur_prev = t[i].inverse().compose(&t[i - 1]);
                let d = epipolar_distances_px(&k, &t_cur_prev, (&prev, &cur), &m);
                seq_errors.extend(m.scores.iter().copied().zip(d));
            }
            let inl = essential_inliers(&k, &prev, &cur, &m, &ransac);
            rows.push_str(&format!(
                "{},{},{},{}\n",
                seq.name(),
                i - 1,
                m.pairs.len(),
                inl
            ));
            ms.push(m.pairs.len() as f64);
            is.push(inl as f64);
            rs.push(if m.pairs.is_empty() {
                0.0
            } else {
                inl as f64 / m.pairs.len() as f64
            });
            prev = cur;
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let (mm, im, rm) = (mean(&ms), mean(&is), mean(&rs));
        outln!(
            "| {} | {} | {:.0} / {:.0} | {:.0} / {:.0} | {:.3} / {:.3} |",
            seq.name(),
            ms.len(),
            median(&mut ms),
            mm,
            median(&mut is),
            im,
            median(&mut rs),
            rm
        );
        if truth.is_some() {
            errors.push((seq.name(), seq_errors));
        }
    }
    if let Some(p) = csv {
        std::fs::write(p, rows)?;
    }
    if ground_truth {
        print_errors_by_score(errors);
    }
    Ok(())
}

/// Per sequence, the share of matches farther than 1, 2 and 3 px from their true epipolar
/// line and the median distance, for all matches and per fifth of the matcher's scores.
fn print_errors_by_score(errors: Vec<(String, Vec<(f32, f64)>)>) {
    outln!("\nDistance from the true epipolar line (px), by the matcher's score (fifths, lowest first):");
    outln!("| seq | matches | score range | median | > 1 px | > 2 px | > 3 px |");
    outln!("|---|---|---|---|---|---|---|");
    for (name, mut e) in errors {
        e.sort_by(|a, b| a.0.total_cmp(&b.0));
        let n = e.len();
        let row = |label: String, part: &[(f32, f64)]| {
            let mut d: Vec<f64> = part.iter().map(|x| x.1).collect();
            let share =
                |x: f64| d.iter().filter(|&&v| v > x).count() as f64 / d.len().max(1) as f64;
            let (s1, s2, s3) = (share(1.0), share(2.0), share(3.0));
            outln!(
                "| {} | {} | {} | {:.2} | {:.3} | {:.3} | {:.3} |",
                name,
                part.len(),
                label,
                median(&mut d),
                s1,
                s2,
                s3
            );
        };
        row("all".into(), &e);
        for q in 0..5 {
            let part = &e[q * n / 5..(q + 1) * n / 5];
            if let (Some(lo), Some(hi)) = (part.first(), part.last()) {
                row(format!("{:.3}-{:.3}", lo.0, hi.0), part);
            }
        }
    }
}

/// One frame's recorded tracker input.
struct Recorded {
    meta: supermvo_vo::tracker::FrameMeta,
    features: supermvo_inference::Features,
    matches: Option<supermvo_inference::Matches>,
    reference: Option<usize>,
}

fn quantile(v: &[f64], q: f64) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return f64::NAN;
    }
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// `supermvo bench tracking`: see [`BenchCommand::Tracking`].
fn tracking(
    seq_dir: &std::path::Path,
    frames: usize,
    repeats: usize,
    frontend: &str,
) -> Result<()> {
    use supermvo_pipeline::{features, matching, tracking::tracker_config};
    use supermvo_vo::loops::{LoopCloser, LoopConfig};
    use supermvo_vo::pipeline::close_loops;
    use supermvo_vo::tracker::{FrameMeta, Tracker};
    let seq = supermvo_dataset::Sequence::open(seq_dir)?;
    let cfg = supermvo_config::PipelineConfig {
        frontend: frontend.parse().map_err(anyhow::Error::msg)?,
        ..Default::default()
    };
    let n = frames.min(seq.len());
    if n < 2 {
        bail!("{}: needs at least 2 frames", seq_dir.display());
    }
    let placement = supermvo_config::NetworkPlacement::Alternating;
    let (mut extractor, mut matcher) = (
        features::extractor(&cfg, placement)?,
        matching::matcher(&cfg, placement)?,
    );
    let mut tracker = Tracker::new(seq.calib, tracker_config(&cfg));
    let mut recorded = Vec::with_capacity(n);
    let (mut extract_ms, mut match_ms) = (Vec::new(), Vec::new());
    for i in 0..n {
        let image = seq.load_frame(i)?;
        let s = Instant::now();
        let cur = extractor.extract(&image)?;
        extract_ms.push(s.elapsed().as_secs_f64() * 1e3);
        let reference = tracker.reference().map(|(f, _)| f);
        let meta = FrameMeta {
            index: i,
            stamp: seq.times[i],
        };
        let mut matches = None;
        tracker.track_frame(meta, cur.clone(), |r, c| {
            let s = Instant::now();
            let m = matcher.match_features(r, c)?;
            match_ms.push(s.elapsed().as_secs_f64() * 1e3);
            matches = Some(m.clone());
            Ok::<_, anyhow::Error>(m)
        })?;
        recorded.push(Recorded {
            meta,
            features: cur,
            matches,
            reference,
        });
    }
    let (mut step_ms, mut kf_ms, mut other_ms, mut ba_ms, mut loop_ms) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut ba_sizes = Vec::new();
    for _ in 0..repeats {
        let mut tracker = Tracker::new(seq.calib, tracker_config(&cfg));
        let mut closer = LoopCloser::new(seq.calib, LoopConfig::default());
        for r in &recorded {
            if tracker.reference().map(|(f, _)| f) != r.reference {
                bail!(
                    "frame {}: the replayed tracker asks for another reference than the recorded run (not deterministic)",
                    r.meta.index
                );
            }
            let features = r.features.clone();
            let s = Instant::now();
            let out = tracker.track_frame(r.meta, features, |_, _| {
                r.matches.clone().ok_or_else(|| {
                    anyhow::anyhow!(
                        "frame {}: the replayed tracker needs matches the recorded run did not (not deterministic)",
                        r.meta.index
                    )
                })
            })?;
            let ms = s.elapsed().as_secs_f64() * 1e3;
            step_ms.push(ms);
            if out.keyframe {
                &mut kf_ms
            } else {
                &mut other_ms
            }
            .push(ms);
            if let Some(b) = tracker.take_ba_stats() {
                ba_ms.push(b.ms);
                ba_sizes.push((b.keyframes, b.points, b.observations));
            }
            let s = Instant::now();
            close_loops(&mut closer, &mut tracker, &out);
            loop_ms.push(s.elapsed().as_secs_f64() * 1e3);
        }
    }
    let tracking_median = quantile(&step_ms, 0.5);
    let networks_median = quantile(&extract_ms, 0.5) + quantile(&match_ms, 0.5);
    let mean_of = |f: fn(&(usize, usize, usize)) -> usize| {
        ba_sizes.iter().map(f).sum::<usize>() as f64 / ba_sizes.len().max(1) as f64
    };
    let result = serde_json::json!({
        "sequence": seq_dir, "frames": n, "repeats": repeats, "frontend": frontend,
        "tracking_ms_median": tracking_median,
        "tracking_ms_p90": quantile(&step_ms, 0.9),
        "tracking_keyframe_ms_median": quantile(&kf_ms, 0.5),
        "tracking_other_ms_median": quantile(&other_ms, 0.5),
        "ba_window_ms_median": quantile(&ba_ms, 0.5),
        "ba_window_ms_p90": quantile(&ba_ms, 0.9),
        "ba_windows": ba_ms.len() / repeats,
        "ba_mean_keyframes": mean_of(|s| s.0),
        "ba_mean_points": mean_of(|s| s.1),
        "ba_mean_observations": mean_of(|s| s.2),
        "loop_closer_ms_median": quantile(&loop_ms, 0.5),
        "loop_closer_ms_p90": quantile(&loop_ms, 0.9),
        "extraction_ms_median": quantile(&extract_ms, 0.5),
        "matching_ms_median": quantile(&match_ms, 0.5),
        "tracking_over_networks": tracking_median / networks_median,
    });
    outln!(
        "tracking without the networks: median {:.2} ms per frame (keyframes {:.2}, others {:.2}); local BA window median {:.2} ms ({} windows, ~{:.0} points); loop closer median {:.2} ms; networks {:.1} ms per frame (tracking/networks = {:.3})",
        tracking_median,
        quantile(&kf_ms, 0.5),
        quantile(&other_ms, 0.5),
        quantile(&ba_ms, 0.5),
        ba_ms.len() / repeats,
        mean_of(|s| s.1),
        quantile(&loop_ms, 0.5),
        networks_median,
        tracking_median / networks_median
    );
    outln!("{result}");
    Ok(())
}
