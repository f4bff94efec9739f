//! `supermvo features`: run a learned extractor on images.

use anyhow::{Context, Result};
use clap::Args;
use std::path::PathBuf;
use supermvo_inference::xfeat::{XFeat, XFeatConfig};
use supermvo_inference::{models, Extractor, GrayImage};

/// Arguments of `supermvo features`.
#[derive(Debug, Args)]
pub struct FeaturesArgs {
    /// Images (PNG).
    #[arg(required = true)]
    images: Vec<PathBuf>,
    /// ONNX model [default: xfeat from the model cache].
    #[arg(long)]
    model: Option<PathBuf>,
    /// Keep at most this many keypoints, 64-8192.
    #[arg(long, default_value_t = 2048, value_parser = crate::keypoint_count)]
    top_k: usize,
    /// ONNX Runtime intra-op threads.
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Where the network runs: cpu, or cuda (falls back to the CPU with a warning).
    #[arg(long, value_enum, default_value_t = DeviceArg::Cpu)]
    device: DeviceArg,
    /// Write keypoints, scores and descriptors as JSON here (one object per image).
    #[arg(long)]
    json: Option<PathBuf>,
}

/// `--device`.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum DeviceArg {
    /// ONNX Runtime's CPU execution provider.
    Cpu,
    /// ONNX Runtime's CUDA execution provider.
    Cuda,
}

impl From<DeviceArg> for supermvo_inference::runtime::Device {
    fn from(d: DeviceArg) -> Self {
        match d {
            DeviceArg::Cpu => Self::Cpu,
            DeviceArg::Cuda => Self::Cuda,
        }
    }
}

impl From<DeviceArg> for supermvo_config::Device {
    fn from(d: DeviceArg) -> Self {
        match d {
            DeviceArg::Cpu => Self::Cpu,
            DeviceArg::Cuda => Self::Cuda,
        }
    }
}

/// Runs `supermvo features`.
pub fn run(args: &FeaturesArgs) -> Result<()> {
    let model = args
        .model
        .clone()
        .unwrap_or_else(|| models::model_path("xfeat"));
    let mut xfeat = XFeat::new(
        &model,
        XFeatConfig {
            top_k: args.top_k,
            threads: args.threads,
            device: args.device.into(),
            ..Default::default()
        },
    )?;
    outln!("xfeat on {}", xfeat.device());
    let mut out = Vec::new();
    for path in &args.images {
        let img = GrayImage::load(path)?;
        let f = xfeat
            .extract(&img)
            .with_context(|| format!("extracting features from {}", path.display()))?;
        outln!(
            "{}: {}x{}, {} keypoints",
            path.display(),
            img.width,
            img.height,
            f.len()
        );
        out.push(serde_json::json!({
            "image": path, "width": img.width, "height": img.height,
            "keypoints": f.keypoints, "scores": f.scores, "descriptor_dim": f.dim,
            "descriptors": f.descriptors,
        }));
    }
    if let Some(p) = &args.json {
        std::fs::write(p, serde_json::to_string(&out)?)
            .with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}
