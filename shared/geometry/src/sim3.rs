//! Similarity transforms Sim(3): `x -> s * R * x + t`.

use crate::{Mat3, Se3, Vec3};
use nalgebra::{Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

/// A similarity transform `x -> scale * rotation * x + translation`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Sim3 {
    /// Rotation part.
    pub rotation: UnitQuaternion<f64>,
    /// Translation part.
    pub translation: Vec3,
    /// Positive scale factor.
    pub scale: f64,
}

impl Default for Sim3 {
    fn default() -> Self {
        Self::identity()
    }
}

impl Sim3 {
    /// The identity transform.
    pub fn identity() -> Self {
        Self {
            rotation: UnitQuaternion::identity(),
            translation: Vec3::zeros(),
            scale: 1.0,
        }
    }

    /// Builds a similarity from a rotation matrix (assumed orthonormal), translation and scale.
    pub fn from_parts(r: &Mat3, t: &Vec3, scale: f64) -> Self {
        let rot = nalgebra::Rotation3::from_matrix_unchecked(*r);
        Self {
            rotation: UnitQuaternion::from_rotation_matrix(&rot),
            translation: *t,
            scale,
        }
    }

    /// Rotation as a matrix.
    pub fn rotation_matrix(&self) -> Mat3 {
        self.rotation.to_rotation_matrix().into_inner()
    }

    /// Applies the transform to a point.
    pub fn transform_point(&self, p: &Vec3) -> Vec3 {
        self.rotation * (p * self.scale) + self.translation
    }

    /// Maps a pose `T_world_cam` of the source frame into the target frame: the camera
    /// centre is transformed as a point and the orientation is rotated; the result stays a
    /// rigid pose (the scale acts on positions only), as trajectory alignment requires.
    pub fn transform_pose(&self, pose: &Se3) -> Se3 {
        Se3::from_parts(
            Translation3::from(self.transform_point(&pose.translation.vector)),
            self.rotation * pose.rotation,
        )
    }

    /// Composition `self * other`.
    pub fn compose(&self, other: &Sim3) -> Sim3 {
        Sim3 {
            rotation: self.rotation * other.rotation,
            translation: self.transform_point(&other.translation),
            scale: self.scale * other.scale,
        }
    }

    /// Inverse transform.
    pub fn inverse(&self) -> Sim3 {
        let rinv = self.rotation.inverse();
        let sinv = 1.0 / self.scale;
        Sim3 {
            rotation: rinv,
            translation: -(rinv * self.translation) * sinv,
            scale: sinv,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn inverse_composes_to_identity() {
        let s = Sim3 {
            rotation: UnitQuaternion::from_euler_angles(0.1, -0.4, 1.2),
            translation: Vec3::new(1.0, -2.0, 3.0),
            scale: 2.5,
        };
        let id = s.compose(&s.inverse());
        assert_relative_eq!(id.scale, 1.0, epsilon = 1e-12);
        assert_relative_eq!(id.translation.norm(), 0.0, epsilon = 1e-12);
        assert_relative_eq!(id.rotation.angle(), 0.0, epsilon = 1e-12);
        let p = Vec3::new(0.3, 0.2, -0.7);
        assert_relative_eq!(
            s.inverse().transform_point(&s.transform_point(&p)),
            p,
            epsilon = 1e-12
        );
    }
}
