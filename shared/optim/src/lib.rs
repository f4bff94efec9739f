//! Pose-graph optimisation: SE(2)/SE(3) variables, between-factors and priors with
//! Gaussian noise from information matrices and robust kernels, g2o IO, and
//! Levenberg-Marquardt with GTSAM's semantics on a sparse Cholesky (faer).
pub mod g2o;
pub mod graph;
pub mod lie;
pub mod lm;
pub mod sparse;

pub use g2o::{read_g2o, write_g2o, G2oGraph, ReadReport};
pub use graph::{Between, GraphError, Kernel, PoseGraph, Prior};
pub use lm::{Lm, LmParams, LmSummary};

/// GTSAM-style anchor variances for the first vertex of a 3D graph: rotation 1e-6,
/// translation 1e-4 (tangent order `omega, v`), as `../shared/data/README.md` sets up GTSAM.
pub const PRIOR_VARIANCES_SE3: [f64; 6] = [1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4];
/// The same anchor for 2D graphs (tangent order `x, y, theta`).
pub const PRIOR_VARIANCES_SE2: [f64; 3] = [1e-4, 1e-4, 1e-6];
