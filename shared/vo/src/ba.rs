//! Local bundle adjustment over a window of keyframes: the one Levenberg-Marquardt driver
//! (Marquardt's rule) on Huber-robust reprojection errors, with the landmarks eliminated by the Schur complement (each point's
//! 3x3 block is inverted; the reduced camera system is dense because windows are small).
//! Keyframes marked fixed fix the gauge (pose and, with two of them, the monocular scale).

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, Vector3};
use std::ops::{AddAssign, SubAssign};
use supermvo_geometry::{so3_exp, Pose, Vec3};
use supermvo_optim::lm::{minimise, LeastSquares, LmParams};
use supermvo_optim::projection::{reprojection, reprojection_residual};
use supermvo_optim::Kernel;

/// One observation: keyframe index (into the window), point index, normalised bearing.
#[derive(Debug, Clone, Copy)]
pub struct Observation {
    /// Keyframe (window index).
    pub kf: usize,
    /// Point index.
    pub point: usize,
    /// Normalised image coordinates `(x, y, 1)`.
    pub bearing: Vec3,
}

/// A local BA problem.
#[derive(Debug, Clone)]
pub struct LocalBa {
    /// `T_cam_world` of each keyframe.
    pub poses: Vec<Pose>,
    /// Whether each keyframe is held fixed.
    pub fixed: Vec<bool>,
    /// Points in the world frame.
    pub points: Vec<Vec3>,
    /// Observations.
    pub observations: Vec<Observation>,
    /// Huber threshold in normalised units (pixels / focal).
    pub huber: f64,
}

/// What became of a local BA given to a [`crate::mapping_solver::MappingSolver`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BaOutcome {
    /// Solved in place: (initial cost, final cost), as [`LocalBa::solve`] returns.
    Solved(f64, f64),
    /// Handed off under this id: the solution comes later, through
    /// `Tracker::apply_local_ba`, while tracking continues.
    Deferred(u64),
}

type Poses = Vec<Pose>;

/// The normal equations of a window: camera blocks (dense, free keyframes only), point
/// blocks, and the camera-point blocks per observation.
struct Normal {
    hcc: DMatrix<f64>,
    gc: DVector<f64>,
    hpp: Vec<Matrix3<f64>>,
    gp: Vec<Vector3<f64>>,
    /// `(camera slot, 6x3 block)` per observation of a free keyframe, grouped by point
    /// (in observation order within a point): point `p`'s are `hcp[first[p]..first[p + 1]]`.
    hcp: Vec<(usize, SMatrix<f64, 6, 3>)>,
    first: Vec<usize>,
}

impl Normal {
    /// Point `p`'s camera-point blocks.
    fn blocks(&self, p: usize) -> &[(usize, SMatrix<f64, 6, 3>)] {
        &self.hcp[self.first[p]..self.first[p + 1]]
    }
}

/// A step: the free keyframes' tangent updates, and each point's update.
struct Step {
    cameras: DVector<f64>,
    points: Vec<Vector3<f64>>,
}

/// The window as a problem of the one least-squares driver, on `(poses, points)`.
struct Window<'a> {
    ba: &'a LocalBa,
    /// Each keyframe's slot among the free ones (`usize::MAX` if fixed).
    slot: Vec<usize>,
    free: Vec<usize>,
}

