//! 5-point RANSAC and pose recovery against OpenCV's findEssentialMat + recoverPose on the
//! seeded problems of tests/fixtures/opencv_essential.json (tools/make_geometry_fixtures.py:
//! KITTI 00 intrinsics, 300 points, 0.5 px Gaussian noise, 20 % planted outliers).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code

use serde_json::Value;
use supermvo_geometry::essential::{find_essential, recover_pose, RansacConfig};
use supermvo_geometry::{rotation_angle, Vec3};

mod common;
use common::{mat, vec3};

#[test]
fn agrees_with_opencv_and_is_at_least_as_accurate() {
    let fx = common::fixture("opencv_essential.json");
    let k = mat(&fx["k"]);
    let (fxp, fyp, cx, cy) = (k[(0, 0)], k[(1, 1)], k[(0, 2)], k[(1, 2)]);
    let norm = |p: &Value| {
        Vec3::new(
            (p[0].as_f64().unwrap() - cx) / fxp,
            (p[1].as_f64().unwrap() - cy) / fyp,
            1.0,
        )
    };
    let cfg = RansacConfig {
        threshold_px: fx["threshold_px"].as_f64().unwrap(),
        confidence: fx["confidence"].as_f64().unwrap(),
        ..Default::default()
    };
    let (mut ours_sum, mut cv_sum, mut ours_t_sum, mut cv_t_sum) = (0.0, 0.0, 0.0, 0.0);
    let cases = fx["cases"].as_array().unwrap();
    for case in cases {
        let seed = &case["seed"];
        let x1: Vec<Vec3> = case["pts1"].as_array().unwrap().iter().map(norm).collect();
        let x2: Vec<Vec3> = case["pts2"].as_array().unwrap().iter().map(norm).collect();
        let est = find_essential(&x1, &x2, 0.5 * (fxp + fyp), &cfg).unwrap();
        let (r, t, good) = recover_pose(&est.e, &x1, &x2, &est.inliers, 50.0);
        let (cv_r, cv_t) = (mat(&case["cv_r"]), vec3(&case["cv_t"]).normalize());
        let (true_r, true_t) = (mat(&case["true_r"]), vec3(&case["true_t"]));
        let cv_inl = case["cv_inliers"].as_u64().unwrap() as usize;
        let planted_in = case["outliers"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|i| est.inliers[i.as_u64().unwrap() as usize])
            .count();
        let ours_err = rotation_angle(&(r.transpose() * true_r)).to_degrees();
        let cv_err = rotation_angle(&(cv_r.transpose() * true_r)).to_degrees();
        let vs_cv = rotation_angle(&(r.transpose() * cv_r)).to_degrees();
        eprintln!(
            "seed {seed}: inliers {} (OpenCV {cv_inl}), planted outliers accepted {planted_in}, rotation error {ours_err:.3} deg (OpenCV {cv_err:.3}), vs OpenCV {vs_cv:.3} deg",
            est.inlier_count()
        );
        assert!(
            est.inlier_count() >= cv_inl,
            "seed {seed}: {} inliers, OpenCV {cv_inl}",
            est.inlier_count()
        );
        assert!(
            planted_in <= 6,
            "seed {seed}: {planted_in} of 60 planted outliers accepted"
        );
        assert!(
            good as f64 >= 0.9 * est.inlier_count() as f64,
            "seed {seed}: only {good} points in front of both cameras"
        );
        assert!(
            ours_err < 0.15,
            "seed {seed}: rotation error {ours_err} deg"
        );
        assert!(
            t.dot(&true_t) > 0.999,
            "seed {seed}: translation direction {t} vs truth {true_t}"
        );
        // Where both land in the same basin the poses agree closely; OpenCV's sample can also
        // end in a worse basin (seed 1: its translation fits the true inliers with twice the
        // Sampson error of the truth), so each is judged against the truth.
        assert!(
            vs_cv < 0.3,
            "seed {seed}: rotation differs from OpenCV's by {vs_cv} deg"
        );
        let t_err = t.dot(&true_t).clamp(-1.0, 1.0).acos().to_degrees();
        let cv_t_err = cv_t.dot(&true_t).clamp(-1.0, 1.0).acos().to_degrees();
        eprintln!("    translation direction error {t_err:.3} deg (OpenCV {cv_t_err:.3})");
        ours_sum += ours_err;
        cv_sum += cv_err;
        ours_t_sum += t_err;
        cv_t_sum += cv_t_err;
    }
    let n = cases.len() as f64;
    eprintln!(
        "mean rotation error: ours {:.4} deg, OpenCV {:.4} deg",
        ours_sum / n,
        cv_sum / n
    );
    eprintln!(
        "mean translation direction error: ours {:.4} deg, OpenCV {:.4} deg",
        ours_t_sum / n,
        cv_t_sum / n
    );
    assert!(
        ours_sum <= cv_sum,
        "rotation on average less accurate than OpenCV"
    );
    assert!(
        ours_t_sum <= cv_t_sum,
        "translation on average less accurate than OpenCV"
    );
}
