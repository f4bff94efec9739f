//! Bad input to `supermvo eval`: one clear error naming file and line, never a panic.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use std::path::{Path, PathBuf};

const POSE: &str = "1 0 0 0 0 1 0 0 0 0 1 0";

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn kitti_lines(n: usize) -> String {
    (0..n)
        .map(|i| format!("1 0 0 {i} 0 1 0 0 0 0 1 0\n"))
        .collect()
}

fn eval_kitti(gt: &Path, est: &Path) -> Vec<String> {
    [
        "eval",
        "--gt",
        gt.to_str().unwrap(),
        "--est",
        est.to_str().unwrap(),
        "--format",
        "kitti",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

fn run_err(args: Vec<String>, needles: &[&str]) {
    let a: Vec<&str> = args.iter().map(String::as_str).collect();
    common::expect_error(&a, needles);
}

#[test]
fn wrong_column_count() {
    let d = tempfile::tempdir().unwrap();
    let gt = write(d.path(), "gt.txt", &kitti_lines(5));
    let est = write(
        d.path(),
        "est.txt",
        &format!("{POSE}\n{POSE}\n1 0 0 0 0 1 0 0 0 0 1\n"),
    );
    run_err(
        eval_kitti(&gt, &est),
        &["est.txt:3:", "found 11 columns, expected 12"],
    );
}

#[test]
fn non_numeric_and_nan_values() {
    let d = tempfile::tempdir().unwrap();
    let gt = write(d.path(), "gt.txt", &kitti_lines(3));
    let est = write(
        d.path(),
        "est.txt",
        &format!("{POSE}\n1 0 0 abc 0 1 0 0 0 0 1 0\n"),
    );
    run_err(
        eval_kitti(&gt, &est),
        &["est.txt:2:", "column 4: 'abc' is not a number"],
    );
    let est = write(
        d.path(),
        "nan.txt",
        &format!("{POSE}\n{POSE}\n1 0 0 nan 0 1 0 0 0 0 1 0\n"),
    );
    run_err(eval_kitti(&gt, &est), &["nan.txt:3:", "not finite"]);
    let tum_gt = write(d.path(), "g.tum", "0.0 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 0 1\n");
    let tum_est = write(
        d.path(),
        "e.tum",
        "0.0 0 0 0 0 0 0 1\n0.1 NaN 0 0 0 0 0 1\n",
    );
    let args = [
        "eval",
        "--gt",
        tum_gt.to_str().unwrap(),
        "--est",
        tum_est.to_str().unwrap(),
        "--format",
        "tum",
    ];
    common::expect_error(&args, &["e.tum:2:", "column 2", "not finite"]);
}

#[test]
fn empty_file() {
    let d = tempfile::tempdir().unwrap();
    let gt = write(d.path(), "gt.txt", &kitti_lines(3));
    let est = write(d.path(), "empty.txt", "");
    run_err(eval_kitti(&gt, &est), &["empty.txt", "file is empty"]);
}

#[test]
fn rotation_not_orthonormal() {
    let d = tempfile::tempdir().unwrap();
    let gt = write(
        d.path(),
        "gt.txt",
        &format!("{POSE}\n1.5 0 0 0 0 1 0 0 0 0 1 0\n"),
    );
    let est = write(d.path(), "est.txt", &kitti_lines(2));
    run_err(
        eval_kitti(&gt, &est),
        &[
            "gt.txt:2:",
            "rotation is not orthonormal",
            "reading ground truth",
        ],
    );
    let tum = write(d.path(), "q.tum", "0.0 0 0 0 0 0 0 0.5\n");
    let args = [
        "eval",
        "--gt",
        tum.to_str().unwrap(),
        "--est",
        tum.to_str().unwrap(),
        "--format",
        "tum",
    ];
    common::expect_error(&args, &["q.tum:1:", "quaternion has norm 0.500000"]);
}

#[test]
fn no_shared_timestamps() {
    let d = tempfile::tempdir().unwrap();
    let gt = write(d.path(), "gt.tum", "0.0 0 0 0 0 0 0 1\n0.1 1 0 0 0 0 0 1\n");
    let est = write(
        d.path(),
        "est.tum",
        "100.0 0 0 0 0 0 0 1\n100.1 1 0 0 0 0 0 1\n",
    );
    let args = [
        "eval",
        "--gt",
        gt.to_str().unwrap(),
        "--est",
        est.to_str().unwrap(),
        "--format",
        "tum",
    ];
    common::expect_error(
        &args,
        &["share no timestamps within 0.01 s", "--t-max-diff"],
    );
}

#[test]
fn mismatched_kitti_lengths() {
    let d = tempfile::tempdir().unwrap();
    let gt = write(d.path(), "gt.txt", &kitti_lines(10));
    let est = write(d.path(), "est.txt", &kitti_lines(9));
    run_err(
        eval_kitti(&gt, &est),
        &["reference 10 poses, estimate 9 poses"],
    );
}

#[test]
fn missing_file_and_bad_options() {
    let d = tempfile::tempdir().unwrap();
    let gt = write(d.path(), "gt.txt", &kitti_lines(10));
    let missing = d.path().join("nope.txt");
    run_err(eval_kitti(&gt, &missing), &["nope.txt", "No such file"]);
    let mut args = eval_kitti(&gt, &gt);
    args.extend(["--delta".into(), "1.5".into()]);
    run_err(args, &["eval.delta", "whole number"]);
    let cfg = write(d.path(), "c.toml", "[eval]\nalign = \"sim3\"\ncolour = 1\n");
    let mut args = eval_kitti(&gt, &gt);
    args.extend(["--config".into(), cfg.to_str().unwrap().into()]);
    run_err(args, &["c.toml", "colour"]);
}

#[test]
fn closed_stdout_is_not_a_panic() {
    // `supermvo ... | head -1`: the reader goes away before the output is written
    let d = tempfile::tempdir().unwrap();
    let gt = write(d.path(), "gt.txt", &kitti_lines(200));
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_supermvo"))
        .args([
            "eval",
            "--gt",
            gt.to_str().unwrap(),
            "--est",
            gt.to_str().unwrap(),
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(out.status.code(), Some(0), "{stderr}");
}

/// A missing file's OS error is printed once, not once by the file's error and again as
/// its cause.
#[test]
fn a_missing_file_is_one_error_with_the_os_reason_once() {
    let d = tempfile::tempdir().unwrap();
    let est = write(d.path(), "est.txt", &kitti_lines(3));
    let gt = d.path().join("missing_gt.txt");
    let out = common::supermvo(&[
        "eval",
        "--gt",
        gt.to_str().unwrap(),
        "--est",
        est.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("missing_gt.txt"), "{stderr}");
    assert_eq!(
        stderr.matches("No such file or directory").count(),
        1,
        "{stderr}"
    );
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
}

/// Two estimates whose file names give the same label would write the same figure and JSON
/// entry: refused before anything is written, with the way to name them.
#[test]
fn two_estimates_with_one_label_are_refused_before_writing() {
    let d = tempfile::tempdir().unwrap();
    let gt = write(d.path(), "gt.txt", &kitti_lines(5));
    for sub in ["a", "b"] {
        std::fs::create_dir_all(d.path().join(sub)).unwrap();
        write(&d.path().join(sub), "trajectory.txt", &kitti_lines(5));
    }
    let (a, b) = (
        d.path().join("a/trajectory.txt"),
        d.path().join("b/trajectory.txt"),
    );
    let plots = d.path().join("plots");
    common::expect_error(
        &[
            "eval",
            "--gt",
            gt.to_str().unwrap(),
            "--est",
            a.to_str().unwrap(),
            "--est",
            b.to_str().unwrap(),
            "--plot",
            plots.to_str().unwrap(),
        ],
        &["share the label 'trajectory'", "NAME=PATH"],
    );
    assert!(!plots.exists(), "nothing written");
    // named, both are evaluated
    let (na, nb) = (
        format!("first={}", a.display()),
        format!("second={}", b.display()),
    );
    let out = common::supermvo(&[
        "eval",
        "--gt",
        gt.to_str().unwrap(),
        "--est",
        &na,
        "--est",
        &nb,
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