impl LeastSquares for Window<'_> {
    type State = (Poses, Vec<Vec3>);
    type System = Normal;
    type Step = Step;

    fn cost(&self, (poses, points): &Self::State) -> f64 {
        self.ba.cost(poses, points)
    }

    fn linearize(&mut self, (poses, points): &Self::State) -> Option<Normal> {
        let (np, nc) = (points.len(), self.free.len() * 6);
        let mut n = Normal {
            hcc: DMatrix::zeros(nc, nc),
            gc: DVector::zeros(nc),
            hpp: vec![Matrix3::zeros(); np],
            gp: vec![Vector3::zeros(); np],
            hcp: Vec::new(),
            first: Vec::new(),
        };
        let kernel = Kernel::Huber(self.ba.huber);
        let mut hcp = Vec::new();
        for o in &self.ba.observations {
            let Pose { r, t } = &poses[o.kf];
            let Some(lin) = reprojection(r, t, &points[o.point], &o.bearing) else {
                continue;
            };
            let (e, jp) = (lin.residual, lin.d_point);
            let w = kernel.weight(e.norm_squared());
            n.hpp[o.point] += w * jp.transpose() * jp;
            n.gp[o.point] += w * jp.transpose() * e;
            let slot = self.slot[o.kf];
            if slot == usize::MAX {
                continue;
            }
            let jc = lin.d_pose;
            let s = slot * 6;
            n.hcc
                .fixed_view_mut::<6, 6>(s, s)
                .add_assign(&(w * jc.transpose() * jc));
            n.gc.fixed_rows_mut::<6>(s)
                .add_assign(&(w * jc.transpose() * e));
            hcp.push((o.point, slot, w * jc.transpose() * jp));
        }
        (n.hcp, n.first) = group_by_point(hcp, np);
        Some(n)
    }

    /// Damped by `lambda diag(H)`; the points eliminated by the Schur complement.
    fn solve(&mut self, n: &Normal, lambda: f64) -> Option<Step> {
        let (np, nc) = (n.hpp.len(), n.gc.len());
        // damped point blocks and their inverses
        let hpp_inv: Vec<Matrix3<f64>> = n
            .hpp
            .iter()
            .map(|h| {
                let mut d = *h;
                for k in 0..3 {
                    d[(k, k)] += lambda * h[(k, k)] + 1e-12;
                }
                d.try_inverse().unwrap_or_else(Matrix3::zeros)
            })
            .collect();
        // Schur complement on the cameras
        let mut s = n.hcc.clone();
        for k in 0..nc {
            s[(k, k)] += lambda * n.hcc[(k, k)] + 1e-12;
        }
        let mut rhs = -n.gc.clone();
        for (p, (hi, gp)) in hpp_inv.iter().zip(&n.gp).enumerate() {
            let blocks = n.blocks(p);
            for &(c1, m1) in blocks {
                let m1hi = m1 * hi;
                rhs.fixed_rows_mut::<6>(c1 * 6).add_assign(&(m1hi * gp));
                for &(c2, m2) in blocks {
                    s.fixed_view_mut::<6, 6>(c1 * 6, c2 * 6)
                        .sub_assign(&(m1hi * m2.transpose()));
                }
            }
        }
        let cameras = if nc == 0 {
            DVector::zeros(0)
        } else {
            s.cholesky()?.solve(&rhs)
        };
        // back-substitute the points
        let points = (0..np)
            .map(|p| {
                let mut r = -n.gp[p];
                for &(c, m) in n.blocks(p) {
                    let d = SMatrix::<f64, 6, 1>::from_fn(|k, _| cameras[c * 6 + k]);
                    r -= m.transpose() * d;
                }
                hpp_inv[p] * r
            })
            .collect();
        Some(Step { cameras, points })
    }

    fn retract(&self, (poses, points): &Self::State, step: &Step) -> Self::State {
        let mut new_poses = poses.clone();
        for (sidx, &k) in self.free.iter().enumerate() {
            let d = SMatrix::<f64, 6, 1>::from_fn(|a, _| step.cameras[sidx * 6 + a]);
            let dr = so3_exp(&Vec3::new(d[0], d[1], d[2]));
            let Pose { r, t } = poses[k];
            new_poses[k] = Pose::new(dr * r, dr * t + Vec3::new(d[3], d[4], d[5]));
        }
        let new_points = points
            .iter()
            .zip(&step.points)
            .map(|(p, d)| p + d)
            .collect();
        (new_poses, new_points)
    }
}

/// `(point, camera slot, block)` triples grouped by point, keeping their order within a
/// point: the blocks, and where each point's blocks start (`np + 1` offsets).
fn group_by_point(
    hcp: Vec<(usize, usize, SMatrix<f64, 6, 3>)>,
    np: usize,
) -> (Vec<(usize, SMatrix<f64, 6, 3>)>, Vec<usize>) {
    let mut first = vec![0usize; np + 1];
    for &(p, _, _) in &hcp {
        first[p + 1] += 1;
    }
    for p in 0..np {
        first[p + 1] += first[p];
    }
    let mut next = first.clone();
    let mut grouped = vec![(0, SMatrix::zeros()); hcp.len()];
    for (p, c, m) in hcp {
        grouped[next[p]] = (c, m);
        next[p] += 1;
    }
    (grouped, first)
}

impl LocalBa {
    /// Robust cost (a point behind its camera counts 1).
    pub fn cost(&self, poses: &[Pose], points: &[Vec3]) -> f64 {
        let kernel = Kernel::Huber(self.huber);
        self.observations
            .iter()
            .map(|o| {
                let Pose { r, t } = &poses[o.kf];
                match reprojection_residual(r, t, &points[o.point], &o.bearing) {
                    Some(e) => kernel.loss(e.norm_squared()),
                    None => 1.0,
                }
            })
            .sum()
    }

