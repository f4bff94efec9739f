//! The SuperPoint + SuperGlue front end through the pipeline. The official weights cannot be
//! obtained here, so the plumbing runs on random-weight models in the official layout
//! (written by tools/models/test_superpoint_superglue.py, which also checks the graphs
//! against reference forward passes); without the models the run is one clear error.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use std::path::PathBuf;
use std::process::Command;

fn runtime_library() -> PathBuf {
    let home = std::env::var_os("SUPERMVO_CACHE")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(std::env::var("HOME").unwrap()).join(".cache/supermvo"));
    home.join("onnxruntime/1.31.1/libonnxruntime.so.1.31.1")
}

/// `supermvo run` of KITTI 00's first frames through the SuperPoint + SuperGlue front end,
/// with the model cache at `cache` (ONNX Runtime from the usual cache); output in
/// `cache/out`.
fn run_spsg(
    cache: &std::path::Path,
    seq: &std::path::Path,
    extra: &[&str],
) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_supermvo"))
        .arg("run")
        .arg(seq)
        .args([
            "--mode",
            "inprocess",
            "-q",
            "--frontend",
            "superpoint-superglue",
        ])
        .arg("--out")
        .arg(cache.join("out"))
        .args(extra)
        .env("SUPERMVO_CACHE", cache)
        .env("ORT_DYLIB_PATH", runtime_library())
        .output()
        .unwrap()
}

#[test]
fn without_the_exported_weights_the_run_says_how_to_export_them() {
    let Some(seq) = common::shared_data("kitti/sequences/00") else {
        return;
    };
    if !common::models_ready() {
        return;
    }
    let cache = tempfile::tempdir().unwrap();
    let r = run_spsg(cache.path(), &seq, &["--max-frames", "3"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success());
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        err.contains("superpoint.onnx not found")
            && err.contains("supermvo models fetch superpoint --weights"),
        "{err}"
    );
}

#[test]
fn random_weight_models_run_through_the_pipeline() {
    let Some(seq) = common::shared_data("kitti/sequences/00") else {
        return;
    };
    if !common::models_ready() {
        return;
    }
    let cache = tempfile::tempdir().unwrap();
    let script = common::root().join("tools/models/test_superpoint_superglue.py");
    let made = Command::new("python3")
        .arg(&script)
        .arg("--write")
        .arg(cache.path())
        .output()
        .unwrap();
    assert!(
        made.status.success(),
        "{}{}",
        String::from_utf8_lossy(&made.stdout),
        String::from_utf8_lossy(&made.stderr)
    );
    let r = run_spsg(cache.path(), &seq, &["--top-k", "256", "--max-frames", "4"]);
    let out = cache.path().join("out");
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(r.status.success(), "{err}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let frames = report["frames_detail"].as_array().unwrap();
    assert_eq!(frames.len(), 4);
    for f in frames {
        // random weights find keypoints everywhere (the top 256 are kept) but match nothing
        // confidently; the tracker logs that it is still initialising
        assert_eq!(f["keypoints"], 256, "{f}");
        assert!(f["state"].is_string(), "{f}");
    }
}
