//! Poses kept exactly as read: a 3x3 rotation matrix and a translation.
//!
//! Evaluation must reproduce the reference tools bit for bit in spirit, and files such as
//! KITTI's store rotations with 7 significant digits. Projecting those onto unit
//! quaternions would move small rotation errors by ~1e-7 rad; so evaluation works on the
//! matrices as given, inverting by transposition as evo and the KITTI devkit do.

use crate::{Mat3, Se3, Vec3};
use nalgebra::{Matrix4, Quaternion, UnitQuaternion};

/// A rigid pose as a rotation matrix and translation (`p_out = R p_in + t`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Rotation matrix (orthonormal up to the precision of its source).
    pub r: Mat3,
    /// Translation.
    pub t: Vec3,
}

impl Default for Pose {
    fn default() -> Self {
        Self::identity()
    }
}

impl Pose {
    /// The identity pose.
    pub fn identity() -> Self {
        Self {
            r: Mat3::identity(),
            t: Vec3::zeros(),
        }
    }

    /// Pose from a rotation matrix and translation.
    pub fn new(r: Mat3, t: Vec3) -> Self {
        Self { r, t }
    }

    /// Pose from a quaternion `(w, x, y, z)`, normalised first. Returns `None` for a
    /// zero or non-finite quaternion.
    pub fn from_quaternion(w: f64, x: f64, y: f64, z: f64, t: Vec3) -> Option<Self> {
        let q = Quaternion::new(w, x, y, z);
        let n = q.norm();
        if !n.is_finite() || n < 1e-12 {
            return None;
        }
        let uq = UnitQuaternion::from_quaternion(q);
        Some(Self {
            r: uq.to_rotation_matrix().into_inner(),
            t,
        })
    }

    /// Inverse, with the rotation inverted by transposition.
    pub fn inverse(&self) -> Self {
        let rt = self.r.transpose();
        Self {
            r: rt,
            t: -(rt * self.t),
        }
    }

    /// Composition `self * other`.
    pub fn compose(&self, other: &Pose) -> Pose {
        Pose {
            r: self.r * other.r,
            t: self.r * other.t + self.t,
        }
    }

    /// Relative pose `self^-1 * other`.
    pub fn between(&self, other: &Pose) -> Pose {
        self.inverse().compose(other)
    }

    /// `self * p`: a point moved from the pose's source frame to its target frame.
    pub fn transform(&self, p: &Vec3) -> Vec3 {
        self.r * p + self.t
    }

    /// The pose of a 3x4 row-major matrix `[R | t]` (the KITTI and wire layout).
    pub fn from_row_major_3x4(m: &[f64; 12]) -> Self {
        Self {
            r: Mat3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]),
            t: Vec3::new(m[3], m[7], m[11]),
        }
    }

    /// The 3x4 row-major matrix `[R | t]`.
    pub fn to_row_major_3x4(&self) -> [f64; 12] {
        let (r, t) = (&self.r, &self.t);
        [
            r[(0, 0)],
            r[(0, 1)],
            r[(0, 2)],
            t.x,
            r[(1, 0)],
            r[(1, 1)],
            r[(1, 2)],
            t.y,
            r[(2, 0)],
            r[(2, 1)],
            r[(2, 2)],
            t.z,
        ]
    }

    /// Homogeneous 4x4 matrix.
    pub fn to_matrix(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.r);
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.t);
        m
    }

    /// Unit quaternion of the rotation (non-negative scalar part).
    pub fn quaternion(&self) -> UnitQuaternion<f64> {
        crate::rotation::unit_quaternion_of(&self.r)
    }

    /// Nearest rigid transform (rotation projected onto SO(3) through its quaternion).
    pub fn to_isometry(&self) -> Se3 {
        Se3::from_parts(nalgebra::Translation3::from(self.t), self.quaternion())
    }

    /// Pose of an isometry.
    pub fn from_isometry(iso: &Se3) -> Self {
        Self {
            r: iso.rotation.to_rotation_matrix().into_inner(),
            t: iso.translation.vector,
        }
    }
}

/// Serialised as its 3x4 row-major matrix.
impl serde::Serialize for Pose {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        self.to_row_major_3x4().serialize(serializer)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn inverse_and_between() {
        let a = Pose::from_quaternion(0.9, 0.1, -0.3, 0.2, Vec3::new(1.0, 2.0, 3.0)).unwrap();
        let b = Pose::from_quaternion(0.5, 0.5, 0.5, -0.5, Vec3::new(-1.0, 0.0, 4.0)).unwrap();
        let id = a.compose(&a.inverse());
        assert_relative_eq!(id.to_matrix(), Matrix4::identity(), epsilon = 1e-12);
        assert_relative_eq!(
            a.compose(&a.between(&b)).to_matrix(),
            b.to_matrix(),
            epsilon = 1e-12
        );
        assert!(Pose::from_quaternion(0.0, 0.0, 0.0, 0.0, Vec3::zeros()).is_none());
        assert_eq!(Pose::from_row_major_3x4(&a.to_row_major_3x4()), a);
        assert_relative_eq!(
            a.transform(&Vec3::new(0.5, -1.0, 2.0)),
            (a.to_matrix() * nalgebra::Vector4::new(0.5, -1.0, 2.0, 1.0)).xyz(),
            epsilon = 1e-12
        );
    }
}
