//! A camera pose refined on its reprojection errors, the pose-only problem of the tracker
//! and of PnP RANSAC, solved by the project's one least-squares driver:
//! - [`refine_pose`]: Levenberg-Marquardt (Marquardt's rule) on the squared errors of
//!   selected inliers;
//! - [`refine_pose_robust`]: iteratively reweighted Gauss-Newton with Huber weights on every
//!   correspondence, those beyond a cutoff left out.
//!
//! Conventions: `T_cam_world = (r, t)`, perturbed on the left; bearings are normalised
//! image coordinates `(x, y, 1)`; thresholds are in normalised units (pixels / focal).

use crate::{Pose, Vec3};
use nalgebra::{SMatrix, SVector};
use supermvo_optim::lm::{minimise, LeastSquares, LmParams};
use supermvo_optim::projection::reprojection;
use supermvo_optim::so3::so3_exp;
use supermvo_optim::Kernel;

type System = (SMatrix<f64, 6, 6>, SVector<f64, 6>);

/// The reprojection errors of world points in one camera.
struct PoseOnly<'a> {
    points_world: &'a [Vec3],
    bearings: &'a [Vec3],
    /// `None`: plain least squares; otherwise a kernel and a cutoff beyond which a
    /// correspondence is left out.
    robust: Option<(Kernel, f64)>,
}

impl LeastSquares for PoseOnly<'_> {
    type State = Pose;
    type System = System;
    type Step = SVector<f64, 6>;

    /// Sum of squared errors, each capped (a point behind the camera counts the cap).
    fn cost(&self, Pose { r, t }: &Pose) -> f64 {
        self.points_world
            .iter()
            .zip(self.bearings)
            .map(|(p, b)| crate::pnp::reprojection_sq(r, t, p, b).min(1e6))
            .sum()
    }

    /// `None` when fewer than six correspondences are left to constrain the pose.
    fn linearize(&mut self, Pose { r, t }: &Pose) -> Option<System> {
        let mut h = SMatrix::<f64, 6, 6>::zeros();
        let mut g = SVector::<f64, 6>::zeros();
        let mut used = 0;
        for (p, b) in self.points_world.iter().zip(self.bearings) {
            let Some(lin) = reprojection(r, t, p, b) else {
                continue;
            };
            let (res, j) = (lin.residual, lin.d_pose);
            match self.robust {
                None => {
                    h += j.transpose() * j;
                    g += j.transpose() * res;
                }
                Some((kernel, cutoff)) => {
                    let e2 = res.norm_squared();
                    if e2.sqrt() >= cutoff {
                        continue;
                    }
                    let w = kernel.weight(e2);
                    h += w * j.transpose() * j;
                    g += w * j.transpose() * res;
                }
            }
            used += 1;
        }
        (self.robust.is_none() || used >= 6).then_some((h, g))
    }

    /// Damped by `lambda diag(H)`.
    fn solve(&mut self, (h, g): &System, lambda: f64) -> Option<SVector<f64, 6>> {
        let mut a = *h;
        for k in 0..6 {
            a[(k, k)] += lambda * (h[(k, k)] + 1e-12);
        }
        a.cholesky().map(|c| c.solve(&(-g)))
    }

    fn retract(&self, Pose { r, t }: &Pose, d: &SVector<f64, 6>) -> Pose {
        let dr = so3_exp(&Vec3::new(d[0], d[1], d[2]));
        Pose::new(dr * r, dr * t + Vec3::new(d[3], d[4], d[5]))
    }

    fn step_norm(&self, d: &SVector<f64, 6>) -> f64 {
        d.norm()
    }
}

/// Levenberg-Marquardt on the squared reprojection errors of the given correspondences,
/// from `t_cam_world`, for at most `iterations` linearisations.
pub fn refine_pose(
    t_cam_world: &Pose,
    points_world: &[Vec3],
    bearings: &[Vec3],
    iterations: usize,
) -> Pose {
    let mut problem = PoseOnly {
        points_world,
        bearings,
        robust: None,
    };
    let params = LmParams::marquardt(1e-6, 1e-12, 8, iterations);
    minimise(&mut problem, *t_cam_world, params).0
}

/// Refines `t_cam_world` on every correspondence under a robust loss, so that the
/// result is a smooth function of the data rather than of which points a threshold happened
/// to select: iteratively reweighted Gauss-Newton with Huber weights (threshold `k`,
/// normalised units) and weight zero beyond `cutoff`.
pub fn refine_pose_robust(
    t_cam_world: &Pose,
    points_world: &[Vec3],
    bearings: &[Vec3],
    (k, cutoff): (f64, f64),
    iterations: usize,
) -> Pose {
    let mut problem = PoseOnly {
        points_world,
        bearings,
        robust: Some((Kernel::Huber(k), cutoff)),
    };
    let params = LmParams::gauss_newton(iterations, 1e-10);
    minimise(&mut problem, *t_cam_world, params).0
}
