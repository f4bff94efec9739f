//! The KITTI metric through the CLI on hand-computed trajectories.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use serde_json::Value;

#[test]
fn straight_line_scale_error_through_cli() {
    // 1 m per frame for 1000 m vs an estimate at 1.05 m per frame. With the devkit's
    // segment rule each segment of nominal length L covers L + 1 m, so its error is
    // 0.05 (L + 1) / L; the average over all 440 segments is computed here by hand.
    let d = tempfile::tempdir().unwrap();
    let line = |s: f64| -> String {
        (0..=1000)
            .map(|i| format!("1 0 0 0 0 1 0 0 0 0 1 {}\n", i as f64 * s))
            .collect()
    };
    let gt = d.path().join("gt.txt");
    let est = d.path().join("est.txt");
    std::fs::write(&gt, line(1.0)).unwrap();
    std::fs::write(&est, line(1.05)).unwrap();
    let js = d.path().join("r.json");
    let out = common::supermvo(&[
        "eval",
        "--gt",
        gt.to_str().unwrap(),
        "--est",
        est.to_str().unwrap(),
        "--json",
        js.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&js).unwrap()).unwrap();
    let mut sum = 0.0;
    let mut n = 0;
    for l in [100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0] {
        for f in (0..=1000).step_by(10) {
            if f as f64 + l < 1000.0 {
                sum += 0.05 * (l + 1.0) / l;
                n += 1;
            }
        }
    }
    assert_eq!(r["kitti"]["segments"].as_u64().unwrap(), n);
    let t = r["kitti"]["t_err_pct"].as_f64().unwrap();
    assert!((t - 100.0 * sum / n as f64).abs() < 1e-9, "{t}");
    assert!(r["kitti"]["r_err_deg_per_100m"].as_f64().unwrap().abs() < 1e-9);
    // Sim(3) alignment of a straight line is degenerate (the roll about the line is free):
    // a clear error, as in evo, rather than an arbitrary answer.
    common::expect_error(
        &[
            "eval",
            "--gt",
            gt.to_str().unwrap(),
            "--est",
            est.to_str().unwrap(),
            "--align",
            "sim3",
        ],
        &["alignment failed", "degenerate"],
    );
}
