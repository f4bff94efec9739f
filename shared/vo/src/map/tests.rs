#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
use super::*;
use supermvo_geometry::essential::triangulate_checked;
use supermvo_geometry::Mat3;

const F: f64 = 700.0;

/// `T_cam_world` of an unrotated camera centred at `c`.
fn at(c: Vec3) -> Pose {
    Pose::new(Mat3::identity(), -c)
}

/// Bearing of world point `p` seen from the camera centred at `c`, moved by `(du, dv)` px.
fn seen(p: &Vec3, c: &Vec3, (du, dv): (f64, f64)) -> Vec3 {
    let q = p - c;
    Vec3::new(q.x / q.z + du / F, q.y / q.z + dv / F, 1.0)
}

/// A tracker with keyframes 0 and 1 (0.5 m apart sideways, 1.4 degrees of parallax at
/// 20 m) holding one landmark triangulated from them with 0.7 px of noise in keyframe 1,
/// and keyframe 2 another 2.5 m on; returns it, the landmark id and the true point.
fn short_baseline_landmark() -> (Map, usize, Vec3) {
    let mut tr = Map::new(F);
    let centres = [
        Vec3::zeros(),
        Vec3::new(0.5, 0.0, 0.0),
        Vec3::new(3.0, 0.0, 0.0),
    ];
    for c in centres {
        tr.new_keyframe_id(at(c), 0);
    }
    let truth = Vec3::new(1.0, 0.5, 20.0);
    let obs = vec![
        (0, seen(&truth, &centres[0], (0.0, 0.0))),
        (1, seen(&truth, &centres[1], (0.7, 0.0))),
    ];
    let views: Vec<_> = obs
        .iter()
        .map(|(k, b)| (tr.keyframe_poses[*k].r, tr.keyframe_poses[*k].t, *b))
        .collect();
    let p = triangulate_checked(&views, 2.0 / F).unwrap().point;
    let id = tr.add_landmark(p, obs, &[0.0; 4], LandmarkSource::Matcher);
    (tr, id, truth)
}

fn reprojection_px(tr: &Map, id: usize, kf: usize, b: &Vec3) -> f64 {
    let t_cam_world = tr.keyframe_poses[kf];
    supermvo_geometry::pnp::reprojection_sq(&t_cam_world.r, &t_cam_world.t, &tr.landmarks[&id].p, b)
        .sqrt()
        * F
}

/// Two keyframes' weight is the number of landmarks both observe; keyframes before the
/// current map segment do not count.
#[test]
fn covisibility_counts_the_landmarks_two_keyframes_share() {
    let mut map = Map::new(F);
    for i in 0..4 {
        map.new_keyframe_id(at(Vec3::new(i as f64, 0.0, 0.0)), i);
    }
    let b = Vec3::new(0.0, 0.0, 1.0);
    let p = Vec3::new(0.0, 0.0, 10.0);
    // keyframe 3 shares three landmarks with 2, two with 1, one with 0
    map.add_landmark(
        p,
        vec![(0, b), (1, b), (2, b), (3, b)],
        &[0.0],
        LandmarkSource::Matcher,
    );
    map.add_landmark(
        p,
        vec![(1, b), (2, b), (3, b)],
        &[0.0],
        LandmarkSource::Matcher,
    );
    map.add_landmark(p, vec![(2, b), (3, b)], &[0.0], LandmarkSource::Matcher);
    map.add_landmark(p, vec![(0, b), (1, b)], &[0.0], LandmarkSource::Matcher);
    assert_eq!(map.covisible(3), vec![(2, 3), (1, 2), (0, 1)]);
    assert_eq!(map.covisible(0), vec![(1, 2), (3, 1), (2, 1)]);
    map.segment_start = 1;
    assert_eq!(map.covisible(3), vec![(2, 3), (1, 2)]);
}

