//! The Sim(3) pose graph of keyframes that spreads a loop's correction (scale included)
//! along it, and the conversions between poses and similarities.

use super::LoopCloser;
use nalgebra::SVector;
use supermvo_geometry::Pose;
use supermvo_optim::lie::{LieGroup, Sim3};
use supermvo_optim::{Between, Kernel, Lm, LmParams, PoseGraph, Prior};

impl LoopCloser {
    /// Sim(3) pose graph over every keyframe: odometry between neighbours, the loops (Cauchy
    /// kernel against a wrong one), the first keyframe anchored.
    pub(super) fn optimise(&mut self) {
        let solved = self.solve();
        for (k, v) in self.keyframes.iter_mut().zip(solved) {
            k.opt = v;
        }
        self.unsolved_loops = false;
    }

    /// The keyframes' best estimates after [`LoopCloser::optimise`], without keeping them.
    pub(super) fn solve(&self) -> Vec<Sim3> {
        let n = self.keyframes.len();
        let values: Vec<Sim3> = self.keyframes.iter().map(|k| k.opt).collect();
        let mut graph = PoseGraph::<Sim3, 7>::new((0..n).collect(), values);
        let info = |rot: f64, trans: f64, scale: f64| {
            let v = [rot, rot, rot, trans, trans, trans, scale];
            nalgebra::SMatrix::<f64, 7, 7>::from_diagonal(&SVector::<f64, 7>::from_fn(|r, _| {
                1.0 / (v[r] * v[r])
            }))
        };
        for k in 1..n {
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
            if let Ok(f) = Between::new(k - 1, k, z, &info(sigmas.0, sigmas.1, sigmas.2)) {
                graph.between.push(f);
            }
        }
        let first_loop = graph.between.len();
        for (i, j, rel, _) in &self.loops {
            let step = rel.t.norm().max(1e-1);
            if let Ok(f) = Between::new(*i, *j, *rel, &info(0.01, 0.05 * step, 0.02)) {
                graph.between.push(f);
            }
        }
        graph
            .priors
            .push(Prior::with_variances(0, self.keyframes[0].opt, &[1e-8; 7]));
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
                initial = summary.initial_error,
                last = summary.final_error,
                iterations = summary.iterations,
                "loop pose graph"
            );
        }
        graph
            .values
            .iter()
            .map(Sim3::with_nearest_rotation)
            .collect()
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
