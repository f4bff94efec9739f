//! `supermvo traj`: inspects a trajectory and converts KITTI (with its times) to TUM and back.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use supermvo_dataset::{read_trajectory, TrajectoryFormat};

#[test]
fn kitti_to_tum_and_back_keeps_every_pose() {
    let (Some(poses), Some(seq)) = (
        common::shared_data("kitti/poses/07.txt"),
        common::shared_data("kitti/sequences/07"),
    ) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (tum, kitti) = (
        tmp.path().join("07.tum.txt"),
        tmp.path().join("07.kitti.txt"),
    );
    let (p, t) = (poses.to_str().unwrap(), seq.join("times.txt"));
    // without timestamps a KITTI file cannot become TUM: refused, naming what to give
    common::expect_error(
        &["traj", p, "--to", "tum", "--out", tum.to_str().unwrap()],
        &["no timestamps", "--times"],
    );
    let r = common::supermvo(&[
        "traj",
        p,
        "--times",
        t.to_str().unwrap(),
        "--to",
        "tum",
        "--out",
        tum.to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let info = String::from_utf8_lossy(&r.stdout);
    assert!(info.contains("160 poses") && info.contains("Hz"), "{info}");
    let r = common::supermvo(&[
        "traj",
        tum.to_str().unwrap(),
        "--format",
        "tum",
        "--to",
        "kitti",
        "--out",
        kitti.to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let a = read_trajectory(&poses, TrajectoryFormat::Kitti).unwrap();
    let b = read_trajectory(&kitti, TrajectoryFormat::Kitti).unwrap();
    let c = read_trajectory(&tum, TrajectoryFormat::Tum).unwrap();
    assert_eq!(a.len(), b.len());
    assert_eq!(c.stamps.as_ref().unwrap().len(), 160);
    for (x, y) in a.poses.iter().zip(&b.poses) {
        assert_eq!(x.t, y.t, "positions are written in round-trip form");
        // KITTI files hold rotations to about 1e-6, not exactly orthonormal; the TUM file's
        // quaternion is that of the nearest rotation
        let d = (x.r - y.r).abs().max();
        assert!(d < 1e-5, "rotations through quaternions: {d}");
    }
}

/// `eval --gt-dir POSES --est-dir RESULTS`, as the KITTI devkit evaluates a results folder:
/// 03's ground truth scaled by 1.1 has no rotation error and a translation error of 10 % of
/// each segment's chord (less of its length, through the turns), the number `eval --gt
/// --est` gives for the file alone; a result without ground truth is listed, not an error.
#[test]
fn a_results_folder_is_evaluated_as_the_devkit_does() {
    let Some(poses) = common::shared_data("kitti/poses") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let results = tmp.path().join("results");
    std::fs::create_dir_all(&results).unwrap();
    let mut t = read_trajectory(&poses.join("03.txt"), TrajectoryFormat::Kitti).unwrap();
    for p in t.poses.iter_mut() {
        p.t *= 1.1;
    }
    supermvo_dataset::write_trajectory(&results.join("03.txt"), TrajectoryFormat::Kitti, &t)
        .unwrap();
    std::fs::copy(poses.join("03.txt"), results.join("99.txt")).unwrap();
    let r = common::supermvo(&[
        "eval",
        "--gt-dir",
        poses.to_str().unwrap(),
        "--est-dir",
        results.to_str().unwrap(),
    ]);
    let out = String::from_utf8_lossy(&r.stdout);
    assert!(
        r.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&r.stderr)
    );
    let row = out.lines().find(|l| l.starts_with("03 ")).unwrap();
    let cells: Vec<&str> = row.split_whitespace().collect();
    assert_eq!(cells[1], "300", "{row}");
    let t_err: f64 = cells[2].parse().unwrap();
    assert!(t_err > 5.0 && t_err <= 10.0, "{row}");
    assert_eq!(cells[3], "0.0000", "{row}");
    let single = common::supermvo(&[
        "eval",
        "--gt",
        poses.join("03.txt").to_str().unwrap(),
        "--est",
        results.join("03.txt").to_str().unwrap(),
    ]);
    let single = String::from_utf8_lossy(&single.stdout);
    assert!(
        single.contains(&format!("t_err {:.4} %", t_err)),
        "{single}"
    );
    assert!(
        out.contains("99") && out.contains("no ground truth"),
        "{out}"
    );
    assert!(out.lines().any(|l| l.starts_with("average")), "{out}");
}
