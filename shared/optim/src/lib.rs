//! The least-squares core of SuPerMVO: one Levenberg-Marquardt driver ([`lm`]) for every
//! problem, one set of robust kernels ([`kernel`]), the projection Jacobian ([`projection`]),
//! SO(3) and the Lie groups with GTSAM's conventions, and pose graphs (SE(2)/SE(3)/Sim(3)
//! variables, between-factors and priors, g2o IO) solved on a sparse Cholesky (faer).
pub mod g2o;
pub mod graph;
mod graph_lm;
pub mod kernel;
pub mod lie;
pub mod lm;
pub mod projection;
pub mod so3;
pub mod sparse;

pub use g2o::{read_g2o, write_g2o, G2oGraph, ReadReport};
pub use graph::{Between, GraphError, PoseGraph, Prior};
pub use graph_lm::Lm;
pub use kernel::Kernel;
pub use lm::{minimise, Acceptance, LeastSquares, LevenbergMarquardt, LmParams, LmSummary};

/// GTSAM-style anchor variances for the first vertex of a 3D graph: rotation 1e-6,
/// translation 1e-4 (tangent order `omega, v`), as `../shared/data/README.md` sets up GTSAM.
pub const PRIOR_VARIANCES_SE3: [f64; 6] = [1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4];
/// The same anchor for 2D graphs (tangent order `x, y, theta`).
pub const PRIOR_VARIANCES_SE2: [f64; 3] = [1e-4, 1e-4, 1e-6];