    /// The window over its free keyframes: each one's slot among them.
    fn free_slots(&self) -> (Vec<usize>, Vec<usize>) {
        let free: Vec<usize> = (0..self.poses.len()).filter(|&k| !self.fixed[k]).collect();
        let mut slot = vec![usize::MAX; self.poses.len()];
        for (s, &k) in free.iter().enumerate() {
            slot[k] = s;
        }
        (free, slot)
    }

    /// Runs up to `iterations` LM iterations; returns (initial cost, final cost).
    pub fn solve(&mut self, iterations: usize) -> (f64, f64) {
        let (free, slot) = self.free_slots();
        let start = (
            std::mem::take(&mut self.poses),
            std::mem::take(&mut self.points),
        );
        let mut window = Window {
            ba: self,
            slot,
            free,
        };
        let params = LmParams::marquardt(1e-4, 1e-9, 6, iterations);
        let ((poses, points), run) = minimise(&mut window, start, params);
        (self.poses, self.points) = (poses, points);
        (run.initial_error, run.final_error)
    }
}

impl LocalBa {
    /// What the window's observations say about the lens: the radial coefficient `k1` (of
    /// normalised coordinates, `x (1 + k1 |x|^2)`) that they ask for beyond the lens they
    /// were undistorted with, at the current state (after [`LocalBa::solve`]). One
    /// Gauss-Newton step on `k1` with the free keyframes and the points re-optimised (their
    /// Schur complement), under the same robust weights. `None` when the window does not
    /// determine it.
    pub fn radial_residual(&self) -> Option<RadialResidual> {
        let (free, slot) = self.free_slots();
        let mut window = Window {
            ba: self,
            slot,
            free,
        };
        let state = (self.poses.clone(), self.points.clone());
        let normal = window.linearize(&state)?;
        let coupling = self.radial_coupling(&window.slot, &normal);
        // H^-1 g and H^-1 H_xk through the window's own Schur solver (it returns -H^-1 g)
        let step = window.solve(&normal, 0.0)?;
        // the same system with the k1 column as its right-hand side
        let column = Normal {
            gc: coupling.camera,
            gp: coupling.point,
            ..normal
        };
        let response = window.solve(&column, 0.0)?;
        let along = |s: &Step| {
            column.gc.dot(&s.cameras)
                + column
                    .gp
                    .iter()
                    .zip(&s.points)
                    .map(|(a, b)| a.dot(b))
                    .sum::<f64>()
        };
        let information = coupling.hkk + along(&response);
        let gradient = coupling.gk + along(&step);
        (information > 0.0 && coupling.observations > 0).then(|| RadialResidual {
            k1: -gradient / information,
            information,
            residual_variance: coupling.weighted_sq / (2.0 * coupling.observations as f64),
        })
    }

    /// The `k1` row of the window's normal equations at its current state.
    fn radial_coupling(&self, slot: &[usize], normal: &Normal) -> RadialCoupling {
        let kernel = Kernel::Huber(self.huber);
        let mut c = RadialCoupling {
            camera: DVector::zeros(normal.gc.len()),
            point: vec![Vector3::zeros(); self.points.len()],
            ..Default::default()
        };
        for o in &self.observations {
            let Pose { r, t } = &self.poses[o.kf];
            let Some(lin) = reprojection(r, t, &self.points[o.point], &o.bearing) else {
                continue;
            };
            let e = lin.residual;
            let w = kernel.weight(e.norm_squared());
            // the projection x = (e + observed) scaled by 1 + k1 |x|^2: d/dk1 = x |x|^2
            let x = nalgebra::Vector2::new(
                e.x + o.bearing.x / o.bearing.z,
                e.y + o.bearing.y / o.bearing.z,
            );
            let jk = x * x.norm_squared();
            c.hkk += w * jk.norm_squared();
            c.gk += w * jk.dot(&e);
            c.weighted_sq += w * e.norm_squared();
            c.observations += 1;
            c.point[o.point] += w * lin.d_point.transpose() * jk;
            if slot[o.kf] != usize::MAX {
                c.camera
                    .fixed_rows_mut::<6>(slot[o.kf] * 6)
                    .add_assign(&(w * lin.d_pose.transpose() * jk));
            }
        }
        c
    }
}

/// The `k1` row of a window's normal equations.
#[derive(Default)]
struct RadialCoupling {
    camera: DVector<f64>,
    point: Vec<Vector3<f64>>,
    hkk: f64,
    gk: f64,
    weighted_sq: f64,
    observations: usize,
}

