//! `supermvo eval` against evo 1.38.1's numbers for every case of `tools/evo_parity.py`.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use serde_json::Value;

const RTOL: f64 = 1e-6;

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= RTOL * a.abs().max(b.abs()) || (a - b).abs() <= 1e-12
}

#[test]
fn every_statistic_matches_evo() {
    let Some(traj_dir) = common::shared_data("trajectories") else {
        return;
    };
    let fixture: Value = serde_json::from_str(
        &std::fs::read_to_string(common::root().join("tests/fixtures/evo_1.38.1_reference.json"))
            .unwrap(),
    )
    .unwrap();
    let cases = fixture["cases"].as_array().unwrap();
    assert_eq!(cases.len(), 84);
    let tmp = tempfile::tempdir().unwrap();
    let mut compared = 0;
    for (ci, case) in cases.iter().enumerate() {
        let js = tmp.path().join(format!("{ci}.json"));
        let gt = traj_dir.join(case["gt"].as_str().unwrap());
        let est = traj_dir.join(case["est"].as_str().unwrap());
        let delta = case["delta"].as_f64().unwrap().to_string();
        let tmd = case["t_max_diff"].as_f64().unwrap().to_string();
        let args = [
            "eval",
            "--quiet",
            "--gt",
            gt.to_str().unwrap(),
            "--est",
            est.to_str().unwrap(),
            "--format",
            case["format"].as_str().unwrap(),
            "--align",
            case["align"].as_str().unwrap(),
            "--delta",
            &delta,
            "--delta-unit",
            case["delta_unit"].as_str().unwrap(),
            "--t-max-diff",
            &tmd,
            "--json",
            js.to_str().unwrap(),
        ];
        let out = common::supermvo(&args);
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let ours: Value = serde_json::from_str(&std::fs::read_to_string(&js).unwrap()).unwrap();
        let evo = &case["evo"];
        let label = format!(
            "{} align={} delta={} {}",
            case["name"], case["align"], delta, case["delta_unit"]
        );
        assert_eq!(ours["matched_poses"], evo["matched_poses"], "{label}");
        for metric in ["ape", "rpe"] {
            if evo[metric].is_null() {
                assert!(
                    ours[metric].is_null(),
                    "{label}: evo finds no RPE pair, supermvo does"
                );
                assert!(ours["rpe_error"]
                    .as_str()
                    .unwrap()
                    .contains("no pose pairs"));
                continue;
            }
            for (rel, stats) in evo[metric].as_object().unwrap() {
                for (k, v) in stats.as_object().unwrap() {
                    let (a, b) = (v.as_f64().unwrap(), ours[metric][rel][k].as_f64().unwrap());
                    assert!(
                        close(a, b),
                        "{label} {metric}.{rel}.{k}: evo {a} supermvo {b}"
                    );
                    compared += 1;
                }
            }
        }
    }
    assert_eq!(compared, 2772);
}

#[test]
fn published_paper_numbers() {
    let Some(dir) = common::shared_data("trajectories/supermvo-paper") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let js = tmp.path().join("r.json");
    let (gt, est) = (dir.join("00_gt_tum.txt"), dir.join("00_supermvo_tum.txt"));
    let out = common::supermvo(&[
        "eval",
        "--gt",
        gt.to_str().unwrap(),
        "--est",
        est.to_str().unwrap(),
        "--format",
        "tum",
        "--t-max-diff",
        "0.02",
        "--align",
        "sim3",
        "--json",
        js.to_str().unwrap(),
    ]);
    assert!(out.status.success());
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&js).unwrap()).unwrap();
    assert!((r["ape"]["trans"]["rmse"].as_f64().unwrap() - 93.335).abs() < 5e-4);
    assert!((r["rpe"]["trans"]["rmse"].as_f64().unwrap() - 0.2858).abs() < 5e-5);
    // the JSON has the documented shape
    for k in ["ape", "rpe", "kitti", "alignment", "matched_poses"] {
        assert!(!r[k].is_null(), "missing {k}");
    }
    for k in ["rmse", "mean", "median", "std", "min", "max", "sse"] {
        assert!(r["ape"]["rot_deg"][k].is_f64() && r["rpe"]["trans"][k].is_f64());
    }
    assert!(r["kitti"]["t_err_pct"].is_f64() && r["kitti"]["r_err_deg_per_100m"].is_f64());
    assert_eq!(r["alignment"]["rotation"].as_array().unwrap().len(), 3);
    assert!((r["alignment"]["scale"].as_f64().unwrap() - 0.7347).abs() < 1e-3);
}
