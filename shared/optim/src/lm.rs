//! Levenberg-Marquardt with GTSAM's semantics (`LevenbergMarquardtParams` defaults):
//! lambda starts at 1e-5 and is multiplied by 10 after a rejected step and divided by 10
//! after an accepted one (bounded to [0, 1e5]); damping adds `lambda * I`; a step is
//! accepted when the actual over the predicted cost decrease exceeds 1e-3; iterations stop
//! when the relative or absolute error decrease falls below 1e-5, after 100 iterations, or
//! when lambda exceeds its bound. The normal equations are solved by a sparse Cholesky
//! factorisation on faer with a fill-reducing (AMD) ordering computed once.

use crate::graph::{GraphError, PoseGraph};
use crate::lie::LieGroup;
use crate::sparse::BlockCholesky;
use nalgebra::{SMatrix, SVector};

/// Lower-triangle blocks `((row block, column block), value)` of `H`.
type Blocks<const D: usize> = Vec<((usize, usize), SMatrix<f64, D, D>)>;

/// Optimiser settings (GTSAM's defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmParams {
    /// Initial damping.
    pub lambda_initial: f64,
    /// Damping change factor.
    pub lambda_factor: f64,
    /// Upper bound on lambda (stop when exceeded).
    pub lambda_upper_bound: f64,
    /// Lower bound on lambda.
    pub lambda_lower_bound: f64,
    /// Minimum ratio of actual to predicted decrease for a step to count.
    pub min_model_fidelity: f64,
    /// Maximum iterations.
    pub max_iterations: usize,
    /// Stop when the relative decrease is at most this.
    pub relative_error_tol: f64,
    /// Stop when the absolute decrease is at most this.
    pub absolute_error_tol: f64,
    /// Stop when the error is at most this.
    pub error_tol: f64,
}

impl Default for LmParams {
    fn default() -> Self {
        Self {
            lambda_initial: 1e-5,
            lambda_factor: 10.0,
            lambda_upper_bound: 1e5,
            lambda_lower_bound: 0.0,
            min_model_fidelity: 1e-3,
            max_iterations: 100,
            relative_error_tol: 1e-5,
            absolute_error_tol: 1e-5,
            error_tol: 0.0,
        }
    }
}

/// Outcome of a run.
#[derive(Debug, Clone, PartialEq)]
pub struct LmSummary {
    /// Error before optimising.
    pub initial_error: f64,
    /// Error after.
    pub final_error: f64,
    /// Iterations (linearisations) performed.
    pub iterations: usize,
    /// Whether a stopping criterion (not the iteration cap) ended the run.
    pub converged: bool,
}

/// Levenberg-Marquardt over a pose graph; call [`Lm::step`] repeatedly or [`Lm::optimize`].
#[derive(Debug)]
pub struct Lm<'g, G, const D: usize> {
    graph: &'g mut PoseGraph<G, D>,
    params: LmParams,
    lambda: f64,
    error: f64,
    iterations: usize,
    solver: Option<BlockCholesky<D>>,
    stopped: bool,
}

/// Block (i, j) of the lower triangle of H, stored in `pattern` order.
fn block_index(
    blocks: &mut std::collections::HashMap<(usize, usize), usize>,
    order: &mut Vec<(usize, usize)>,
    i: usize,
    j: usize,
) -> usize {
    let key = if i >= j { (i, j) } else { (j, i) };
    *blocks.entry(key).or_insert_with(|| {
        order.push(key);
        order.len() - 1
    })
}

impl<'g, G: LieGroup<D>, const D: usize> Lm<'g, G, D> {
    /// Prepares the optimiser; the graph needs at least one prior (an anchor).
    pub fn new(graph: &'g mut PoseGraph<G, D>, params: LmParams) -> Result<Self, GraphError> {
        if graph.priors.is_empty() {
            return Err(GraphError::Setup(
                "the graph has no prior: anchor a vertex (e.g. the first) or the problem is gauge-free and singular".into(),
            ));
        }
        let error = graph.error();
        Ok(Self {
            graph,
            params,
            lambda: params.lambda_initial,
            error,
            iterations: 0,
            solver: None,
            stopped: false,
        })
    }

    /// Current error.
    pub fn error(&self) -> f64 {
        self.error
    }

    /// Iterations done.
    pub fn iterations(&self) -> usize {
        self.iterations
    }

