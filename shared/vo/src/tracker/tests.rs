#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
use super::*;
use supermvo_geometry::{Mat3, Vec3};

const F: f64 = 700.0;

/// A camera of focal length `F` with principal point `(cx, cy)`.
fn calibration(cx: f64, cy: f64) -> Calibration {
    Calibration {
        fx: F,
        fy: F,
        cx,
        cy,
    }
}

fn features(n: usize, shift: f32) -> Features {
    Features {
        keypoints: (0..n)
            .map(|i| [(i % 40) as f32 * 30.0 + shift, (i / 40) as f32 * 30.0])
            .collect(),
        scores: vec![1.0; n],
        descriptors: vec![0.0; n * 4],
        dim: 4,
        image_size: (1241, 376),
    }
}

/// Frames dropped upstream (a real-time pipeline behind) never reach the tracker: the
/// prediction for the next frame it sees spans them, and the motion measured over the
/// gap becomes a motion per frame again.
#[test]
fn the_motion_model_spans_frames_that_never_arrived() {
    let mut tr = Tracker::new(calibration(620.0, 188.0), TrackerConfig::default());
    let yaw = |a: f64| supermvo_geometry::so3_exp(&Vec3::new(0.0, a, 0.0));
    tr.velocity = Some(Pose::new(yaw(0.02), Vec3::new(0.0, 0.0, -1.0)));
    tr.last_t_cam_world = Pose::identity();
    tr.note_frame(10);
    let Pose { r: r1, t: t1 } = tr.predict().unwrap();
    // frames 11 and 12 dropped: frame 13 is three steps on
    tr.note_frame(13);
    assert_eq!(tr.unseen, 2);
    let Pose { r: r3, t: t3 } = tr.predict().unwrap();
    let mut expected = (Mat3::identity(), Vec3::zeros());
    for _ in 0..3 {
        expected = (
            yaw(0.02) * expected.0,
            yaw(0.02) * expected.1 + Vec3::new(0.0, 0.0, -1.0),
        );
    }
    assert!((r3 - expected.0).norm() < 1e-12 && (t3 - expected.1).norm() < 1e-12);
    assert!((r1 - yaw(0.02)).norm() < 1e-12 && (t1 - Vec3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
    // tracked there: the velocity is per frame, the gap closed
    let meta = FrameMeta {
        index: 13,
        stamp: 1.3,
    };
    let fit = tracking::PoseFit {
        t_cam_world: Pose::new(expected.0, expected.1),
        inlier: Vec::new(),
    };
    tr.update_motion_model(&meta, &fit);
    let Pose { r: rv, t: tv } = tr.velocity.unwrap();
    assert!((rv - yaw(0.02)).norm() < 1e-9, "{rv}");
    assert!((tv - Vec3::new(0.0, 0.0, -1.0)).norm() < 0.02, "{tv}");
    assert_eq!(tr.unseen, 0);
}

/// A reference that too few matches reach (fewer than `min_init_landmarks`) can never
/// initialise: the frame becomes the new reference instead of the tracker waiting on the
/// old one for the rest of the run (as ORB on KITTI 03 did after a failed attempt in
/// the turn).
#[test]
fn initialisation_restarts_when_the_reference_loses_its_matches() {
    let mut tr = Tracker::new(calibration(620.0, 188.0), TrackerConfig::default());
    let meta = |index| FrameMeta {
        index,
        stamp: index as f64 * 0.1,
    };
    tr.step(meta(0), features(400, 0.0), None);
    assert_eq!(tr.reference().map(|r| r.0), Some(0));
    // many matches, too little parallax: keep waiting on frame 0
    let matches = |n: usize| Matches {
        pairs: (0..n).map(|i| (i, i)).collect(),
        scores: vec![1.0; n],
    };
    let many = matches(300);
    let out = tr.step(meta(1), features(400, 2.0), Some(&many));
    assert_eq!(out.state, TrackingState::Initializing);
    assert_eq!(tr.reference().map(|r| r.0), Some(0));
    // fewer matches than an initialisation needs: frame 2 becomes the reference
    let few = matches(50);
    let out = tr.step(meta(2), features(400, 40.0), Some(&few));
    assert_eq!(out.state, TrackingState::Initializing);
    assert!(out.t_world_cam.is_none());
    assert_eq!(tr.reference().map(|r| r.0), Some(2));
    // a blind frame (no keypoints, so no matches) says nothing about the reference: it
    // stays
    let none = matches(0);
    let out = tr.step(meta(3), features(0, 0.0), Some(&none));
    assert_eq!(out.state, TrackingState::Initializing);
    assert_eq!(tr.reference().map(|r| r.0), Some(2));
    // a frame with keypoints that do not reach the reference does replace it
    tr.step(meta(4), features(400, 0.0), Some(&none));
    assert_eq!(tr.reference().map(|r| r.0), Some(4));
}