/// A window's reading of the lens ([`LocalBa::radial_residual`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RadialResidual {
    /// The radial coefficient the window asks for (normalised coordinates).
    pub k1: f64,
    /// Its information (the Schur complement of the normal equations, normalised units).
    pub information: f64,
    /// The weighted squared residual per coordinate (normalised units squared).
    pub residual_variance: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Uniform numbers in [0, 1) from a xorshift generator seeded with `s`.
    fn uniform(mut s: u64) -> impl FnMut() -> f64 {
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    #[test]
    fn recovers_perturbed_window() {
        // 4 cameras moving forward, 60 points; perturb free poses and points, BA must
        // bring the reprojection cost back to (near) zero
        let poses: Vec<Pose> = (0..4)
            .map(|k| {
                Pose::new(
                    so3_exp(&Vec3::new(0.0, 0.02 * k as f64, 0.0)),
                    Vec3::new(0.1 * k as f64, 0.0, -(k as f64)),
                )
            })
            .collect();
        let mut points = Vec::new();
        let mut u = uniform(7u64);
        for _ in 0..60 {
            points.push(Vec3::new(
                u() * 20.0 - 10.0,
                u() * 4.0 - 2.0,
                8.0 + u() * 30.0,
            ));
        }
        let mut obs = Vec::new();
        for (k, Pose { r, t }) in poses.iter().enumerate() {
            for (i, p) in points.iter().enumerate() {
                let q = r * p + t;
                obs.push(Observation {
                    kf: k,
                    point: i,
                    bearing: q / q.z,
                });
            }
        }
        let mut noisy_poses = poses.clone();
        for Pose { r, t } in noisy_poses.iter_mut().skip(2) {
            *r = so3_exp(&Vec3::new(0.003, -0.002, 0.001)) * *r;
            *t += Vec3::new(0.05, -0.03, 0.04);
        }
        let noisy_points: Vec<Vec3> = points
            .iter()
            .enumerate()
            .map(|(i, p)| p + Vec3::new(0.1, -0.05, 0.2) * ((i % 3) as f64 - 1.0))
            .collect();
        let mut ba = LocalBa {
            poses: noisy_poses,
            fixed: vec![true, true, false, false],
            points: noisy_points,
            observations: obs,
            huber: 2.0 / 700.0,
        };
        let (c0, c1) = ba.solve(20);
        assert!(c1 < 1e-6 * c0, "{c0} -> {c1}");
        for (k, Pose { r, t }) in ba.poses.iter().enumerate() {
            assert!(supermvo_geometry::rotation_angle(&(r.transpose() * poses[k].r)) < 1e-6);
            assert!((t - poses[k].t).norm() < 1e-5, "pose {k}");
        }
    }

    /// A turning window observed through a lens with radial coefficient `k1`.
    fn turning_window(k1: f64) -> LocalBa {
        let poses: Vec<Pose> = (0..6)
            .map(|k| {
                let yaw = 0.08 * k as f64;
                let r = so3_exp(&Vec3::new(0.0, yaw, 0.0));
                let centre = Vec3::new(0.3 * k as f64, 0.0, 1.0 * k as f64);
                Pose::new(r, -(r * centre))
            })
            .collect();
        let mut u = uniform(11u64);
        let points: Vec<Vec3> = (0..300)
            .map(|_| Vec3::new(u() * 40.0 - 20.0, u() * 6.0 - 3.0, 8.0 + u() * 40.0))
            .collect();
        let mut observations = Vec::new();
        for (k, Pose { r, t }) in poses.iter().enumerate() {
            for (i, p) in points.iter().enumerate() {
                let q = r * p + t;
                let x = q / q.z;
                let d = 1.0 + k1 * (x.x * x.x + x.y * x.y);
                if q.z > 1.0 && x.x.abs() < 0.9 && x.y.abs() < 0.3 {
                    observations.push(Observation {
                        kf: k,
                        point: i,
                        bearing: Vec3::new(x.x * d, x.y * d, 1.0),
                    });
                }
            }
        }
        LocalBa {
            fixed: (0..poses.len()).map(|k| k < 2).collect(),
            poses,
            points,
            observations,
            huber: 2.0 / 700.0,
        }
    }

    #[test]
    fn a_window_reads_the_lens_residual_it_was_observed_through() {
        for k1 in [0.0, 0.01, -0.02] {
            let mut ba = turning_window(k1);
            ba.solve(20);
            let reading = ba
                .radial_residual()
                .expect("a turning window determines k1");
            assert!(reading.information > 0.0);
            assert!(
                (reading.k1 - k1).abs() < 0.2 * k1.abs() + 1e-6,
                "k1 {k1}: read {}",
                reading.k1
            );
        }
    }
}
