//! The KITTI odometry benchmark metric (Geiger et al., 2012; `devkit/cpp/evaluate_odometry.cpp`).
//!
//! Definition, as in the devkit:
//! * `dist[i]` is the path length of the *ground truth* up to frame `i`.
//! * For every first frame `f = 0, 10, 20, ...` and every length `L` in 100, 200, ..., 800 m,
//!   the last frame `l` is the first frame with `dist[l] > dist[f] + L`; segments that run past
//!   the end are skipped.
//! * The segment error is `E = (P_f^-1 P_l)^-1 (Q_f^-1 Q_l)` (P estimate, Q ground truth);
//!   translation error `|t(E)| / L`, rotation error `acos(clamp((tr R(E) - 1) / 2)) / L`.
//! * The reported numbers average over all segments of all lengths:
//!   `t_err` in percent, `r_err` in degrees per 100 m.

use serde::{Deserialize, Serialize};
use supermvo_geometry::Pose;

/// The devkit's segment lengths in metres.
pub const KITTI_LENGTHS: [f64; 8] = [100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0];
/// The devkit's step between first frames.
pub const KITTI_STEP: usize = 10;

/// Averages for one segment length.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KittiLengthError {
    /// Segment length, metres.
    pub length_m: f64,
    /// Number of segments of that length.
    pub segments: usize,
    /// Mean translational error, percent.
    pub t_err_pct: f64,
    /// Mean rotational error, degrees per 100 m.
    pub r_err_deg_per_100m: f64,
}

/// The KITTI odometry metric of one trajectory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KittiMetric {
    /// Mean translational error over all segments, percent.
    pub t_err_pct: f64,
    /// Mean rotational error over all segments, degrees per 100 m.
    pub r_err_deg_per_100m: f64,
    /// Number of segments averaged.
    pub segments: usize,
    /// Breakdown by segment length (lengths with no segment are omitted).
    pub per_length: Vec<KittiLengthError>,
}

fn to_m4(p: &Pose) -> nalgebra::Matrix4<f64> {
    p.to_matrix()
}

fn inv(m: &nalgebra::Matrix4<f64>) -> nalgebra::Matrix4<f64> {
    m.try_inverse().unwrap_or_else(nalgebra::Matrix4::identity)
}

/// Computes the metric with the devkit's lengths and step. `None` when the ground truth is
/// shorter than the shortest segment length (no segment can be formed).
pub fn kitti_metric(ground_truth: &[Pose], estimate: &[Pose]) -> Option<KittiMetric> {
    kitti_metric_with(ground_truth, estimate, &KITTI_LENGTHS, KITTI_STEP)
}

