//! The Sim(3) pose graph of keyframes that spreads a loop's correction (scale included)
//! along it, and the conversions between poses and similarities.

use super::LoopCloser;
use nalgebra::SVector;
use supermvo_geometry::Pose;
use supermvo_optim::lie::{LieGroup, Sim3};
use supermvo_optim::{Between, Kernel, Lm, LmParams, PoseGraph, Prior};

impl LoopCloser {
    /// Solves the Sim(3) pose graph (odometry between neighbouring keyframes, the loops with
    /// a Cauchy kernel against a wrong one, the first keyframe anchored) over the keyframes
    /// since the map was last tied together (see [`LoopCloser::solve`]) and keeps the result.
    pub(super) fn optimise(&mut self) {
        let solved = self.solve();
        self.solves += 1;
        self.free_in_last_solve = self.keyframes.len() - self.free_from();
        for (k, v) in self.keyframes.iter_mut().zip(solved) {
            k.opt = v;
        }
        self.unsolved_loops = false;
        self.tied = self.loops.iter().map(|l| l.1).max().max(self.tied);
        // a loop wholly before the keyframes free from now on joins no later solve
        let start = self.free_from();
        self.loops.retain(|&(i, j, _)| i >= start || j >= start);
    }

    /// The first keyframe free in a solve (see [`LoopCloser::solve`]).
    fn free_from(&self) -> usize {
        self.tied
            .map_or(0, |k| k.saturating_sub(self.cfg.pose_graph_margin))
            .min(self.keyframes.len().saturating_sub(1))
    }

    /// The keyframes' best estimates after [`LoopCloser::optimise`], without keeping them.
    /// The keyframes free in it are those since the map was last made consistent: every
    /// keyframe until a loop has been solved, then those after the newest keyframe a solved
    /// loop tied to the map, less `LoopConfig::pose_graph_margin`. Older keyframes that a
    /// factor of theirs reaches enter held at their current estimate; the others are left as
    /// they are. A new loop then corrects the drift since the last one, as far back as it
    /// goes, and the cost of a solve no longer grows with the run: a replay driven lap after
    /// lap closes a loop at nearly every keyframe, and solving every keyframe and every loop
    /// each time put the back end seconds behind after a few minutes.
    pub(super) fn solve(&self) -> Vec<Sim3> {
        let n = self.keyframes.len();
        let start = self.free_from();
        let info = |rot: f64, trans: f64, scale: f64| {
            let v = [rot, rot, rot, trans, trans, trans, scale];
            nalgebra::SMatrix::<f64, 7, 7>::from_diagonal(&SVector::<f64, 7>::from_fn(|r, _| {
                1.0 / (v[r] * v[r])
            }))
        };
        // the factors that touch a free keyframe: odometry into each, the loops
        let mut odometry = Vec::new();
        for k in start.max(1)..n {
            let z = self.keyframes[k - 1]
                .odom
                .inverse()
                .compose(&self.keyframes[k].odom);
            let step = z.t.norm().max(1e-3);
            // across a loss the tracker's new map is placed and scaled by guesses (the last
            // pose, the median depth): a loop, not this edge, decides where it lies
            let sigmas = if self.keyframes[k].after_gap {
                (0.1, (10.0 * step).max(1.0), 0.5)
            } else {
                (0.002, 0.02 * step, 0.005)
            };
            odometry.push((k - 1, k, z, info(sigmas.0, sigmas.1, sigmas.2)));
        }
        let loops: Vec<_> = self
            .loops
            .iter()
            .filter(|(i, j, _)| *i >= start || *j >= start)
            .map(|(i, j, rel)| {
                let step = rel.t.norm().max(1e-1);
                (*i, *j, *rel, info(0.01, 0.05 * step, 0.02))
            })
            .collect();
        // variables: the free keyframes, then the held ones the factors reach
        let mut keys: Vec<usize> = (start..n).collect();
        let mut held: Vec<usize> = odometry
            .iter()
            .chain(&loops)
            .flat_map(|f| [f.0, f.1])
            .filter(|&k| k < start)
            .collect();
        held.sort_unstable();
        held.dedup();
        keys.extend(&held);
        let slot: std::collections::HashMap<usize, usize> =
            keys.iter().enumerate().map(|(s, &k)| (k, s)).collect();
        let values: Vec<Sim3> = keys.iter().map(|&k| self.keyframes[k].opt).collect();
        let mut graph = PoseGraph::<Sim3, 7>::new((0..keys.len()).collect(), values);
        for (i, j, z, inf) in &odometry {
            if let Ok(f) = Between::new(slot[i], slot[j], *z, inf) {
                graph.between.push(f);
            }
        }
        let first_loop = graph.between.len();
        for (i, j, rel, inf) in &loops {
            if let Ok(f) = Between::new(slot[i], slot[j], *rel, inf) {
                graph.between.push(f);
            }
        }
        // the first keyframe anchors the world; held keyframes stay where they are
        for &k in std::iter::once(&0).filter(|_| start == 0).chain(&held) {
            graph.priors.push(Prior::with_variances(
                slot[&k],
                self.keyframes[k].opt,
                &[1e-8; 7],
            ));
        }
        // Least squares first: from the odometry guess a true loop's residual is as large as
        // the drift, and a robust kernel would discard it. Then Cauchy from that solution, so
        // a loop that disagrees with the others loses its weight.
        for stage in 0..2 {
            if stage == 1 {
                for f in graph.between.iter_mut().skip(first_loop) {
                    f.kernel = Kernel::Cauchy(1.0);
                }
            }
            let Ok(mut lm) = Lm::new(&mut graph, LmParams::default()) else {
                break;
            };
            let summary = lm.optimize();
            tracing::debug!(
                stage,
                free = n - start,
                held = held.len(),
                initial = summary.initial_error,
                last = summary.final_error,
                iterations = summary.iterations,
                "loop pose graph"
            );
        }
        let mut solved: Vec<Sim3> = self.keyframes.iter().map(|k| k.opt).collect();
        for (s, &k) in keys.iter().enumerate().take(n - start) {
            solved[k] = graph.values[s].with_nearest_rotation();
        }
        solved
    }
}

/// The similarity of a reported pose, its rotation projected onto SO(3) (the tracker's poses
/// come back after corrections this module issued: see [`Sim3::with_nearest_rotation`]).
pub(super) fn sim3_of(p: &Pose) -> Sim3 {
    Sim3 {
        r: supermvo_optim::so3::nearest_rotation(&p.r),
        t: p.t,
        s: 1.0,
    }
}

/// The rigid camera pose `T_world_cam` of a similarity world<-camera (the scale only
/// changes positions).
pub fn pose_of(s: &Sim3) -> Pose {
    Pose::new(s.r, s.t)
}