/// The trace of a new landmark carries what `tools/landmark_depth_check.py` compares
/// with the ground truth: the frames, the observations and the scale-free depth.
#[test]
fn a_new_landmark_is_traced_with_its_depth_over_the_baseline() {
    #[derive(Clone, Default)]
    struct Buffer(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);
    impl std::io::Write for Buffer {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    let buffer = Buffer::default();
    let writer = buffer.clone();
    let subscriber = tracing_subscriber::fmt()
        .with_env_filter("supermvo::landmarks=trace")
        .with_ansi(false)
        .with_writer(move || writer.clone())
        .finish();
    tracing::subscriber::with_default(subscriber, || {
        let mut map = Map::new(F);
        // a map forgotten (a restored tracker) leaves no frames behind its ids
        map.new_keyframe_id(at(Vec3::zeros()), 3);
        map.forget_keyframes();
        map.new_keyframe_id(at(Vec3::zeros()), 10);
        map.new_keyframe_id(at(Vec3::new(0.0, 0.0, 2.0)), 14);
        let p = Vec3::new(3.0, -1.0, 20.0);
        let obs = vec![
            (0, seen(&p, &Vec3::zeros(), (0.0, 0.0))),
            (1, seen(&p, &Vec3::new(0.0, 0.0, 2.0), (0.0, 0.0))),
        ];
        map.add_landmark(p, obs, &[0.0], LandmarkSource::Covisible);
    });
    let text = String::from_utf8(buffer.0.lock().unwrap().clone()).unwrap();
    let field = |name: &str| {
        text.split_whitespace()
            .find_map(|w| w.strip_prefix(&format!("{name}=")))
            .unwrap_or_else(|| panic!("{name} missing in {text}"))
            .to_string()
    };
    assert_eq!(field("source"), "\"covisible\"");
    assert_eq!(
        (field("first_frame"), field("last_frame")),
        ("10".into(), "14".into())
    );
    assert_eq!(field("observations"), "2");
    // 18 m deep in the second camera, 2 m from the first
    let ratio: f64 = field("depth_over_baseline").parse().unwrap();
    assert!((ratio - 9.0).abs() < 1e-9, "{ratio}");
    let x: f64 = field("last_x").parse().unwrap();
    assert!((x - 3.0 / 18.0).abs() < 1e-9, "{x}");
}

#[test]
fn a_wider_baseline_corrects_a_landmark_that_tracking_rejected() {
    let (mut tr, id, truth) = short_baseline_landmark();
    let b = seen(&truth, &Vec3::new(3.0, 0.0, 0.0), (0.0, 0.0));
    let before = (tr.landmarks[&id].p - truth).norm();
    // the short baseline's depth error puts the landmark beyond the 2 px PnP threshold
    // from keyframe 2, within the 6 px re-observation gate
    let miss = reprojection_px(&tr, id, 2, &b);
    assert!(miss > 2.0 && miss < 6.0, "reprojection {miss} px");
    assert!(tr.reobserve_landmark(id, 2, b, &[1.0; 4]));
    let after = (tr.landmarks[&id].p - truth).norm();
    assert!(after < 0.25 * before, "error {before} m -> {after} m");
    assert_eq!(tr.landmarks[&id].obs.len(), 3);
    assert_eq!(tr.landmarks[&id].desc, vec![1.0; 4]);
}

#[test]
fn a_match_inconsistent_with_the_other_views_is_not_added() {
    let (mut tr, id, truth) = short_baseline_landmark();
    let p = tr.landmarks[&id].p;
    // 5 px off across the epipolar line: no point fits all three views within 2 px
    let b = seen(&truth, &Vec3::new(3.0, 0.0, 0.0), (0.0, 5.0));
    assert!(!tr.reobserve_landmark(id, 2, b, &[1.0; 4]));
    assert_eq!(tr.landmarks[&id].p, p);
    assert_eq!(tr.landmarks[&id].obs.len(), 2);
    // an unknown keyframe or landmark changes nothing either
    assert!(!tr.reobserve_landmark(id, 7, b, &[1.0; 4]));
    assert!(!tr.reobserve_landmark(id + 1, 2, b, &[1.0; 4]));
}