/// The metric with custom segment lengths and first-frame step (for short clips).
pub fn kitti_metric_with(
    ground_truth: &[Pose],
    estimate: &[Pose],
    lengths: &[f64],
    step: usize,
) -> Option<KittiMetric> {
    let n = ground_truth.len().min(estimate.len());
    if n < 2 || step == 0 {
        return None;
    }
    let mut dist = Vec::with_capacity(n);
    dist.push(0.0);
    for i in 1..n {
        dist.push(dist[i - 1] + (ground_truth[i].t - ground_truth[i - 1].t).norm());
    }
    let gt: Vec<_> = ground_truth[..n].iter().map(to_m4).collect();
    let est: Vec<_> = estimate[..n].iter().map(to_m4).collect();
    let gt_inv: Vec<_> = gt.iter().map(inv).collect();
    let est_inv: Vec<_> = est.iter().map(inv).collect();
    let mut per: Vec<(usize, f64, f64)> = vec![(0, 0.0, 0.0); lengths.len()];
    for first in (0..n).step_by(step) {
        for (li, &len) in lengths.iter().enumerate() {
            let Some(last) = (first..n).find(|&i| dist[i] > dist[first] + len) else {
                continue;
            };
            let delta_gt = gt_inv[first] * gt[last];
            let delta_est = est_inv[first] * est[last];
            let e = inv(&delta_est) * delta_gt;
            let d = 0.5 * (e[(0, 0)] + e[(1, 1)] + e[(2, 2)] - 1.0);
            let r_err = d.clamp(-1.0, 1.0).acos();
            let t_err = (e[(0, 3)].powi(2) + e[(1, 3)].powi(2) + e[(2, 3)].powi(2)).sqrt();
            per[li].0 += 1;
            per[li].1 += t_err / len;
            per[li].2 += r_err / len;
        }
    }
    let segments: usize = per.iter().map(|p| p.0).sum();
    if segments == 0 {
        return None;
    }
    let t_sum: f64 = per.iter().map(|p| p.1).sum();
    let r_sum: f64 = per.iter().map(|p| p.2).sum();
    let per_length = lengths
        .iter()
        .zip(&per)
        .filter(|(_, p)| p.0 > 0)
        .map(|(&len, p)| KittiLengthError {
            length_m: len,
            segments: p.0,
            t_err_pct: 100.0 * p.1 / p.0 as f64,
            r_err_deg_per_100m: 100.0 * (p.2 / p.0 as f64).to_degrees(),
        })
        .collect();
    Some(KittiMetric {
        t_err_pct: 100.0 * t_sum / segments as f64,
        r_err_deg_per_100m: 100.0 * (r_sum / segments as f64).to_degrees(),
        segments,
        per_length,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use supermvo_geometry::{so3_exp, Mat3, Vec3};

    fn straight(n: usize, step: f64) -> Vec<Pose> {
        (0..n)
            .map(|i| Pose::new(Mat3::identity(), Vec3::new(0.0, 0.0, i as f64 * step)))
            .collect()
    }

    #[test]
    fn straight_line_with_scale_error() {
        // 1 m per frame for 1000 m; the estimate travels 1.02 m per frame, so the translation
        // error of a segment is 2 % of the distance it covers. As in the devkit, a segment of
        // nominal length L ends at the first frame *beyond* L (here L + 1 m) and its error is
        // divided by L: each contributes 0.02 * (L + 1) / L.
        let gt = straight(1001, 1.0);
        let est = straight(1001, 1.02);
        let m = kitti_metric(&gt, &est).unwrap();
        let (mut sum, mut count) = (0.0, 0usize);
        for &l in &KITTI_LENGTHS {
            // segment (f, L) exists when some frame has dist > f + L, i.e. f + L + 1 <= 1000
            let starts = (0..=1000)
                .step_by(10)
                .filter(|&f| (f as f64) + l < 1000.0)
                .count();
            for _ in 0..starts {
                sum += 0.02 * (l + 1.0) / l;
                count += 1;
            }
        }
        assert_eq!(m.segments, count);
        assert_eq!(count, 440);
        assert!(
            (m.t_err_pct - 100.0 * sum / count as f64).abs() < 1e-9,
            "{m:?}"
        );
        assert!(m.r_err_deg_per_100m.abs() < 1e-9);
        assert!((m.per_length[0].t_err_pct - 2.02).abs() < 1e-9);
    }

    #[test]
    fn constant_yaw_drift() {
        // Straight ground truth along z; the estimate yaws by a constant 0.001 rad per metre
        // travelled about the camera's y axis. A segment of length L has rotation error
        // 0.001 * (L + 1) rad over L metres (the segment ends one frame past L).
        let gt = straight(901, 1.0);
        let yaw_rate = 0.001;
        let mut est = vec![Pose::identity()];
        for _ in 1..901 {
            let prev = est[est.len() - 1];
            let step = Pose::new(
                so3_exp(&Vec3::new(0.0, yaw_rate, 0.0)),
                Vec3::new(0.0, 0.0, 1.0),
            );
            est.push(prev.compose(&step));
        }
        let m = kitti_metric(&gt, &est).unwrap();
        let (mut sum, mut count) = (0.0, 0usize);
        for &l in &KITTI_LENGTHS {
            for f in (0..=900).step_by(10) {
                if (f as f64) + l < 900.0 {
                    sum += yaw_rate * (l + 1.0) / l;
                    count += 1;
                }
            }
        }
        let expected = 100.0 * (sum / count as f64).to_degrees();
        assert_eq!(m.segments, count);
        assert!(
            (m.r_err_deg_per_100m - expected).abs() < 1e-6 * expected,
            "{} vs {expected}",
            m.r_err_deg_per_100m
        );
        assert!(m.t_err_pct > 0.0);
    }

    #[test]
    fn too_short_for_any_segment() {
        assert!(kitti_metric(&straight(50, 1.0), &straight(50, 1.0)).is_none());
    }
}
