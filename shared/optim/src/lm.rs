//! The project's one Levenberg-Marquardt driver. A problem says how to evaluate its cost,
//! linearise (the normal equations), solve them damped, and apply a step; the driver owns
//! the damping schedule, the acceptance of a step and the stopping rules, all set by
//! [`LmParams`]:
//! - GTSAM's semantics ([`LmParams::default`], the pose graphs): lambda from 1e-5, divided
//!   by 10 after an accepted step and multiplied by 10 after a rejected one within [0, 1e5];
//!   a step is accepted when the actual over the predicted cost decrease exceeds 1e-3;
//!   stopping when the relative or absolute decrease falls below 1e-5, after 100
//!   iterations, or when lambda exceeds its bound;
//! - Marquardt's rule for small problems ([`LmParams::marquardt`]: PnP and essential-matrix
//!   refinement, local bundle adjustment): a step is accepted when it lowers the cost, a few
//!   dampings are tried per linearisation, and the run stops when none helps;
//! - Gauss-Newton ([`LmParams::gauss_newton`]: iteratively reweighted refinements whose
//!   weights change with every linearisation): every solvable step is taken, until one is
//!   shorter than a tolerance.
//!
//! How the damping enters the normal equations (`lambda I` or `lambda diag(H)`) is the
//! problem's choice, made in [`LeastSquares::solve`].

/// A least-squares problem as the driver sees it.
pub trait LeastSquares {
    /// The variables.
    type State: Clone;
    /// The normal equations at a state.
    type System;
    /// A solution of the damped normal equations.
    type Step;

    /// The (robust) cost at a state.
    fn cost(&self, state: &Self::State) -> f64;
    /// The normal equations at `state`; `None` when the problem cannot be linearised (too
    /// few residuals constrain it), which stops the run.
    fn linearize(&mut self, state: &Self::State) -> Option<Self::System>;
    /// Solves the normal equations damped by `lambda`; `None` when they are not positive
    /// definite (the driver then raises the damping).
    fn solve(&mut self, system: &Self::System, lambda: f64) -> Option<Self::Step>;
    /// The state moved by a step.
    fn retract(&self, state: &Self::State, step: &Self::Step) -> Self::State;
    /// The decrease of the linearised cost, `-(g.d + d.H.d / 2)`; needed by
    /// [`Acceptance::ModelFidelity`] (without it a step must lower the cost).
    fn predicted_decrease(&self, _system: &Self::System, _step: &Self::Step) -> Option<f64> {
        None
    }
    /// The size of a step, compared with [`LmParams::step_tol`].
    fn step_norm(&self, _step: &Self::Step) -> f64 {
        f64::INFINITY
    }
}

/// When a step is taken.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Acceptance {
    /// When it lowers the cost.
    CostDecrease,
    /// When the actual over the predicted cost decrease exceeds this (GTSAM).
    ModelFidelity(f64),
    /// Always (Gauss-Newton); the cost is then not evaluated.
    Always,
}

/// Driver settings; the default is GTSAM's `LevenbergMarquardtParams`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmParams {
    /// Initial damping.
    pub lambda_initial: f64,
    /// Damping change factor.
    pub lambda_factor: f64,
    /// Upper bound on lambda (the run stops when it is reached).
    pub lambda_upper_bound: f64,
    /// Lower bound on lambda.
    pub lambda_lower_bound: f64,
    /// When a step is taken.
    pub acceptance: Acceptance,
    /// Dampings tried per linearisation before the run stops.
    pub dampings_per_iteration: usize,
    /// Maximum iterations (linearisations).
    pub max_iterations: usize,
    /// Stop when the relative decrease is at most this.
    pub relative_error_tol: f64,
    /// Stop when the absolute decrease is at most this.
    pub absolute_error_tol: f64,
    /// Stop when the error is at most this.
    pub error_tol: f64,
    /// Stop after a step shorter than this.
    pub step_tol: f64,
}

