//! The ALIKED + LightGlue front end (the graphs themselves are checked against reference
//! forward passes by tools/models/test_aliked_lightglue.py): its features and matches on
//! consecutive KITTI frames, as the pipeline builds it, against the epipolar geometry and
//! against ORB; LightGlue's pruning and early stopping against the full network; and the
//! error when the models are missing.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use supermvo_config::{Frontend, PipelineConfig};
use supermvo_dataset::{GrayImage, Sequence};
use supermvo_geometry::essential::RansacConfig;
use supermvo_inference::lighterglue::{LightGlue, LightGlueConfig};
use supermvo_inference::{models, Features, Matcher, Matches};

const ALTERNATING: supermvo_config::NetworkPlacement =
    supermvo_config::NetworkPlacement::Alternating;
use supermvo_vo::pairs::essential_inliers;

/// 5-point RANSAC inliers (1 px, 0.999) of `m` between `a` and `b` under `seq`'s calibration.
fn inliers(seq: &Sequence, a: &Features, b: &Features, m: &Matches) -> usize {
    essential_inliers(&seq.calib, a, b, m, &RansacConfig::default())
}

#[test]
fn consecutive_kitti_frames_give_many_epipolar_inliers_and_beat_orb() {
    let Some(kitti) = common::shared_data("kitti/sequences") else {
        return;
    };
    if !common::models_ready_for(&["aliked", "lightglue"]) {
        return;
    }
    let cfg = |frontend| PipelineConfig {
        frontend,
        top_k: 2048,
        ..Default::default()
    };
    let mut aliked =
        supermvo_pipeline::features::extractor(&cfg(Frontend::AlikedLightglue), ALTERNATING)
            .unwrap();
    let mut glue =
        supermvo_pipeline::matching::matcher(&cfg(Frontend::AlikedLightglue), ALTERNATING).unwrap();
    let mut orb = supermvo_pipeline::features::extractor(&cfg(Frontend::Orb), ALTERNATING).unwrap();
    let mut orb_match =
        supermvo_pipeline::matching::matcher(&cfg(Frontend::Orb), ALTERNATING).unwrap();
    let mut full = LightGlue::new(
        &models::model_path("lightglue"),
        "lightglue",
        LightGlueConfig {
            width_confidence: -1.0,
            depth_confidence: -1.0,
            ..Default::default()
        },
    )
    .unwrap();
    for (name, frame) in [("00", 0), ("07", 100)] {
        let seq = Sequence::open(&kitti.join(name)).unwrap();
        let (ia, ib) = (
            GrayImage::load(&seq.images[frame]).unwrap(),
            GrayImage::load(&seq.images[frame + 1]).unwrap(),
        );
        let (a, b) = (aliked.extract(&ia).unwrap(), aliked.extract(&ib).unwrap());
        for f in [&a, &b] {
            assert!(
                f.len() > 500 && f.len() <= 2048,
                "{name}: {} keypoints",
                f.len()
            );
            assert_eq!((f.dim, f.image_size), (128, (ia.width, ia.height)));
            assert!(f.scores.windows(2).all(|s| s[0] >= s[1]) && f.scores[f.len() - 1] > 0.2);
            for (i, p) in f.keypoints.iter().enumerate() {
                assert!(p[0] >= 0.0 && p[0] <= (ia.width - 1) as f32, "{p:?}");
                assert!(p[1] >= 0.0 && p[1] <= (ia.height - 1) as f32, "{p:?}");
                let n: f32 = f.descriptor(i).iter().map(|v| v * v).sum();
                assert!((n - 1.0).abs() < 1e-4, "descriptor norm^2 {n}");
            }
        }
        let m = glue.match_features(&a, &b).unwrap();
        let inl = inliers(&seq, &a, &b, &m);
        let ratio = inl as f64 / m.pairs.len() as f64;
        // ORB through the same RANSAC
        let (oa, ob) = (orb.extract(&ia).unwrap(), orb.extract(&ib).unwrap());
        let om = orb_match.match_features(&oa, &ob).unwrap();
        let orb_inl = inliers(&seq, &oa, &ob, &om);
        eprintln!(
            "{name} {frame}: {} + {} keypoints, {} matches, {inl} inliers ({ratio:.3}); ORB {} matches, {orb_inl} inliers",
            a.len(),
            b.len(),
            m.pairs.len(),
            om.pairs.len()
        );
        assert!(
            m.pairs.len() > 800 && ratio > 0.9,
            "{name}: {inl}/{}",
            m.pairs.len()
        );
        assert!(
            inl > orb_inl,
            "{name}: ALIKED+LightGlue {inl} inliers, ORB {orb_inl}"
        );
        // pruning and early stopping (LightGlue's defaults) keep the full network's matches
        let all = full.match_features(&a, &b).unwrap();
        let shared = m.pairs.iter().filter(|p| all.pairs.contains(p)).count();
        eprintln!(
            "{name} {frame}: full network {} matches, {shared} of them also with pruning and early stopping",
            all.pairs.len()
        );
        assert!(
            shared as f64 >= 0.95 * all.pairs.len() as f64,
            "{shared} of {}",
            all.pairs.len()
        );
    }
}

#[test]
fn without_the_models_the_run_says_how_to_fetch_them() {
    let Some(seq) = common::shared_data("kitti/sequences/06") else {
        return;
    };
    if !common::models_ready() {
        return;
    }
    let cache = tempfile::tempdir().unwrap();
    let r = common::run_frontend_with_cache(
        cache.path(),
        &seq,
        "aliked-lightglue",
        &["--max-frames", "3"],
    );
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success());
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        err.contains("aliked.onnx not found") && err.contains("supermvo models fetch aliked"),
        "{err}"
    );
}

/// The daemon checks ONNX Runtime and the models before it starts any stage: a missing
/// model is the same one clear error as in process, not stages failing and restarting.
#[test]
fn the_daemon_checks_the_models_before_starting_stages() {
    let Some(seq) = common::shared_data("kitti/sequences/06") else {
        return;
    };
    if !common::models_ready() {
        return;
    }
    let cache = tempfile::tempdir().unwrap();
    let out = cache.path().join("out");
    let r = std::process::Command::new(env!("CARGO_BIN_EXE_supermvo"))
        .arg("run")
        .arg(&seq)
        .args(["--mode", "multiprocess", "-q", "--max-frames", "3"])
        .args(["--name", "preflight-test", "--out"])
        .arg(&out)
        .env("SUPERMVO_CACHE", cache.path())
        .env("ORT_DYLIB_PATH", common::runtime_library())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(
        err.contains("xfeat.onnx not found") && err.contains("supermvo models fetch xfeat"),
        "{err}"
    );
    assert!(!err.contains("restart"), "{err}");
    assert!(!out.join("logs").exists(), "no stage was started");
}
