//! Pose graphs: variables, between-factors, priors with robust kernels, and the error GTSAM uses
//! (`0.5 * sum |whitened residual|^2`, each residual whitened by the square root of its
//! information matrix and, if robust, reweighted).

use crate::kernel::Kernel;
use crate::lie::LieGroup;
use nalgebra::{SMatrix, SVector};
use std::path::PathBuf;

/// Errors of graph IO and optimisation.
#[derive(Debug, thiserror::Error)]
pub enum GraphError {
    /// File access.
    #[error("{path}: {source}")]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: std::io::Error,
    },
    /// A malformed line.
    #[error("{path}:{line}: {message}")]
    Parse {
        /// File.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// The graph as a whole is unusable.
    #[error("{path}: {message}")]
    Invalid {
        /// File.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Optimisation cannot start.
    #[error("{0}")]
    Setup(String),
}

/// Square root `R` (upper triangular, `R^T R = info`) of an information matrix, or why not.
pub fn sqrt_information<const D: usize>(
    info: &SMatrix<f64, D, D>,
) -> Result<SMatrix<f64, D, D>, String> {
    if info.iter().any(|v| !v.is_finite()) {
        return Err("information matrix has non-finite entries".into());
    }
    let sym = (info + info.transpose()) * 0.5;
    match nalgebra::Cholesky::new(sym) {
        Some(c) => Ok(c.l().transpose()),
        None => Err("information matrix is not positive definite".into()),
    }
}

/// `measured ~ X_i^-1 X_j`.
#[derive(Debug, Clone, Copy)]
pub struct Between<G, const D: usize> {
    /// First variable index.
    pub i: usize,
    /// Second variable index.
    pub j: usize,
    /// Measured relative pose.
    pub measured: G,
    /// Square-root information `R`.
    pub sqrt_info: SMatrix<f64, D, D>,
    /// Robust kernel.
    pub kernel: Kernel,
}

impl<G: LieGroup<D>, const D: usize> Between<G, D> {
    /// A between-factor with an information matrix (must be positive definite).
    pub fn new(i: usize, j: usize, measured: G, info: &SMatrix<f64, D, D>) -> Result<Self, String> {
        Ok(Self {
            i,
            j,
            measured,
            sqrt_info: sqrt_information(info)?,
            kernel: Kernel::None,
        })
    }

    /// Information matrix `R^T R`.
    pub fn information(&self) -> SMatrix<f64, D, D> {
        self.sqrt_info.transpose() * self.sqrt_info
    }

    /// Unwhitened residual `Log(Z^-1 X_i^-1 X_j)`.
    pub fn residual(&self, xi: &G, xj: &G) -> SVector<f64, D> {
        self.measured.between(&xi.between(xj)).log()
    }

    /// Residual and its Jacobians with respect to right perturbations of `X_i`, `X_j`.
    pub fn linearize(
        &self,
        xi: &G,
        xj: &G,
    ) -> (SVector<f64, D>, SMatrix<f64, D, D>, SMatrix<f64, D, D>) {
        let hx = xi.between(xj);
        let e = self.measured.between(&hx).log();
        let jinv = G::right_jacobian_inverse(&e);
        let hj = jinv;
        let hi = -(jinv * hx.inverse().adjoint());
        (e, hi, hj)
    }
}

/// `X_i ~ prior`.
#[derive(Debug, Clone, Copy)]
pub struct Prior<G, const D: usize> {
    /// Variable index.
    pub i: usize,
    /// Prior value.
    pub value: G,
    /// Square-root information.
    pub sqrt_info: SMatrix<f64, D, D>,
}

impl<G: LieGroup<D>, const D: usize> Prior<G, D> {
    /// A prior with diagonal variances (in the tangent order of `G`).
    pub fn with_variances(i: usize, value: G, variances: &[f64; D]) -> Self {
        let sqrt_info = SMatrix::<f64, D, D>::from_fn(|r, c| {
            if r == c {
                1.0 / variances[r].sqrt()
            } else {
                0.0
            }
        });
        Self {
            i,
            value,
            sqrt_info,
        }
    }

    /// Residual `Log(P^-1 X)` and its Jacobian.
    pub fn linearize(&self, x: &G) -> (SVector<f64, D>, SMatrix<f64, D, D>) {
        let e = self.value.between(x).log();
        (e, G::right_jacobian_inverse(&e))
    }
}

/// Variables (with their external keys) and factors.
#[derive(Debug, Clone)]
pub struct PoseGraph<G, const D: usize> {
    /// External id of each variable (g2o vertex id).
    pub keys: Vec<usize>,
    /// Current values.
    pub values: Vec<G>,
    /// Between-factors.
    pub between: Vec<Between<G, D>>,
    /// Priors.
    pub priors: Vec<Prior<G, D>>,
}

impl<G: LieGroup<D>, const D: usize> PoseGraph<G, D> {
    /// A graph without factors.
    pub fn new(keys: Vec<usize>, values: Vec<G>) -> Self {
        Self {
            keys,
            values,
            between: Vec::new(),
            priors: Vec::new(),
        }
    }

    /// Total error at `values` (GTSAM's definition).
    pub fn error_at(&self, values: &[G]) -> f64 {
        let b: f64 = self
            .between
            .iter()
            .map(|f| {
                let r = f.sqrt_info * f.residual(&values[f.i], &values[f.j]);
                f.kernel.loss(r.norm_squared())
            })
            .sum();
        let p: f64 = self
            .priors
            .iter()
            .map(|f| 0.5 * (f.sqrt_info * f.value.between(&values[f.i]).log()).norm_squared())
            .sum();
        b + p
    }

    /// Total error at the current values.
    pub fn error(&self) -> f64 {
        self.error_at(&self.values)
    }

    /// The external ids of the variables that no chain of between-factors links to a
    /// variable with a prior (to the first variable when there is none): their values are
    /// not determined by the graph (a truncated file, a missing edge).
    pub fn unanchored(&self) -> Vec<usize> {
        let n = self.values.len();
        let mut adjacent: Vec<Vec<usize>> = vec![Vec::new(); n];
        for f in &self.between {
            if f.i < n && f.j < n {
                adjacent[f.i].push(f.j);
                adjacent[f.j].push(f.i);
            }
        }
        let mut reached = vec![false; n];
        let mut todo: Vec<usize> = self.priors.iter().map(|p| p.i).filter(|&i| i < n).collect();
        if todo.is_empty() && n > 0 {
            todo.push(0);
        }
        while let Some(v) = todo.pop() {
            if std::mem::replace(&mut reached[v], true) {
                continue;
            }
            todo.extend(adjacent[v].iter().copied().filter(|&w| !reached[w]));
        }
        (0..n)
            .filter(|&v| !reached[v])
            .map(|v| self.keys[v])
            .collect()
    }
}
