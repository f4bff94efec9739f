//! Local bundle adjustment over a window of keyframes: Levenberg-Marquardt on Huber-robust
//! reprojection errors, with the landmarks eliminated by the Schur complement (each point's
//! 3x3 block is inverted; the reduced camera system is dense because windows are small).
//! Keyframes marked fixed fix the gauge (pose and, with two of them, the monocular scale).

use nalgebra::{DMatrix, DVector, Matrix2x3, Matrix3, SMatrix, Vector2, Vector3};
use supermvo_geometry::{skew, so3_exp, Mat3, Vec3};

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
    pub poses: Vec<(Mat3, Vec3)>,
    /// Whether each keyframe is held fixed.
    pub fixed: Vec<bool>,
    /// Points in the world frame.
    pub points: Vec<Vec3>,
    /// Observations.
    pub observations: Vec<Observation>,
    /// Huber threshold in normalised units (pixels / focal).
    pub huber: f64,
}

fn residual(r: &Mat3, t: &Vec3, p: &Vec3, b: &Vec3) -> Option<(Vector2<f64>, Vector3<f64>)> {
    let q = r * p + t;
    (q.z > 1e-6).then(|| {
        (
            Vector2::new(q.x / q.z - b.x / b.z, q.y / q.z - b.y / b.z),
            q,
        )
    })
}

impl LocalBa {
    fn huber_weight(&self, e2: f64) -> f64 {
        let e = e2.sqrt();
        if e <= self.huber {
            1.0
        } else {
            self.huber / e
        }
    }

    /// Robust cost.
    pub fn cost(&self, poses: &[(Mat3, Vec3)], points: &[Vec3]) -> f64 {
        self.observations
            .iter()
            .map(|o| {
                let (r, t) = &poses[o.kf];
                match residual(r, t, &points[o.point], &o.bearing) {
                    Some((e, _)) => {
                        let (s2, k) = (e.norm_squared(), self.huber);
                        if s2.sqrt() <= k {
                            0.5 * s2
                        } else {
                            k * s2.sqrt() - 0.5 * k * k
                        }
                    }
                    None => 1.0,
                }
            })
            .sum()
    }

