//! `supermvo bench frontend`: per-call timings of the learned front end (medians).

use anyhow::{bail, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;
use std::time::Instant;
use supermvo_inference::lighterglue::{LightGlue, LightGlueConfig};
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
        /// Keypoints per frame.
        #[arg(long, default_value_t = 2048)]
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
        /// Front end: xfeat-lighterglue or orb.
        #[arg(long, default_value = "xfeat-lighterglue")]
        frontend: String,
    },
    /// XFeat extraction and LighterGlue matching on two consecutive frames.
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
    let (image_a, image_b, runs, threads) = match &args.command {
        BenchCommand::Ipc { samples } => {
            let exe = std::env::current_exe()?;
            let rows = supermvo_services::bench_ipc::run(&exe, (*samples).max(10))?;
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
        BenchCommand::IpcEcho { name } => return supermvo_services::bench_ipc::echo(name),
        BenchCommand::Frontend {
            image_a,
            image_b,
            runs,
            threads,
        } => (image_a, image_b, runs, threads),
        BenchCommand::Matching {
            sequences,
            top_k,
            threshold_px,
            confidence,
            csv,
            frontend,
        } => {
            return matching(
                sequences,
                (frontend, *top_k),
                *threshold_px,
                *confidence,
                csv.as_deref(),
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
        median_ms(|| Ok(xfeat.run_raw(&input, h, w).map(|_| ())?), *runs)?.into(),
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
        result.insert(
            format!("lighterglue_{k}_network_ms"),
            median_ms(|| Ok(lg.log_assignment(&fa, &fb).map(|_| ())?), *runs)?.into(),
        );
        result.insert(
            format!("lighterglue_{k}_match_ms"),
            median_ms(|| Ok(lg.match_features(&fa, &fb).map(|_| ())?), *runs)?.into(),
        );
    }
    result.insert("input_size".into(), serde_json::json!([w, h]));
    result.insert("threads".into(), (*threads).into());
    outln!("{}", serde_json::Value::Object(result));
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
    (frontend, top_k): (&str, usize),
    threshold_px: f64,
    confidence: f64,
    csv: Option<&std::path::Path>,
) -> Result<()> {
    use supermvo_dataset::KittiSequence;
    use supermvo_geometry::essential::{find_essential, RansacConfig};
    use supermvo_geometry::Vec3;
    let (mut xfeat, mut lg): (Box<dyn Extractor>, Box<dyn Matcher>) = match frontend {
        "xfeat-lighterglue" => (
            Box::new(XFeat::new(
                &models::model_path("xfeat"),
                XFeatConfig {
                    top_k,
                    ..Default::default()
                },
            )?),
            Box::new(LightGlue::new(
                &models::model_path("lighterglue"),
                "lighterglue",
                LightGlueConfig::default(),
            )?),
        ),
        "orb" => (
            Box::new(supermvo_inference::orb::Orb::new(
                supermvo_inference::orb::OrbConfig {
                    top_k,
                    ..Default::default()
                },
            )),
            Box::new(supermvo_inference::orb::OrbMatcher::default()),
        ),
        other => bail!("unknown front end '{other}'; use xfeat-lighterglue or orb"),
    };
    let ransac = RansacConfig {
        threshold_px,
        confidence,
        ..Default::default()
    };
    let mut rows = String::from("seq,frame,matches,inliers\n");
    outln!("| seq | pairs | matches (median / mean) | inliers (median / mean) | inlier ratio (median / mean) |");
    outln!("|---|---|---|---|---|");
    for dir in sequences {
        let seq = KittiSequence::open(dir)?;
        let k = seq.calib;
        let norm = |p: &[f32; 2]| {
            Vec3::new(
                (p[0] as f64 - k.cx) / k.fx,
                (p[1] as f64 - k.cy) / k.fy,
                1.0,
            )
        };
        let (mut ms, mut is, mut rs) = (Vec::new(), Vec::new(), Vec::new());
        let mut prev = xfeat.extract(&GrayImage::load(&seq.images[0])?)?;
        for (i, path) in seq.images.iter().enumerate().skip(1) {
            let cur = xfeat.extract(&GrayImage::load(path)?)?;
            let m = lg.match_features(&prev, &cur)?;
            let x1: Vec<Vec3> = m
                .pairs
                .iter()
                .map(|&(a, _)| norm(&prev.keypoints[a]))
                .collect();
            let x2: Vec<Vec3> = m
                .pairs
                .iter()
                .map(|&(_, b)| norm(&cur.keypoints[b]))
                .collect();
            let inl = find_essential(&x1, &x2, 0.5 * (k.fx + k.fy), &ransac)
                .map_or(0, |e| e.inlier_count());
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
    }
    if let Some(p) = csv {
        std::fs::write(p, rows)?;
    }
    Ok(())
}
