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
    let BenchCommand::Frontend {
        image_a,
        image_b,
        runs,
        threads,
    } = &args.command;
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
    println!("{}", serde_json::Value::Object(result));
    Ok(())
}
