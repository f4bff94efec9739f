//! Geometric verification of a loop candidate: each keyframe's points triangulated against
//! a nearby keyframe, mutual descriptor matches between the two places, and one similarity
//! between their points (RANSAC, reprojection in both images).

use super::LoopCloser;
use nalgebra::DMatrix;
use supermvo_geometry::essential::triangulate_checked;
use supermvo_geometry::{umeyama, Mat3, Vec3};
use supermvo_optim::lie::{LieGroup, Sim3};

impl LoopCloser {
    /// Triangulates keyframe `k`'s keypoints against the earlier keyframe (of the last
    /// `TRIANGULATION_KEYFRAMES`, of the same map: none before a frame tracking failed on,
    /// where the odometry between them is a guess) with the widest baseline, using the
    /// odometry between them.
    pub(super) fn triangulate(&mut self, k: usize) {
        let cur = &self.keyframes[k];
        let mut points = vec![None; cur.keypoints.len()];
        let map_start = (k.saturating_sub(super::TRIANGULATION_KEYFRAMES)..=k)
            .rev()
            .find(|&m| self.keyframes[m].after_gap)
            .unwrap_or(0);
        let first = k
            .saturating_sub(super::TRIANGULATION_KEYFRAMES)
            .max(map_start);
        let best = (first..k).max_by(|&a, &b| {
            let da = (self.keyframes[a].odom.t - cur.odom.t).norm();
            let db = (self.keyframes[b].odom.t - cur.odom.t).norm();
            da.total_cmp(&db)
        });
        if let Some(m) = best {
            let other = &self.keyframes[m];
            // T_other_cur: maps points of the current camera into the other camera.
            let rel = other.odom.inverse().compose(&cur.odom);
            let (r, t) = (rel.r, rel.t / rel.s);
            let thr = 2.0 / self.calib.fx;
            for (a, b) in mutual_matches(&cur.desc, &other.desc, self.cfg.min_cosine) {
                let (x1, x2) = (
                    self.bearing(&cur.keypoints[a]),
                    self.bearing(&other.keypoints[b]),
                );
                let views = [(Mat3::identity(), Vec3::zeros(), x1), (r, t, x2)];
                let accepted =
                    triangulate_checked(&views, thr).filter(|tri| tri.parallax_deg > 1.0);
                if let Some(tri) = accepted {
                    points[a] = Some(tri.point);
                }
            }
        }
        self.keyframes[k].points = points;
    }

    /// Sim(3) from keyframe `j`'s camera to keyframe `i`'s that best explains their common
    /// points (RANSAC over minimal triples, inliers by reprojection in both images), with its
    /// inlier count when it has enough.
    pub(super) fn verify(&self, i: usize, j: usize) -> Option<(Sim3, usize)> {
        let (a, b) = (&self.keyframes[i], &self.keyframes[j]);
        let pairs: Vec<(usize, usize, Vec3, Vec3)> =
            mutual_matches(&a.desc, &b.desc, self.cfg.min_cosine)
                .into_iter()
                .filter_map(|(ka, kb)| {
                    Some((
                        ka,
                        kb,
                        a.points.get(ka).copied().flatten()?,
                        b.points.get(kb).copied().flatten()?,
                    ))
                })
                .collect();
        tracing::trace!(
            query = b.frame,
            candidate = a.frame,
            pairs = pairs.len(),
            "loop candidate"
        );
        if pairs.len() < self.cfg.min_inliers {
            return None;
        }
        let thr2 = self.cfg.reprojection_px * self.cfg.reprojection_px;
        let inliers_of = |s: &Sim3| -> Vec<usize> {
            let inv = s.inverse();
            pairs
                .iter()
                .enumerate()
                .filter(|(_, (ka, kb, pa, pb))| {
                    let ok = |p: Option<(f64, f64)>, kp: &[f32; 2]| {
                        p.is_some_and(|(u, v)| {
                            (u - kp[0] as f64).powi(2) + (v - kp[1] as f64).powi(2) < thr2
                        })
                    };
                    ok(self.project(&s.transform(pb)), &a.keypoints[*ka])
                        && ok(self.project(&inv.transform(pa)), &b.keypoints[*kb])
                })
                .map(|(n, _)| n)
                .collect()
        };
        let fit = |idx: &[usize]| -> Option<Sim3> {
            let xs: Vec<Vec3> = idx.iter().map(|&n| pairs[n].3).collect();
            let ys: Vec<Vec3> = idx.iter().map(|&n| pairs[n].2).collect();
            let s = umeyama(&xs, &ys, true).ok()?;
            (s.scale.is_finite() && s.scale > 0.0).then(|| Sim3 {
                r: s.rotation_matrix(),
                t: s.translation,
                s: s.scale,
            })
        };
        let mut state = (i as u64) << 32 | j as u64;
        let mut pick = |n: usize| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 33) as usize) % n
        };
        let mut best: Option<(Sim3, Vec<usize>)> = None;
        for _ in 0..300 {
            let s = [pick(pairs.len()), pick(pairs.len()), pick(pairs.len())];
            if s[0] == s[1] || s[1] == s[2] || s[0] == s[2] {
                continue;
            }
            let Some(model) = fit(&s) else { continue };
            let inl = inliers_of(&model);
            if best.as_ref().is_none_or(|b| inl.len() > b.1.len()) {
                best = Some((model, inl));
            }
        }
        let (mut model, mut inliers) = best?;
        tracing::trace!(
            query = b.frame,
            candidate = a.frame,
            pairs = pairs.len(),
            inliers = inliers.len(),
            "loop candidate verified"
        );
        if inliers.len() < self.cfg.min_inliers {
            return None;
        }
        // Refit on the inliers while that explains at least as many points.
        for _ in 0..2 {
            let Some(refit) = fit(&inliers) else { break };
            let inl = inliers_of(&refit);
            if inl.len() < inliers.len() {
                break;
            }
            (model, inliers) = (refit, inl);
        }
        Some((model, inliers.len()))
    }
}