    /// Linear system `H = J^T J`, `g = J^T r` (whitened, robust-reweighted), as dense blocks.
    fn linearize(&self) -> (Blocks<D>, Vec<f64>) {
        let n = self.graph.values.len();
        let mut blocks = std::collections::HashMap::new();
        let mut order = Vec::new();
        let mut data: Vec<SMatrix<f64, D, D>> = Vec::new();
        let mut g = vec![0.0; n * D];
        let mut add =
            |i: usize, j: usize, m: SMatrix<f64, D, D>, data: &mut Vec<SMatrix<f64, D, D>>| {
                let k = block_index(&mut blocks, &mut order, i, j);
                if k == data.len() {
                    data.push(SMatrix::zeros());
                }
                // stored as (row block >= col block)
                data[k] += if i >= j { m } else { m.transpose() };
            };
        for i in 0..n {
            add(i, i, SMatrix::zeros(), &mut data);
        }
        let values = &self.graph.values;
        for f in &self.graph.between {
            let (e, hi, hj) = f.linearize(&values[f.i], &values[f.j]);
            let (r, mut ji, mut jj) = (f.sqrt_info * e, f.sqrt_info * hi, f.sqrt_info * hj);
            let w = f.kernel.weight(r.norm_squared()).sqrt();
            let r: SVector<f64, D> = r * w;
            ji *= w;
            jj *= w;
            add(f.i, f.i, ji.transpose() * ji, &mut data);
            add(f.j, f.j, jj.transpose() * jj, &mut data);
            add(f.j, f.i, jj.transpose() * ji, &mut data);
            let (gi, gj) = (ji.transpose() * r, jj.transpose() * r);
            for k in 0..D {
                g[f.i * D + k] += gi[k];
                g[f.j * D + k] += gj[k];
            }
        }
        for p in &self.graph.priors {
            let (e, h) = p.linearize(&values[p.i]);
            let (r, j) = (p.sqrt_info * e, p.sqrt_info * h);
            add(p.i, p.i, j.transpose() * j, &mut data);
            let gi = j.transpose() * r;
            for k in 0..D {
                g[p.i * D + k] += gi[k];
            }
        }
        (order.into_iter().zip(data).collect(), g)
    }

    /// One iteration: linearise, then try dampings until a step is accepted or lambda
    /// exceeds its bound. Returns false once the optimiser has stopped.
    pub fn step(&mut self) -> bool {
        if self.stopped {
            return false;
        }
        let (h, g) = self.linearize();
        self.iterations += 1;
        if self.solver.is_none() {
            let blocks: Vec<(usize, usize)> = h.iter().map(|(k, _)| *k).collect();
            self.solver = BlockCholesky::new(self.graph.values.len(), &blocks);
        }
        let Some(solver) = self.solver.as_mut() else {
            self.stopped = true;
            return false;
        };
        let block_values: Vec<SMatrix<f64, D, D>> = h.iter().map(|(_, m)| *m).collect();
        solver.set_blocks(&block_values);
        loop {
            let mut delta: Vec<f64> = g.iter().map(|v| -v).collect();
            let solved = self
                .solver
                .as_mut()
                .is_some_and(|s| s.solve(self.lambda, &mut delta));
            if !solved {
                if !self.increase_lambda() {
                    return false;
                }
                continue;
            }
            // predicted decrease: -(g^T d + 0.5 d^T H d)
            let mut hd = vec![0.0; delta.len()];
            for &((bi, bj), m) in &h {
                let di = SVector::<f64, D>::from_fn(|k, _| delta[bj * D + k]);
                let hi = m * di;
                for k in 0..D {
                    hd[bi * D + k] += hi[k];
                }
                if bi != bj {
                    let dj = SVector::<f64, D>::from_fn(|k, _| delta[bi * D + k]);
                    let hj = m.transpose() * dj;
                    for k in 0..D {
                        hd[bj * D + k] += hj[k];
                    }
                }
            }
            let gd: f64 = g.iter().zip(&delta).map(|(a, b)| a * b).sum();
            let dhd: f64 = hd.iter().zip(&delta).map(|(a, b)| a * b).sum();
            let predicted = -(gd + 0.5 * dhd);
            let new_values: Vec<G> = self
                .graph
                .values
                .iter()
                .enumerate()
                .map(|(i, x)| x.retract(&SVector::<f64, D>::from_fn(|k, _| delta[i * D + k])))
                .collect();
            let new_error = self.graph.error_at(&new_values);
            let actual = self.error - new_error;
            let success = if predicted > f64::EPSILON * self.error {
                actual / predicted > self.params.min_model_fidelity
            } else {
                actual >= 0.0
            };
            if predicted >= 0.0 && success {
                self.graph.values = new_values;
                self.error = new_error;
                self.lambda =
                    (self.lambda / self.params.lambda_factor).max(self.params.lambda_lower_bound);
                return true;
            }
            if !self.increase_lambda() {
                return false;
            }
        }
    }

    fn increase_lambda(&mut self) -> bool {
        self.lambda *= self.params.lambda_factor;
        if self.lambda >= self.params.lambda_upper_bound {
            self.stopped = true;
            return false;
        }
        true
    }

    /// Runs to convergence with GTSAM's stopping rules.
    pub fn optimize(&mut self) -> LmSummary {
        let initial_error = self.error;
        let mut converged = self.error <= self.params.error_tol;
        while !converged && self.iterations < self.params.max_iterations {
            let prev = self.error;
            if !self.step() {
                converged = true;
                break;
            }
            let decrease = prev - self.error;
            converged = self.error <= self.params.error_tol
                || decrease <= self.params.absolute_error_tol
                || decrease / prev <= self.params.relative_error_tol;
        }
        LmSummary {
            initial_error,
            final_error: self.error,
            iterations: self.iterations,
            converged,
        }
    }
}