impl Default for LmParams {
    fn default() -> Self {
        Self {
            lambda_initial: 1e-5,
            lambda_factor: 10.0,
            lambda_upper_bound: 1e5,
            lambda_lower_bound: 0.0,
            acceptance: Acceptance::ModelFidelity(1e-3),
            dampings_per_iteration: usize::MAX,
            max_iterations: 100,
            relative_error_tol: 1e-5,
            absolute_error_tol: 1e-5,
            error_tol: 0.0,
            step_tol: 0.0,
        }
    }
}

impl LmParams {
    /// Marquardt's rule for small problems: a step must lower the cost, `dampings` tries
    /// per linearisation, lambda kept at or above `lambda_lower_bound`; the run ends after
    /// `max_iterations` or when no damping lowers the cost.
    pub fn marquardt(
        lambda_initial: f64,
        lambda_lower_bound: f64,
        dampings: usize,
        max_iterations: usize,
    ) -> Self {
        Self {
            lambda_initial,
            lambda_upper_bound: f64::INFINITY,
            lambda_lower_bound,
            acceptance: Acceptance::CostDecrease,
            dampings_per_iteration: dampings,
            max_iterations,
            relative_error_tol: 0.0,
            absolute_error_tol: 0.0,
            ..Self::default()
        }
    }

    /// Gauss-Newton: no damping, every solvable step taken, stopping after a step shorter
    /// than `step_tol` or when the normal equations cannot be solved.
    pub fn gauss_newton(max_iterations: usize, step_tol: f64) -> Self {
        Self {
            lambda_initial: 0.0,
            lambda_upper_bound: f64::INFINITY,
            acceptance: Acceptance::Always,
            dampings_per_iteration: 1,
            max_iterations,
            step_tol,
            ..Self::default()
        }
    }
}

/// Outcome of a run.
#[derive(Debug, Clone, PartialEq)]
pub struct LmSummary {
    /// Cost before optimising (NaN under [`Acceptance::Always`]).
    pub initial_error: f64,
    /// Cost after.
    pub final_error: f64,
    /// Iterations (linearisations) performed.
    pub iterations: usize,
    /// Whether a stopping criterion (not the iteration cap) ended the run.
    pub converged: bool,
}

/// The driver's state over one run: the variables, their cost and the damping.
#[derive(Debug, Clone)]
pub struct LevenbergMarquardt<S> {
    state: S,
    params: LmParams,
    lambda: f64,
    cost: f64,
    initial_cost: f64,
    iterations: usize,
    stopped: bool,
}

impl<S: Clone> LevenbergMarquardt<S> {
    /// Starts a run from `state`.
    pub fn new<P: LeastSquares<State = S>>(problem: &P, state: S, params: LmParams) -> Self {
        let cost = if params.acceptance == Acceptance::Always {
            f64::NAN
        } else {
            problem.cost(&state)
        };
        Self {
            state,
            params,
            lambda: params.lambda_initial,
            cost,
            initial_cost: cost,
            iterations: 0,
            stopped: false,
        }
    }

    /// The current variables.
    pub fn state(&self) -> &S {
        &self.state
    }

    /// The variables, ending the run.
    pub fn into_state(self) -> S {
        self.state
    }

    /// The current cost.
    pub fn cost(&self) -> f64 {
        self.cost
    }

    /// Iterations done.
    pub fn iterations(&self) -> usize {
        self.iterations
    }

    fn tracks_cost(&self) -> bool {
        self.params.acceptance != Acceptance::Always
    }