    /// Runs up to `iterations` LM iterations; returns (initial cost, final cost).
    pub fn solve(&mut self, iterations: usize) -> (f64, f64) {
        let free: Vec<usize> = (0..self.poses.len()).filter(|&k| !self.fixed[k]).collect();
        let mut slot = vec![usize::MAX; self.poses.len()];
        for (s, &k) in free.iter().enumerate() {
            slot[k] = s;
        }
        let nc = free.len() * 6;
        let initial = self.cost(&self.poses, &self.points);
        let mut current = initial;
        let mut lambda = 1e-4;
        for _ in 0..iterations {
            let np = self.points.len();
            let mut hcc = DMatrix::<f64>::zeros(nc, nc);
            let mut gc = DVector::<f64>::zeros(nc);
            let mut hpp = vec![Matrix3::<f64>::zeros(); np];
            let mut gp = vec![Vector3::<f64>::zeros(); np];
            // Hcp blocks per observation (6x3)
            let mut hcp: Vec<(usize, usize, SMatrix<f64, 6, 3>)> = Vec::new();
            for o in &self.observations {
                let (r, t) = &self.poses[o.kf];
                let Some((e, q)) = residual(r, t, &self.points[o.point], &o.bearing) else {
                    continue;
                };
                let w = self.huber_weight(e.norm_squared());
                let (iz, iz2) = (1.0 / q.z, 1.0 / (q.z * q.z));
                let dpi = Matrix2x3::new(iz, 0.0, -q.x * iz2, 0.0, iz, -q.y * iz2);
                let jp = dpi * r;
                hpp[o.point] += w * jp.transpose() * jp;
                gp[o.point] += w * jp.transpose() * e;
                if slot[o.kf] == usize::MAX {
                    continue;
                }
                let mut dq = SMatrix::<f64, 3, 6>::zeros();
                dq.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-skew(&q)));
                dq.fixed_view_mut::<3, 3>(0, 3).copy_from(&Mat3::identity());
                let jc = dpi * dq;
                let s = slot[o.kf] * 6;
                let hb = w * jc.transpose() * jc;
                let gb = w * jc.transpose() * e;
                for a in 0..6 {
                    gc[s + a] += gb[a];
                    for b in 0..6 {
                        hcc[(s + a, s + b)] += hb[(a, b)];
                    }
                }
                hcp.push((slot[o.kf], o.point, w * jc.transpose() * jp));
            }
            let mut improved = false;
            for _ in 0..6 {
                // damped point blocks and their inverses
                let mut hpp_inv = Vec::with_capacity(np);
                for h in &hpp {
                    let mut d = *h;
                    for k in 0..3 {
                        d[(k, k)] += lambda * h[(k, k)] + 1e-12;
                    }
                    hpp_inv.push(d.try_inverse().unwrap_or_else(Matrix3::zeros));
                }
                // Schur complement on the cameras
                let mut s = hcc.clone();
                for k in 0..nc {
                    s[(k, k)] += lambda * hcc[(k, k)] + 1e-12;
                }
                let mut rhs = -gc.clone();
                let mut by_point: Vec<Vec<(usize, SMatrix<f64, 6, 3>)>> = vec![Vec::new(); np];
                for &(c, p, ref m) in &hcp {
                    by_point[p].push((c, *m));
                }
                for p in 0..np {
                    let hi = hpp_inv[p];
                    for &(c1, m1) in &by_point[p] {
                        let m1hi = m1 * hi;
                        let r1 = m1hi * gp[p];
                        for k in 0..6 {
                            rhs[c1 * 6 + k] += r1[k];
                        }
                        for &(c2, m2) in &by_point[p] {
                            let blk = m1hi * m2.transpose();
                            for a in 0..6 {
                                for b in 0..6 {
                                    s[(c1 * 6 + a, c2 * 6 + b)] -= blk[(a, b)];
                                }
                            }
                        }
                    }
                }
                let dc = if nc == 0 {
                    DVector::zeros(0)
                } else {
                    match s.clone().cholesky() {
                        Some(ch) => ch.solve(&rhs),
                        None => {
                            lambda *= 10.0;
                            continue;
                        }
                    }
                };
                // back-substitute the points
                let mut new_points = self.points.clone();
                for p in 0..np {
                    let mut r = -gp[p];
                    for &(c, m) in &by_point[p] {
                        let d = SMatrix::<f64, 6, 1>::from_fn(|k, _| dc[c * 6 + k]);
                        r -= m.transpose() * d;
                    }
                    new_points[p] += hpp_inv[p] * r;
                }
                let mut new_poses = self.poses.clone();
                for (sidx, &k) in free.iter().enumerate() {
                    let d = SMatrix::<f64, 6, 1>::from_fn(|a, _| dc[sidx * 6 + a]);
                    let dr = so3_exp(&Vec3::new(d[0], d[1], d[2]));
                    let (r, t) = self.poses[k];
                    new_poses[k] = (dr * r, dr * t + Vec3::new(d[3], d[4], d[5]));
                }
                let c2 = self.cost(&new_poses, &new_points);
                if c2 < current {
                    self.poses = new_poses;
                    self.points = new_points;
                    current = c2;
                    lambda = (lambda * 0.1).max(1e-9);
                    improved = true;
                    break;
                }
                lambda *= 10.0;
            }
            if !improved {
                break;
            }
        }
        (initial, current)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_perturbed_window() {
        // 4 cameras moving forward, 60 points; perturb free poses and points, BA must
        // bring the reprojection cost back to (near) zero
        let poses: Vec<(Mat3, Vec3)> = (0..4)
            .map(|k| {
                (
                    so3_exp(&Vec3::new(0.0, 0.02 * k as f64, 0.0)),
                    Vec3::new(0.1 * k as f64, 0.0, -(k as f64)),
                )
            })
            .collect();
        let mut points = Vec::new();
        let mut s = 7u64;
        let mut u = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..60 {
            points.push(Vec3::new(
                u() * 20.0 - 10.0,
                u() * 4.0 - 2.0,
                8.0 + u() * 30.0,
            ));
        }
        let mut obs = Vec::new();
        for (k, (r, t)) in poses.iter().enumerate() {
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
        for (r, t) in noisy_poses.iter_mut().skip(2) {
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
        for (k, (r, t)) in ba.poses.iter().enumerate() {
            assert!(supermvo_geometry::rotation_angle(&(r.transpose() * poses[k].0)) < 1e-6);
            assert!((t - poses[k].1).norm() < 1e-5, "pose {k}");
        }
    }
}
