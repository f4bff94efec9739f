//! Helpers shared by the inference tests.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code

use std::path::{Path, PathBuf};
use supermvo_inference::models;
use supermvo_inference::runtime::init;

fn required() -> bool {
    std::env::var("SUPERMVO_REQUIRE_SHARED").as_deref() == Ok("1")
}

/// `../shared` (data and reference models), ONNX Runtime loaded, and the cached models
/// named in `names`; or a printed skip (a failure when `SUPERMVO_REQUIRE_SHARED=1`).
pub fn setup(names: &[&str]) -> Option<(PathBuf, Vec<PathBuf>)> {
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared");
    let paths: Vec<PathBuf> = names.iter().map(|n| models::model_path(n)).collect();
    if shared.join("models/reference").is_dir()
        && paths.iter().all(|p| p.is_file())
        && init(None).is_ok()
    {
        return Some((shared, paths));
    }
    let why = format!(
        "shared data, ONNX Runtime or models {names:?} missing: run 'supermvo models fetch'"
    );
    assert!(!required(), "{why} (SUPERMVO_REQUIRE_SHARED=1)");
    eprintln!("SKIP: {why}");
    None
}

/// Runs a single-input session and returns every output as f32.
pub fn run(
    session: &mut ort::session::Session,
    name: &str,
    shape: [usize; 4],
    data: &[f32],
) -> Vec<Vec<f32>> {
    let t = ort::value::TensorRef::from_array_view((shape, data)).unwrap();
    let out = session.run(ort::inputs![name => t]).unwrap();
    (0..out.len())
        .map(|i| out[i].try_extract_tensor::<f32>().unwrap().1.to_vec())
        .collect()
}