    /// One iteration: linearise, then try dampings until a step is taken. Returns false
    /// once the run has stopped (no step taken).
    pub fn step<P: LeastSquares<State = S>>(&mut self, problem: &mut P) -> bool {
        if self.stopped {
            return false;
        }
        let Some(system) = problem.linearize(&self.state) else {
            self.stopped = true;
            return false;
        };
        self.iterations += 1;
        for _ in 0..self.params.dampings_per_iteration {
            let Some(step) = problem.solve(&system, self.lambda) else {
                if !self.increase_lambda() {
                    return false;
                }
                continue;
            };
            let moved = problem.retract(&self.state, &step);
            if self.params.acceptance == Acceptance::Always {
                self.take(moved, f64::NAN, problem.step_norm(&step));
                return true;
            }
            let moved_cost = problem.cost(&moved);
            if self.accepts(problem, &system, &step, moved_cost) {
                self.take(moved, moved_cost, problem.step_norm(&step));
                self.lambda =
                    (self.lambda / self.params.lambda_factor).max(self.params.lambda_lower_bound);
                return true;
            }
            if !self.increase_lambda() {
                return false;
            }
        }
        self.stopped = true;
        false
    }

    fn accepts<P: LeastSquares<State = S>>(
        &self,
        problem: &P,
        system: &P::System,
        step: &P::Step,
        moved_cost: f64,
    ) -> bool {
        let actual = self.cost - moved_cost;
        match self.params.acceptance {
            Acceptance::Always => true,
            Acceptance::CostDecrease => moved_cost < self.cost,
            Acceptance::ModelFidelity(fidelity) => {
                let Some(predicted) = problem.predicted_decrease(system, step) else {
                    return moved_cost < self.cost;
                };
                let success = if predicted > f64::EPSILON * self.cost {
                    actual / predicted > fidelity
                } else {
                    actual >= 0.0
                };
                predicted >= 0.0 && success
            }
        }
    }

