//! Two-view checks of a front end's matches.

use crate::tracker::{bearing, Lens};
use supermvo_dataset::Calibration;
use supermvo_geometry::essential::{find_essential, RansacConfig};
use supermvo_geometry::{Pose, Vec3};
use supermvo_inference::{Features, Matches};

/// How many of the matches `m` between `a` and `b` are inliers of the essential matrix that
/// 5-point RANSAC (`ransac`) finds under calibration `k`; 0 when it finds none.
pub fn essential_inliers(
    k: &Calibration,
    a: &Features,
    b: &Features,
    m: &Matches,
    ransac: &RansacConfig,
) -> usize {
    let lens = Lens::from(*k);
    let x1: Vec<Vec3> = m
        .pairs
        .iter()
        .map(|&(i, _)| bearing(&lens, &a.keypoints[i]))
        .collect();
    let x2: Vec<Vec3> = m
        .pairs
        .iter()
        .map(|&(_, j)| bearing(&lens, &b.keypoints[j]))
        .collect();
    find_essential(&x1, &x2, 0.5 * (k.fx + k.fy), ransac).map_or(0, |e| e.inlier_count())
}

/// For each match `(i, j)` of `m`, the distance (pixels: normalised image coordinates times
/// the mean focal length) of keypoint `j` of `b` from the epipolar line of keypoint `i` of
/// `a` under the known motion `t_b_a`: the matches' own error, with no estimated pose in it.
/// Empty when the camera did not move.
pub fn epipolar_distances_px(
    k: &Calibration,
    t_b_a: &Pose,
    (a, b): (&Features, &Features),
    m: &Matches,
) -> Vec<f64> {
    if t_b_a.t.norm() < 1e-9 {
        return Vec::new();
    }
    let e = t_b_a.t.cross_matrix() * t_b_a.r;
    let focal = 0.5 * (k.fx + k.fy);
    let lens = Lens::from(*k);
    m.pairs
        .iter()
        .map(|&(i, j)| {
            let line = e * bearing(&lens, &a.keypoints[i]);
            bearing(&lens, &b.keypoints[j]).dot(&line).abs() / line.x.hypot(line.y) * focal
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use supermvo_geometry::Mat3;

    #[test]
    fn a_match_off_its_true_epipolar_line_is_measured_in_pixels() {
        let k = Calibration {
            fx: 700.0,
            fy: 700.0,
            cx: 600.0,
            cy: 180.0,
        };
        // the camera moves 1 m to the right: epipolar lines are the image rows
        let t_b_a = Pose::new(Mat3::identity(), Vec3::new(-1.0, 0.0, 0.0));
        // the point (2, 1, 10) of the first camera is at (740, 250), then at (670, 250)
        let at = |pts: Vec<[f32; 2]>| Features {
            keypoints: pts,
            ..Default::default()
        };
        let a = at(vec![[740.0, 250.0], [740.0, 250.0]]);
        let b = at(vec![[670.0, 250.0], [650.0, 252.0]]);
        let m = Matches {
            pairs: vec![(0, 0), (1, 1)],
            scores: vec![0.9, 0.2],
        };
        let d = epipolar_distances_px(&k, &t_b_a, (&a, &b), &m);
        assert_eq!(d.len(), 2);
        assert!(d[0] < 1e-9, "{d:?}");
        assert!((d[1] - 2.0).abs() < 1e-9, "{d:?}");
        // no motion, no epipolar geometry
        assert!(epipolar_distances_px(&k, &Pose::identity(), (&a, &b), &m).is_empty());
    }
}
