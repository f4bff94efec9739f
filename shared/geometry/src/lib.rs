//! Rigid-body and similarity transforms used everywhere in SuPerMVO.
//!
//! Conventions: a pose named `T_a_b` maps points expressed in frame `b` into frame `a`
//! (`p_in_a = T_a_b * p_in_b`). Trajectories store `T_world_cam` per frame.
//!
//! The refinements of the minimal solvers run on the project's one least-squares core,
//! `supermvo-optim`.

pub mod essential;
pub mod pnp;
mod pose;
mod pose_refinement;
pub mod rng;
mod rotation;
mod sim3;
mod umeyama;

pub use pose::Pose;
pub use rotation::{euler_rpy, rotation_angle, skew, so3_exp, so3_log, OrthonormalityError};
pub use sim3::Sim3;
pub use umeyama::{umeyama, AlignmentKind, UmeyamaError};

/// A rigid transform in SE(3) (rotation + translation), double precision.
pub type Se3 = nalgebra::Isometry3<f64>;
/// A 3-vector, double precision.
pub type Vec3 = nalgebra::Vector3<f64>;
/// A 3x3 matrix, double precision.
pub type Mat3 = nalgebra::Matrix3<f64>;

/// Builds an SE(3) pose from a rotation matrix and translation without re-orthonormalising.
///
/// The rotation is converted to a unit quaternion; callers that need to reject
/// non-rotations should first call [`rotation::check_orthonormal`].
pub fn se3_from_parts(r: &Mat3, t: &Vec3) -> Se3 {
    let rot = nalgebra::Rotation3::from_matrix_unchecked(*r);
    Se3::from_parts(
        nalgebra::Translation3::from(*t),
        nalgebra::UnitQuaternion::from_rotation_matrix(&rot),
    )
}

pub use rotation::check_orthonormal;

/// Index of the smallest value (the first on ties); 0 for an empty input.
pub fn argmin(values: impl IntoIterator<Item = f64>) -> usize {
    values
        .into_iter()
        .enumerate()
        .fold(
            (0, f64::INFINITY),
            |best, (i, v)| if v < best.1 { (i, v) } else { best },
        )
        .0
}
