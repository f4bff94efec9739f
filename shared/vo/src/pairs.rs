//! Two-view checks of a front end's matches.

use supermvo_dataset::Calibration;
use supermvo_geometry::essential::{find_essential, RansacConfig};
use supermvo_geometry::Vec3;
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
    let norm = |p: &[f32; 2]| {
        Vec3::new(
            (p[0] as f64 - k.cx) / k.fx,
            (p[1] as f64 - k.cy) / k.fy,
            1.0,
        )
    };
    let x1: Vec<Vec3> = m
        .pairs
        .iter()
        .map(|&(i, _)| norm(&a.keypoints[i]))
        .collect();
    let x2: Vec<Vec3> = m
        .pairs
        .iter()
        .map(|&(_, j)| norm(&b.keypoints[j]))
        .collect();
    find_essential(&x1, &x2, 0.5 * (k.fx + k.fy), ransac).map_or(0, |e| e.inlier_count())
}
