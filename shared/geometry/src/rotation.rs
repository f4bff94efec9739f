//! SO(3) helpers: exp/log, angle of a rotation, Euler angles, orthonormality checks.

use crate::Mat3;
use nalgebra::UnitQuaternion;
pub use supermvo_optim::so3::{skew, so3_exp, so3_log};

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

/// Unit quaternion of a (nearly) orthonormal matrix, non-negative scalar part.
pub(crate) fn unit_quaternion_of(r: &Mat3) -> UnitQuaternion<f64> {
    UnitQuaternion::new_unchecked(supermvo_optim::so3::quaternion_of(r))
}

/// Rotation angle in radians of a rotation matrix, in [0, pi].
pub fn rotation_angle(r: &Mat3) -> f64 {
    so3_log(r).norm()
}

/// Roll, pitch, yaw in radians of a rotation, static x-y-z convention
/// (`R = Rz(yaw) * Ry(pitch) * Rx(roll)`), as evo plots them.
pub fn euler_rpy(q: &UnitQuaternion<f64>) -> (f64, f64, f64) {
    q.euler_angles()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Vec3;
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
