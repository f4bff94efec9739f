//! SO(3) helpers: exp/log, angle of a rotation, Euler angles, orthonormality checks.

use crate::{Mat3, Vec3};
use nalgebra::{Quaternion, Rotation3, UnitQuaternion};

/// A 3x3 matrix that is not a proper rotation within tolerance.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("rotation is not orthonormal: max |R^T R - I| = {max_dev:.3e}, det = {det:.6} (tolerance {tol:.0e})")]
pub struct OrthonormalityError {
    /// Largest absolute entry of `R^T R - I`.
    pub max_dev: f64,
    /// Determinant of R.
    pub det: f64,
    /// Tolerance that was applied.
    pub tol: f64,
}

/// Checks that `r` is a rotation: `R^T R = I` and `det R = 1` within `tol` (absolute).
pub fn check_orthonormal(r: &Mat3, tol: f64) -> Result<(), OrthonormalityError> {
    let dev = r.transpose() * r - Mat3::identity();
    let max_dev = dev.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let det = r.determinant();
    if max_dev.is_finite() && max_dev <= tol && (det - 1.0).abs() <= tol {
        Ok(())
    } else {
        Err(OrthonormalityError { max_dev, det, tol })
    }
}

/// Quaternion of a (nearly) orthonormal matrix by the numerically stable branch choice
/// (largest of the trace and the diagonal), normalised, with non-negative scalar part.
fn quaternion_of(r: &Mat3) -> Quaternion<f64> {
    let tr = r.trace();
    let d = [r[(0, 0)], r[(1, 1)], r[(2, 2)]];
    let (mut best, mut best_val) = (3usize, tr);
    for (i, v) in d.iter().enumerate() {
        if *v > best_val {
            best = i;
            best_val = *v;
        }
    }
    // q = [x, y, z, w]
    let mut q = [0.0_f64; 4];
    if best == 3 {
        q[0] = r[(2, 1)] - r[(1, 2)];
        q[1] = r[(0, 2)] - r[(2, 0)];
        q[2] = r[(1, 0)] - r[(0, 1)];
        q[3] = 1.0 + tr;
    } else {
        let i = best;
        let j = (i + 1) % 3;
        let k = (j + 1) % 3;
        q[i] = 1.0 - tr + 2.0 * r[(i, i)];
        q[j] = r[(j, i)] + r[(i, j)];
        q[k] = r[(k, i)] + r[(i, k)];
        q[3] = r[(k, j)] - r[(j, k)];
    }
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let s = if q[3] < 0.0 { -1.0 / n } else { 1.0 / n };
    Quaternion::new(q[3] * s, q[0] * s, q[1] * s, q[2] * s)
}

/// Unit quaternion of a (nearly) orthonormal matrix, non-negative scalar part.
pub(crate) fn unit_quaternion_of(r: &Mat3) -> UnitQuaternion<f64> {
    UnitQuaternion::new_unchecked(quaternion_of(r))
}

/// Rotation vector (axis * angle, radians) of a rotation matrix: the SO(3) logarithm.
///
/// Computed through the quaternion, which keeps full relative precision for small
/// angles where `acos((tr R - 1) / 2)` loses half the digits.
pub fn so3_log(r: &Mat3) -> Vec3 {
    let q = quaternion_of(r);
    let v = q.imag();
    let vn = v.norm();
    let angle = 2.0 * vn.atan2(q.w);
    if angle <= 1e-3 {
        // Taylor expansion of angle / sin(angle / 2).
        let a2 = angle * angle;
        let scale = 2.0 + a2 / 12.0 + 7.0 * a2 * a2 / 2880.0;
        v * scale
    } else {
        v * (angle / (angle / 2.0).sin())
    }
}

/// Rotation angle in radians of a rotation matrix, in [0, pi].
pub fn rotation_angle(r: &Mat3) -> f64 {
    so3_log(r).norm()
}

/// SO(3) exponential: rotation matrix of a rotation vector.
pub fn so3_exp(w: &Vec3) -> Mat3 {
    Rotation3::new(*w).into_inner()
}

/// Skew-symmetric matrix `[v]x` with `[v]x w = v x w`.
pub fn skew(v: &Vec3) -> Mat3 {
    Mat3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Roll, pitch, yaw in radians of a rotation, static x-y-z convention
/// (`R = Rz(yaw) * Ry(pitch) * Rx(roll)`), as evo plots them.
pub fn euler_rpy(q: &UnitQuaternion<f64>) -> (f64, f64, f64) {
    q.euler_angles()
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn log_inverts_exp(angle in 0.0f64..std::f64::consts::PI - 1e-6, polar in 0.0f64..std::f64::consts::PI, azimuth in -std::f64::consts::PI..std::f64::consts::PI) {
            // every rotation vector inside the ball of radius pi, without rejection sampling
            let w = angle * Vec3::new(polar.sin() * azimuth.cos(), polar.sin() * azimuth.sin(), polar.cos());
            let r = so3_exp(&w);
            let back = so3_log(&r);
            prop_assert!((back - w).norm() < 1e-9);
        }

        #[test]
        fn tiny_angles_keep_relative_precision(e in -12.0f64..-4.0) {
            let a = 10f64.powf(e);
            let w = Vec3::new(a, -0.5 * a, 0.25 * a);
            let ang = rotation_angle(&so3_exp(&w));
            prop_assert!(((ang - w.norm()) / w.norm()).abs() < 1e-9);
        }
    }

    #[test]
    fn angle_of_half_turn() {
        let r = so3_exp(&Vec3::new(0.0, std::f64::consts::PI, 0.0));
        assert_relative_eq!(rotation_angle(&r), std::f64::consts::PI, epsilon = 1e-12);
    }

    #[test]
    fn orthonormality_check_rejects_scaled_matrix() {
        assert!(check_orthonormal(&Mat3::identity(), 1e-6).is_ok());
        assert!(check_orthonormal(&(Mat3::identity() * 1.01), 1e-6).is_err());
        let mut reflect = Mat3::identity();
        reflect[(2, 2)] = -1.0;
        assert!(check_orthonormal(&reflect, 1e-6).is_err());
        assert!(check_orthonormal(&(Mat3::identity() * f64::NAN), 1e-6).is_err());
    }
}
