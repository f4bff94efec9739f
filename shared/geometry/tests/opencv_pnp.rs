//! PnP RANSAC against OpenCV's solvePnPRansac on the seeded problems of
//! tests/fixtures/opencv_pnp.json (tools/make_geometry_fixtures.py: KITTI 00 intrinsics,
//! 200 points, 0.5 px Gaussian noise, 25 % planted outliers).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code

use supermvo_geometry::pnp::{solve_pnp_ransac, PnpConfig};
use supermvo_geometry::{rotation_angle, Vec3};

mod common;
use common::{mat, vec3};

#[test]
fn agrees_with_opencv() {
    let fx = common::fixture("opencv_pnp.json");
    let k = mat(&fx["k"]);
    let (f, cx, cy) = (k[(0, 0)], k[(0, 2)], k[(1, 2)]);
    let cfg = PnpConfig {
        threshold_px: fx["threshold_px"].as_f64().unwrap(),
        confidence: fx["confidence"].as_f64().unwrap(),
        ..Default::default()
    };
    let (mut ours_r, mut cv_r_sum, mut ours_t, mut cv_t_sum) = (0.0, 0.0, 0.0, 0.0);
    let cases = fx["cases"].as_array().unwrap();
    for case in cases {
        let seed = &case["seed"];
        let pw: Vec<Vec3> = case["points_world"]
            .as_array()
            .unwrap()
            .iter()
            .map(vec3)
            .collect();
        let px: Vec<Vec3> = case["pixels"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| {
                Vec3::new(
                    (p[0].as_f64().unwrap() - cx) / f,
                    (p[1].as_f64().unwrap() - cy) / f,
                    1.0,
                )
            })
            .collect();
        let est = solve_pnp_ransac(&pw, &px, f, &cfg).unwrap();
        let (tr, tt) = (mat(&case["true_r"]), vec3(&case["true_t"]));
        let (cr, ct) = (mat(&case["cv_r"]), vec3(&case["cv_t"]));
        let (est_r, est_t) = (est.t_cam_world.r, est.t_cam_world.t);
        let r_err = rotation_angle(&(est_r.transpose() * tr)).to_degrees();
        let cv_r_err = rotation_angle(&(cr.transpose() * tr)).to_degrees();
        let (t_err, cv_t_err) = ((est_t - tt).norm(), (ct - tt).norm());
        let planted = case["outliers"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|i| est.inliers[i.as_u64().unwrap() as usize])
            .count();
        let cv_inl = case["cv_inliers"].as_u64().unwrap() as usize;
        eprintln!(
            "seed {seed}: inliers {} (OpenCV {cv_inl}), planted outliers in {planted}; rotation error {r_err:.4} deg (OpenCV {cv_r_err:.4}); translation error {t_err:.4} (OpenCV {cv_t_err:.4})",
            est.inlier_count()
        );
        assert!(
            est.inlier_count() >= cv_inl,
            "seed {seed}: {} inliers, OpenCV {cv_inl}",
            est.inlier_count()
        );
        assert!(
            planted <= 3,
            "seed {seed}: {planted} planted outliers accepted"
        );
        ours_r += r_err;
        cv_r_sum += cv_r_err;
        ours_t += t_err;
        cv_t_sum += cv_t_err;
    }
    let n = cases.len() as f64;
    eprintln!("mean rotation error ours {:.4} deg, OpenCV {:.4} deg; translation ours {:.4}, OpenCV {:.4}", ours_r / n, cv_r_sum / n, ours_t / n, cv_t_sum / n);
    assert!(
        ours_r <= cv_r_sum,
        "rotation less accurate than OpenCV on average"
    );
    assert!(
        ours_t <= cv_t_sum,
        "translation less accurate than OpenCV on average"
    );
}
