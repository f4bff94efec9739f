//! `supermvo eval` of a timestamped (TUM) estimate against KITTI ground truth with its
//! `times.txt`: the README's KITTI recipe, where a run has not posed every frame.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use std::path::{Path, PathBuf};

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// KITTI ground truth of 10 frames at 10 Hz along x, its times, and a TUM estimate of 6 of
/// them at half the scale and shifted (Sim(3) alignment recovers it exactly).
fn files(d: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let gt: String = (0..10)
        .map(|i| {
            format!(
                "1 0 0 {} 0 1 0 {} 0 0 1 0\n",
                i as f64,
                (i * i) as f64 * 0.1
            )
        })
        .collect();
    let times: String = (0..10)
        .map(|i| format!("{:.6}\n", i as f64 * 0.1))
        .collect();
    let est: String = [0, 1, 2, 5, 6, 9]
        .iter()
        .map(|&i| {
            let (x, y) = (i as f64 * 0.5 + 3.0, (i * i) as f64 * 0.05);
            format!("{:.6} {x} {y} 0 0 0 0 1\n", i as f64 * 0.1)
        })
        .collect();
    (
        write(d, "00.txt", &gt),
        write(d, "times.txt", &times),
        write(d, "trajectory.tum.txt", &est),
    )
}

#[test]
fn a_tum_estimate_is_evaluated_against_kitti_ground_truth_with_its_times() {
    let d = tempfile::tempdir().unwrap();
    let (gt, times, est) = files(d.path());
    let json = d.path().join("ape.json");
    let r = common::supermvo(&[
        "eval",
        "--gt",
        gt.to_str().unwrap(),
        "--gt-times",
        times.to_str().unwrap(),
        "--est",
        est.to_str().unwrap(),
        "--est-format",
        "tum",
        "--align",
        "sim3",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(report["matched_poses"], 6, "{report}");
    assert!(report["ape"]["trans"]["rmse"].as_f64().unwrap() < 1e-9);
    assert!((report["alignment"]["scale"].as_f64().unwrap() - 2.0).abs() < 1e-9);
}

#[test]
fn times_that_do_not_fit_the_ground_truth_are_a_clear_error() {
    let d = tempfile::tempdir().unwrap();
    let (gt, _, est) = files(d.path());
    let short = write(d.path(), "short.txt", "0.0\n0.1\n");
    let (gt, est, short) = (
        gt.to_str().unwrap(),
        est.to_str().unwrap(),
        short.to_str().unwrap(),
    );
    common::expect_error(
        &[
            "eval",
            "--gt",
            gt,
            "--gt-times",
            short,
            "--est",
            est,
            "--est-format",
            "tum",
        ],
        &["--gt-times", "2 timestamps", "10 poses"],
    );
    common::expect_error(
        &[
            "eval",
            "--gt",
            est,
            "--format",
            "tum",
            "--gt-times",
            short,
            "--est",
            est,
        ],
        &["--gt-times", "carry their own"],
    );
    // without the times, a KITTI ground truth and a shorter TUM estimate cannot be paired
    common::expect_error(
        &["eval", "--gt", gt, "--est", est, "--est-format", "tum"],
        &["10", "6"],
    );
}
