//! Levenberg-Marquardt over a pose graph with GTSAM's semantics ([`LmParams::default`]):
//! the graph as a problem of the project's one driver ([`crate::lm`]), damped by adding
//! `lambda * I`, its normal equations solved by a sparse Cholesky factorisation on faer with a
//! fill-reducing (AMD) ordering computed once.

use crate::graph::{GraphError, PoseGraph};
use crate::lie::LieGroup;
use crate::lm::{LeastSquares, LevenbergMarquardt, LmParams, LmSummary};
use crate::sparse::BlockCholesky;
use nalgebra::{SMatrix, SVector};

/// Lower-triangle blocks `((row block, column block), value)` of `H`.
type Blocks<const D: usize> = Vec<((usize, usize), SMatrix<f64, D, D>)>;

/// Levenberg-Marquardt over a pose graph; call [`Lm::step`] repeatedly or [`Lm::optimize`].
#[derive(Debug)]
pub struct Lm<'g, G, const D: usize> {
    graph: &'g mut PoseGraph<G, D>,
    driver: LevenbergMarquardt<Vec<G>>,
    solver: Option<BlockCholesky<D>>,
}

/// The graph's factors as a least-squares problem over its values.
struct GraphProblem<'a, G, const D: usize> {
    graph: &'a PoseGraph<G, D>,
    solver: &'a mut Option<BlockCholesky<D>>,
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
        let mut solver = None;
        let problem = GraphProblem {
            graph,
            solver: &mut solver,
        };
        let driver = LevenbergMarquardt::new(&problem, graph.values.clone(), params);
        Ok(Self {
            graph,
            driver,
            solver,
        })
    }

    /// Current error.
    pub fn error(&self) -> f64 {
        self.driver.cost()
    }

    /// Iterations done.
    pub fn iterations(&self) -> usize {
        self.driver.iterations()
    }

    /// One iteration: linearise, then try dampings until a step is accepted or lambda
    /// exceeds its bound. Returns false once the optimiser has stopped.
    pub fn step(&mut self) -> bool {
        self.drive(|driver, problem| driver.step(problem))
    }

    /// Runs to convergence with GTSAM's stopping rules.
    pub fn optimize(&mut self) -> LmSummary {
        self.drive(|driver, problem| driver.optimize(problem))
    }

    /// Runs the driver on the graph's factors, then writes its values back to the graph.
    fn drive<R>(
        &mut self,
        run: impl FnOnce(&mut LevenbergMarquardt<Vec<G>>, &mut GraphProblem<'_, G, D>) -> R,
    ) -> R {
        let mut problem = GraphProblem {
            graph: self.graph,
            solver: &mut self.solver,
        };
        let result = run(&mut self.driver, &mut problem);
        self.graph.values.clone_from(self.driver.state());
        result
    }
}

impl<G: LieGroup<D>, const D: usize> GraphProblem<'_, G, D> {
    /// Linear system `H = J^T J`, `g = J^T r` (whitened, robust-reweighted), as dense blocks.
    fn normal_equations(&self, values: &[G]) -> (Blocks<D>, Vec<f64>) {
        let n = values.len();
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
}

impl<G: LieGroup<D>, const D: usize> LeastSquares for GraphProblem<'_, G, D> {
    type State = Vec<G>;
    type System = (Blocks<D>, Vec<f64>);
    type Step = Vec<f64>;

    fn cost(&self, values: &Vec<G>) -> f64 {
        self.graph.error_at(values)
    }

    /// The normal equations, with the sparse factorisation's pattern analysed on the first
    /// call and its values set on every call.
    fn linearize(&mut self, values: &Vec<G>) -> Option<Self::System> {
        let (h, g) = self.normal_equations(values);
        if self.solver.is_none() {
            let blocks: Vec<(usize, usize)> = h.iter().map(|(k, _)| *k).collect();
            *self.solver = BlockCholesky::new(values.len(), &blocks);
        }
        let solver = self.solver.as_mut()?;
        let block_values: Vec<SMatrix<f64, D, D>> = h.iter().map(|(_, m)| *m).collect();
        solver.set_blocks(&block_values);
        Some((h, g))
    }

    fn solve(&mut self, (_, g): &Self::System, lambda: f64) -> Option<Vec<f64>> {
        let mut delta: Vec<f64> = g.iter().map(|v| -v).collect();
        let solver = self.solver.as_mut()?;
        solver.solve(lambda, &mut delta).then_some(delta)
    }

    fn retract(&self, values: &Vec<G>, delta: &Vec<f64>) -> Vec<G> {
        values
            .iter()
            .enumerate()
            .map(|(i, x)| x.retract(&SVector::<f64, D>::from_fn(|k, _| delta[i * D + k])))
            .collect()
    }

    fn predicted_decrease(&self, (h, g): &Self::System, delta: &Vec<f64>) -> Option<f64> {
        let mut hd = vec![0.0; delta.len()];
        for &((bi, bj), m) in h {
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
        let gd: f64 = g.iter().zip(delta).map(|(a, b)| a * b).sum();
        let dhd: f64 = hd.iter().zip(delta).map(|(a, b)| a * b).sum();
        Some(-(gd + 0.5 * dhd))
    }
}
