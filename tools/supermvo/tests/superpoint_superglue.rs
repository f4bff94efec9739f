//! The SuperPoint + SuperGlue front end through the pipeline. The official weights cannot be
//! obtained here, so the plumbing runs on random-weight models in the official layout
//! (written by tools/models/test_superpoint_superglue.py, which also checks the graphs
//! against reference forward passes); without the models the run is one clear error.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use std::path::Path;
use std::process::Command;

/// `supermvo run` of KITTI 00's first frames through the SuperPoint + SuperGlue front end,
/// with the model cache at `cache`; output in `cache/out`.
fn run_spsg(cache: &Path, seq: &Path, extra: &[&str]) -> std::process::Output {
    common::run_frontend_with_cache(cache, seq, "superpoint-superglue", extra)
}

/// Writes the random-weight SuperPoint and SuperGlue models into `dir/models` with
/// tools/models/test_superpoint_superglue.py (which first checks the graphs); `extra` adds
/// its arguments.
fn write_random_models(dir: &Path, extra: &[std::ffi::OsString]) {
    let made = Command::new("python3")
        .arg(common::root().join("tools/models/test_superpoint_superglue.py"))
        .arg("--write")
        .arg(dir)
        .args(extra)
        .output()
        .unwrap();
    assert!(
        made.status.success(),
        "{}{}",
        String::from_utf8_lossy(&made.stdout),
        String::from_utf8_lossy(&made.stderr)
    );
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
    write_random_models(cache.path(), &[]);
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

/// The Rust SuperPoint post-processing against a NumPy version of MagicLeap's (softmax,
/// NMS with recovery rounds, threshold, border, top-k, grid_sample descriptors), both on the
/// same random-weight network's outputs for a 640x368 crop of a KITTI frame.
#[test]
fn superpoint_postprocessing_matches_the_reference() {
    use supermvo_inference::superpoint::{SuperPoint, SuperPointConfig};
    use supermvo_inference::{Extractor, GrayImage};
    let Some(frame) = common::shared_data("kitti/sequences/00/image_0/000000.png") else {
        return;
    };
    if !common::models_ready() {
        return;
    }
    let full = GrayImage::load(&frame).unwrap();
    let (w, h) = (640usize, 368usize);
    let crop = GrayImage {
        width: w,
        height: h,
        data: (0..h)
            .flat_map(|y| full.data[y * full.width..y * full.width + w].to_vec())
            .collect(),
    };
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("crop.raw");
    std::fs::write(&raw, &crop.data).unwrap();
    write_random_models(
        dir.path(),
        &[
            "--image".into(),
            raw.into(),
            w.to_string().into(),
            h.to_string().into(),
        ],
    );
    let expected: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("superpoint_expected.json")).unwrap(),
    )
    .unwrap();
    supermvo_inference::runtime::init(Some(&common::runtime_library())).unwrap();
    let mut sp = SuperPoint::new(
        &dir.path().join("models/superpoint.onnx"),
        SuperPointConfig {
            top_k: usize::MAX, // every keypoint, so the NMS is compared everywhere
            ..Default::default()
        },
    )
    .unwrap();
    let f = sp.extract(&crop).unwrap();
    let kp = expected["keypoints"].as_array().unwrap();
    assert!(kp.len() > 100, "the reference found {} keypoints", kp.len());
    assert_eq!(f.len(), kp.len());
    // the same keypoints; the order may differ only between scores equal to float
    // precision (the reference computes in f64)
    let index: std::collections::HashMap<(i64, i64), usize> = kp
        .iter()
        .enumerate()
        .map(|(j, k)| {
            let k = k.as_array().unwrap();
            (
                (k[0].as_f64().unwrap() as i64, k[1].as_f64().unwrap() as i64),
                j,
            )
        })
        .collect();
    for i in 0..f.len() {
        let key = (f.keypoints[i][0] as i64, f.keypoints[i][1] as i64);
        assert_eq!(
            (key.0 as f32, key.1 as f32),
            (f.keypoints[i][0], f.keypoints[i][1]),
            "integer pixel positions"
        );
        let j = *index
            .get(&key)
            .unwrap_or_else(|| panic!("keypoint {i} at {key:?} is not in the reference"));
        let s = expected["scores"][j].as_f64().unwrap();
        assert!((f.scores[i] as f64 - s).abs() < 1e-5, "score {i}");
        let in_order = expected["scores"][i].as_f64().unwrap();
        assert!(
            (f.scores[i] as f64 - in_order).abs() < 1e-5,
            "rank {i}: {} vs {in_order}",
            f.scores[i]
        );
        let d = expected["descriptors"][j].as_array().unwrap();
        let err = d
            .iter()
            .zip(f.descriptor(i))
            .map(|(a, b)| (a.as_f64().unwrap() - *b as f64).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-4, "descriptor {i}: {err}");
    }
    eprintln!("{} keypoints as the reference", f.len());
}
