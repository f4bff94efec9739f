//! Least-squares similarity between two point sets (Umeyama 1991).

use crate::{Mat3, Sim3, Vec3};
use serde::{Deserialize, Serialize};

/// Which part of a similarity to estimate when aligning trajectories.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum AlignmentKind {
    /// No alignment.
    #[default]
    None,
    /// Rotation and translation.
    Se3,
    /// Rotation, translation and scale.
    Sim3,
    /// Scale alone (rotation and translation of the estimate are kept).
    Scale,
}

/// Why an alignment could not be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum UmeyamaError {
    /// The two point sets differ in length.
    #[error("point sets differ in length: {0} vs {1}")]
    LengthMismatch(usize, usize),
    /// Too few points, or all points (nearly) collinear / coincident.
    #[error(
        "degenerate point set ({0} points): the covariance has rank < 2, alignment is not possible"
    )]
    Degenerate(usize),
}

/// Finds the similarity `T` minimising `sum |y_i - T(x_i)|^2` (Umeyama, PAMI 1991,
/// eqs. 34-43). With `with_scale == false` the scale is fixed to 1.
pub fn umeyama(x: &[Vec3], y: &[Vec3], with_scale: bool) -> Result<Sim3, UmeyamaError> {
    if x.len() != y.len() {
        return Err(UmeyamaError::LengthMismatch(x.len(), y.len()));
    }
    let n = x.len();
    if n == 0 {
        return Err(UmeyamaError::Degenerate(0));
    }
    let nf = n as f64;
    let mean_x = x.iter().sum::<Vec3>() / nf;
    let mean_y = y.iter().sum::<Vec3>() / nf;
    let mut sigma_x = 0.0;
    let mut cov = Mat3::zeros();
    for (xi, yi) in x.iter().zip(y) {
        let dx = xi - mean_x;
        sigma_x += dx.norm_squared();
        cov += (yi - mean_y) * dx.transpose();
    }
    sigma_x /= nf;
    cov /= nf;
    let svd = cov.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(UmeyamaError::Degenerate(n));
    };
    let d = svd.singular_values;
    let rank = d.iter().filter(|s| **s > f64::EPSILON).count();
    if rank < 2 {
        return Err(UmeyamaError::Degenerate(n));
    }
    let mut s = Mat3::identity();
    if u.determinant() * v_t.determinant() < 0.0 {
        s[(2, 2)] = -1.0;
    }
    let r = u * s * v_t;
    let c = if with_scale {
        (Mat3::from_diagonal(&d) * s).trace() / sigma_x
    } else {
        1.0
    };
    let t = mean_y - r * mean_x * c;
    Ok(Sim3::from_parts(&r, &t, c))
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use nalgebra::UnitQuaternion;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn recovers_known_similarity(roll in -3.0f64..3.0, pitch in -1.5f64..1.5, yaw in -3.0f64..3.0,
                                     tx in -50.0f64..50.0, s in 0.1f64..10.0, seed in 0u64..1000) {
            let truth = Sim3 { rotation: UnitQuaternion::from_euler_angles(roll, pitch, yaw),
                               translation: Vec3::new(tx, -tx * 0.5, 3.0), scale: s };
            // deterministic pseudo-random, non-degenerate point cloud
            let mut state = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let mut next = || { state = state.wrapping_mul(6364136223846793005).wrapping_add(1); ((state >> 11) as f64) / ((1u64 << 53) as f64) - 0.5 };
            let x: Vec<Vec3> = (0..20).map(|_| Vec3::new(next() * 10.0, next() * 10.0, next() * 10.0)).collect();
            let y: Vec<Vec3> = x.iter().map(|p| truth.transform_point(p)).collect();
            let est = umeyama(&x, &y, true).unwrap();
            prop_assert!((est.scale - s).abs() < 1e-8 * s);
            prop_assert!(est.rotation.angle_to(&truth.rotation) < 1e-8);
            prop_assert!((est.translation - truth.translation).norm() < 1e-6);
        }
    }

    #[test]
    fn collinear_points_are_degenerate() {
        let x: Vec<Vec3> = (0..5).map(|i| Vec3::new(i as f64, 0.0, 0.0)).collect();
        assert!(matches!(
            umeyama(&x, &x, true),
            Err(UmeyamaError::Degenerate(5))
        ));
        assert!(matches!(
            umeyama(&x, &x[..2], true),
            Err(UmeyamaError::LengthMismatch(5, 2))
        ));
    }

    #[test]
    fn rigid_alignment_keeps_unit_scale() {
        let x = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 2.0, 0.0),
            Vec3::new(0.0, 0.0, 3.0),
        ];
        let y: Vec<Vec3> = x.iter().map(|p| p * 2.0).collect();
        let est = umeyama(&x, &y, false).unwrap();
        assert_relative_eq!(est.scale, 1.0);
    }
}
