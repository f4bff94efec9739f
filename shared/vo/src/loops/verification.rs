//! Geometric verification of a loop candidate: each keyframe's points triangulated against
//! a nearby keyframe, mutual descriptor matches between the two places, and one similarity
//! between their points (RANSAC, reprojection in both images).

use super::mutual_nearest::{mutual_matches, mutual_matches_among};
use super::LoopCloser;
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
        // only keypoints with a point on both sides can pair
        let with_point = |k: &super::KeyframeEntry| -> Vec<usize> {
            (0..k.desc.nrows())
                .filter(|&n| k.points.get(n).copied().flatten().is_some())
                .collect()
        };
        let pairs: Vec<(usize, usize, Vec3, Vec3)> = mutual_matches_among(
            (&a.desc, &with_point(a)),
            (&b.desc, &with_point(b)),
            self.cfg.min_cosine,
        )
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