/// Mutually nearest neighbours between two sets of unit descriptors (rows) with cosine
/// similarity at least `min_cos`.
pub(super) fn mutual_matches(
    a: &DMatrix<f32>,
    b: &DMatrix<f32>,
    min_cos: f32,
) -> Vec<(usize, usize)> {
    if a.nrows() == 0 || b.nrows() == 0 {
        return Vec::new();
    }
    // one pass down the columns (nalgebra stores them contiguously): each column's best
    // row, and each row's best column so far; ties go to the lowest index either way
    let sim = a * b.transpose();
    let rows = sim.nrows();
    let (mut row_best, mut row_arg) = (vec![f32::MIN; rows], vec![0u32; rows]);
    let best_a: Vec<usize> = sim
        .as_slice()
        .chunks_exact(rows)
        .enumerate()
        .map(|(j, column)| {
            for ((rb, ra), &v) in row_best.iter_mut().zip(&mut row_arg).zip(column) {
                // a select, not a branch, so that it vectorises
                let better = v > *rb;
                *rb = if better { v } else { *rb };
                *ra = if better { j as u32 } else { *ra };
            }
            first_argmax(column)
        })
        .collect();
    row_arg
        .iter()
        .zip(&row_best)
        .enumerate()
        .filter(|&(i, (&j, &v))| v >= min_cos && best_a[j as usize] == i)
        .map(|(i, (&j, _))| (i, j as usize))
        .collect()
}

/// The index of the first largest value of `v` (0 if empty or all NaN), scanned eight
/// lanes at a time so that it vectorises: each lane keeps its own first maximum, and ties
/// between lanes go to the lowest index.
fn first_argmax(v: &[f32]) -> usize {
    const LANES: usize = 8;
    let (mut best, mut at) = ([f32::MIN; LANES], [0u32; LANES]);
    let chunks = v.chunks_exact(LANES);
    let rest = chunks.remainder();
    for (c, chunk) in chunks.enumerate() {
        for l in 0..LANES {
            let better = chunk[l] > best[l];
            best[l] = if better { chunk[l] } else { best[l] };
            at[l] = if better {
                (c * LANES + l) as u32
            } else {
                at[l]
            };
        }
    }
    let mut winner = (0usize, f32::MIN);
    for l in 0..LANES {
        let i = at[l] as usize;
        if best[l] > winner.1 || (best[l] == winner.1 && best[l] > f32::MIN && i < winner.0) {
            winner = (i, best[l]);
        }
    }
    let tail = v.len() - rest.len();
    for (k, &x) in rest.iter().enumerate() {
        if x > winner.1 {
            winner = (tail + k, x);
        }
    }
    winner.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mutual_matches_pair_equal_rows() {
        let a = DMatrix::<f32>::from_row_slice(3, 2, &[1.0, 0.0, 0.0, 1.0, 0.6, 0.8]);
        let b = DMatrix::<f32>::from_row_slice(2, 2, &[0.0, 1.0, 1.0, 0.0]);
        let m = mutual_matches(&a, &b, 0.9);
        assert_eq!(m, vec![(0, 1), (1, 0)]);
    }

    /// The scan by columns and lanes finds what a plain scan of every row and column finds,
    /// ties (coarse values) and odd sizes included.
    #[test]
    fn mutual_matches_agree_with_a_plain_scan() {
        let mut state = 0x2545_f491u64;
        let mut u = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        for (na, nb, levels) in [(37, 53, 4.0), (64, 64, 1e6), (5, 300, 3.0), (129, 17, 50.0)] {
            let mut quantised =
                |n: usize| DMatrix::<f32>::from_fn(n, 3, |_, _| (u() * levels).round() / levels);
            let (a, b) = (quantised(na), quantised(nb));
            let sim = &a * b.transpose();
            let first_max = |v: Vec<f32>| {
                v.iter()
                    .enumerate()
                    .fold((0, f32::MIN), |m, (i, &x)| if x > m.1 { (i, x) } else { m })
            };
            let plain: Vec<(usize, usize)> = (0..na)
                .filter_map(|i| {
                    let (j, v) = first_max(sim.row(i).iter().copied().collect());
                    let back = first_max(sim.column(j).iter().copied().collect()).0;
                    (v >= 0.1 && back == i).then_some((i, j))
                })
                .collect();
            for column in sim.column_iter() {
                let v: Vec<f32> = column.iter().copied().collect();
                assert_eq!(first_argmax(&v), first_max(v.clone()).0, "{v:?}");
            }
            assert!(!plain.is_empty());
            assert_eq!(mutual_matches(&a, &b, 0.1), plain, "{na} x {nb}");
        }
    }
}
