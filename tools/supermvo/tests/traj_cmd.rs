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
