//! The projection Jacobian: the reprojection residual of a world point in a camera, in
//! normalised image units, with its derivatives for the camera pose and the point. PnP
//! refinement and bundle adjustment both linearise through it.
//!
//! Conventions: the camera pose is `T_cam_world = (r, t)` (`p_cam = r p_world + t`), perturbed
//! on the left, `T <- Exp(delta) T` with `delta = (omega, v)`; a bearing is a normalised ray
//! `(x, y, 1)` (any positive multiple of it).

use crate::so3::skew;
use nalgebra::{Matrix2x3, Matrix3, SMatrix, Vector2, Vector3};

/// Points closer to the camera plane than this (world units along the optical axis) have no
/// residual: they are behind the camera or at its centre.
pub const MIN_DEPTH: f64 = 1e-6;

/// A residual linearised at the current estimate.
#[derive(Debug, Clone, Copy)]
pub struct Reprojection {
    /// Projected minus observed normalised coordinates.
    pub residual: Vector2<f64>,
    /// Derivative for the left pose perturbation `(omega, v)`.
    pub d_pose: SMatrix<f64, 2, 6>,
    /// Derivative for the world point.
    pub d_point: Matrix2x3<f64>,
}

/// Residual only (for costs): `None` for a point not in front of the camera.
pub fn reprojection_residual(
    r_cam_world: &Matrix3<f64>,
    t_cam_world: &Vector3<f64>,
    p_world: &Vector3<f64>,
    bearing: &Vector3<f64>,
) -> Option<Vector2<f64>> {
    let q = r_cam_world * p_world + t_cam_world;
    (q.z > MIN_DEPTH).then(|| {
        Vector2::new(
            q.x / q.z - bearing.x / bearing.z,
            q.y / q.z - bearing.y / bearing.z,
        )
    })
}

/// Residual and Jacobians: `None` for a point not in front of the camera.
pub fn reprojection(
    r_cam_world: &Matrix3<f64>,
    t_cam_world: &Vector3<f64>,
    p_world: &Vector3<f64>,
    bearing: &Vector3<f64>,
) -> Option<Reprojection> {
    let q = r_cam_world * p_world + t_cam_world;
    if q.z <= MIN_DEPTH {
        return None;
    }
    let residual = Vector2::new(
        q.x / q.z - bearing.x / bearing.z,
        q.y / q.z - bearing.y / bearing.z,
    );
    let (iz, iz2) = (1.0 / q.z, 1.0 / (q.z * q.z));
    let d_projection = Matrix2x3::new(iz, 0.0, -q.x * iz2, 0.0, iz, -q.y * iz2);
    // d q / d (omega, v) = [-[q]x | I]
    let mut dq = SMatrix::<f64, 3, 6>::zeros();
    dq.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-skew(&q)));
    dq.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&Matrix3::identity());
    Some(Reprojection {
        residual,
        d_pose: d_projection * dq,
        d_point: d_projection * r_cam_world,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::so3::so3_exp;

    fn numeric(
        f: impl Fn(&SMatrix<f64, 9, 1>) -> Vector2<f64>,
        at: &SMatrix<f64, 9, 1>,
    ) -> SMatrix<f64, 2, 9> {
        let h = 1e-7;
        SMatrix::<f64, 2, 9>::from_fn(|row, col| {
            let (mut a, mut b) = (*at, *at);
            a[col] += h;
            b[col] -= h;
            (f(&a)[row] - f(&b)[row]) / (2.0 * h)
        })
    }

    #[test]
    fn jacobians_match_central_differences() {
        let r = so3_exp(&Vector3::new(0.1, -0.2, 0.05));
        let t = Vector3::new(0.3, -0.1, 0.5);
        let p = Vector3::new(1.0, -0.5, 6.0);
        let bearing = Vector3::new(0.12, -0.04, 1.0);
        let lin = reprojection(&r, &t, &p, &bearing).unwrap();
        // x = (omega, v, point)
        let f = |x: &SMatrix<f64, 9, 1>| {
            let dr = so3_exp(&Vector3::new(x[0], x[1], x[2]));
            let (r2, t2) = (dr * r, dr * t + Vector3::new(x[3], x[4], x[5]));
            let p2 = p + Vector3::new(x[6], x[7], x[8]);
            reprojection_residual(&r2, &t2, &p2, &bearing).unwrap()
        };
        let j = numeric(f, &SMatrix::zeros());
        assert!((j.fixed_view::<2, 6>(0, 0) - lin.d_pose).amax() < 1e-6);
        assert!((j.fixed_view::<2, 3>(0, 6) - lin.d_point).amax() < 1e-6);
        assert_eq!(
            lin.residual,
            reprojection_residual(&r, &t, &p, &bearing).unwrap()
        );
    }

    #[test]
    fn a_point_behind_the_camera_has_no_residual() {
        let (r, t) = (Matrix3::identity(), Vector3::zeros());
        let p = Vector3::new(0.0, 0.0, -2.0);
        assert!(reprojection(&r, &t, &p, &Vector3::z()).is_none());
        assert!(reprojection_residual(&r, &t, &p, &Vector3::z()).is_none());
    }
}