    fn take(&mut self, moved: S, moved_cost: f64, step_norm: f64) {
        self.state = moved;
        self.cost = moved_cost;
        if step_norm < self.params.step_tol {
            self.stopped = true;
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

    /// Iterates until a stopping rule or the iteration cap ends the run.
    pub fn optimize<P: LeastSquares<State = S>>(&mut self, problem: &mut P) -> LmSummary {
        let mut converged = self.tracks_cost() && self.cost <= self.params.error_tol;
        while !converged && self.iterations < self.params.max_iterations {
            let previous = self.cost;
            if !self.step(problem) {
                converged = true;
                break;
            }
            if self.tracks_cost() {
                let decrease = previous - self.cost;
                converged = self.cost <= self.params.error_tol
                    || decrease <= self.params.absolute_error_tol
                    || decrease / previous <= self.params.relative_error_tol;
            }
        }
        LmSummary {
            initial_error: self.initial_cost,
            final_error: self.cost,
            iterations: self.iterations,
            converged,
        }
    }
}

/// Runs `problem` from `state` to the end under `params`; the final variables and the run.
pub fn minimise<P: LeastSquares>(
    problem: &mut P,
    state: P::State,
    params: LmParams,
) -> (P::State, LmSummary) {
    let mut lm = LevenbergMarquardt::new(problem, state, params);
    let summary = lm.optimize(problem);
    (lm.into_state(), summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock's function as residuals `(10 (y - x^2), 1 - x)`, damped by `lambda I`.
    struct Rosenbrock;

    impl LeastSquares for Rosenbrock {
        type State = [f64; 2];
        type System = ([[f64; 2]; 2], [f64; 2]);
        type Step = [f64; 2];

        fn cost(&self, s: &[f64; 2]) -> f64 {
            0.5 * ((10.0 * (s[1] - s[0] * s[0])).powi(2) + (1.0 - s[0]).powi(2))
        }
        fn linearize(&mut self, s: &[f64; 2]) -> Option<Self::System> {
            let r = [10.0 * (s[1] - s[0] * s[0]), 1.0 - s[0]];
            let j = [[-20.0 * s[0], 10.0], [-1.0, 0.0]];
            let mut h = [[0.0; 2]; 2];
            let mut g = [0.0; 2];
            for k in 0..2 {
                for a in 0..2 {
                    g[a] += j[k][a] * r[k];
                    for b in 0..2 {
                        h[a][b] += j[k][a] * j[k][b];
                    }
                }
            }
            Some((h, g))
        }
        fn solve(&mut self, (h, g): &Self::System, lambda: f64) -> Option<[f64; 2]> {
            let (a, b, d) = (h[0][0] + lambda, h[0][1], h[1][1] + lambda);
            let det = a * d - b * b;
            (det > 0.0).then(|| [-(d * g[0] - b * g[1]) / det, -(a * g[1] - b * g[0]) / det])
        }
        fn retract(&self, s: &[f64; 2], d: &[f64; 2]) -> [f64; 2] {
            [s[0] + d[0], s[1] + d[1]]
        }
        fn predicted_decrease(&self, (h, g): &Self::System, d: &[f64; 2]) -> Option<f64> {
            let gd = g[0] * d[0] + g[1] * d[1];
            let dhd =
                d[0] * (h[0][0] * d[0] + h[0][1] * d[1]) + d[1] * (h[1][0] * d[0] + h[1][1] * d[1]);
            Some(-(gd + 0.5 * dhd))
        }
        fn step_norm(&self, d: &[f64; 2]) -> f64 {
            d[0].hypot(d[1])
        }
    }

    #[test]
    fn every_rule_reaches_the_minimum_of_rosenbrock() {
        for params in [
            LmParams {
                relative_error_tol: 1e-12,
                absolute_error_tol: 1e-14,
                ..LmParams::default()
            },
            LmParams::marquardt(1e-3, 1e-9, 6, 200),
            LmParams::gauss_newton(50, 1e-12),
        ] {
            let (s, run) = minimise(&mut Rosenbrock, [-1.2, 1.0], params);
            assert!(
                (s[0] - 1.0).abs() < 1e-6 && (s[1] - 1.0).abs() < 1e-6,
                "{params:?}: {s:?} after {run:?}"
            );
        }
    }

    #[test]
    fn a_cost_decrease_rule_never_raises_the_cost() {
        let mut problem = Rosenbrock;
        let params = LmParams::marquardt(1e-3, 1e-9, 6, 200);
        let mut lm = LevenbergMarquardt::new(&problem, [-1.2, 1.0], params);
        let mut before = lm.cost();
        while lm.step(&mut problem) {
            assert!(lm.cost() < before);
            before = lm.cost();
        }
        assert!(lm.iterations() > 5, "{}", lm.iterations());
    }

    /// Normal equations that are never positive definite.
    struct Singular(usize);

    impl LeastSquares for Singular {
        type State = [f64; 2];
        type System = ();
        type Step = [f64; 2];
        fn cost(&self, s: &[f64; 2]) -> f64 {
            Rosenbrock.cost(s)
        }
        fn linearize(&mut self, _: &[f64; 2]) -> Option<()> {
            Some(())
        }
        fn solve(&mut self, _: &(), _: f64) -> Option<[f64; 2]> {
            self.0 += 1;
            None
        }
        fn retract(&self, s: &[f64; 2], _: &[f64; 2]) -> [f64; 2] {
            *s
        }
    }

    #[test]
    fn the_damping_bound_and_the_tries_per_iteration_end_a_run() {
        // GTSAM: lambda from 1e-5 by factors of 10 reaches 1e5 after ten tries
        let mut problem = Singular(0);
        let (_, run) = minimise(&mut problem, [0.0, 0.0], LmParams::default());
        assert_eq!((problem.0, run.iterations, run.converged), (10, 1, true));
        let mut lm = LevenbergMarquardt::new(&problem, [0.0, 0.0], LmParams::default());
        assert!(!lm.step(&mut Singular(0)));
        assert!(!lm.step(&mut problem), "a stopped run takes no more steps");
        // Marquardt: as many tries as dampings allowed
        let mut problem = Singular(0);
        minimise(
            &mut problem,
            [0.0, 0.0],
            LmParams::marquardt(1e-3, 1e-9, 6, 20),
        );
        assert_eq!(problem.0, 6);
    }
}
