//! Tracking a frame against the map: PnP on the matches to the reference keyframe's
//! landmarks (or the motion model), the local-map search, the robust final refinement, and
//! the keyframe decision with the new keyframe's observations and re-observations.

use super::frame::bearing;
use super::{FrameMeta, FrameOutput, Tracker, TrackingState};
use supermvo_geometry::pnp::solve_pnp_ransac;
use supermvo_geometry::{Mat3, Vec3};
use supermvo_inference::{Features, Matches};

impl Tracker {
    pub(crate) fn track(
        &mut self,
        input: &FrameMeta,
        cur: Features,
        m: Option<&Matches>,
    ) -> FrameOutput {
        let Some(kf) = self.keyframe.take() else {
            return self.lost(input, cur, 0);
        };
        let Some(m) = m else {
            return self.unusable_reference(input, kf, cur, 0, TrackingState::Lost);
        };
        let with_lm: Vec<(usize, usize, usize)> = m
            .pairs
            .iter()
            .filter_map(|&(a, b)| kf.landmark[a].map(|id| (a, b, id)))
            .collect();
        let pw: Vec<Vec3> = with_lm
            .iter()
            .map(|(_, _, id)| self.map.landmarks[id].p)
            .collect();
        let bw: Vec<Vec3> = with_lm
            .iter()
            .map(|&(_, b, _)| bearing(&self.calib, &cur.keypoints[b]))
            .collect();
        let est = solve_pnp_ransac(&pw, &bw, self.focal(), &self.cfg.pnp)
            .filter(|e| e.inlier_count() >= self.cfg.min_tracked)
            .or_else(|| {
                // the keyframe's landmarks do not suffice: predict the pose with constant
                // velocity and search the whole local map around it
                let (r, t) = self.predict()?;
                tracing::debug!(frame = input.index, "keyframe PnP failed: motion model");
                Some(supermvo_geometry::pnp::PnpEstimate {
                    r,
                    t,
                    inliers: vec![false; pw.len()],
                })
            });
        let Some(est) = est else {
            return self.unusable_reference(input, kf, cur, m.pairs.len(), TrackingState::Lost);
        };
        // the local map: landmarks of the window that this keyframe does not carry
        let mut taken = vec![false; cur.len()];
        let mut skip = std::collections::BTreeSet::new();
        for (k, &(_, b, id)) in with_lm.iter().enumerate() {
            if est.inliers[k] {
                taken[b] = true;
                skip.insert(id);
            }
        }
        // a prediction is coarser than a PnP pose: search twice as far
        let predicted = est.inlier_count() == 0;
        let radius = self.cfg.map_search_radius_px * if predicted { 2.0 } else { 1.0 };
        let from_map = self.search_local_map(&cur, (&est.r, &est.t), &taken, &skip, radius);
        // refine the pose on both sets, re-selecting inliers with the refined pose
        let all_p: Vec<Vec3> = pw
            .iter()
            .copied()
            .chain(from_map.iter().map(|(_, id)| self.map.landmarks[id].p))
            .collect();
        let all_b: Vec<Vec3> = bw
            .iter()
            .copied()
            .chain(
                from_map
                    .iter()
                    .map(|&(b, _)| bearing(&self.calib, &cur.keypoints[b])),
            )
            .collect();
        let thr_sq = (self.cfg.pnp.threshold_px / self.focal()).powi(2);
        let reproj_sq = supermvo_geometry::pnp::reprojection_sq;
        let inliers_at = |r: &Mat3, t: &Vec3| -> Vec<bool> {
            all_p
                .iter()
                .zip(&all_b)
                .map(|(p, b)| reproj_sq(r, t, p, b) < thr_sq)
                .collect()
        };
        let (mut r, mut t) = (est.r, est.t);
        if predicted {
            // motion-model prediction: a PnP RANSAC over the local map's matches
            let Some(e) = solve_pnp_ransac(&all_p, &all_b, self.focal(), &self.cfg.pnp)
                .filter(|e| e.inlier_count() >= self.cfg.min_tracked)
            else {
                return self.unusable_reference(input, kf, cur, m.pairs.len(), TrackingState::Lost);
            };
            (r, t) = (e.r, e.t);
        }
        let mut inlier: Vec<bool> = est
            .inliers
            .iter()
            .copied()
            .chain(std::iter::repeat_n(false, from_map.len()))
            .collect();
        if !from_map.is_empty() {
            for _ in 0..2 {
                let sel: Vec<usize> = (0..all_p.len())
                    .filter(|&i| reproj_sq(&r, &t, &all_p[i], &all_b[i]) < thr_sq)
                    .collect();
                if sel.len() < self.cfg.min_tracked {
                    break;
                }
                let sp: Vec<Vec3> = sel.iter().map(|&i| all_p[i]).collect();
                let sb: Vec<Vec3> = sel.iter().map(|&i| all_b[i]).collect();
                (r, t) = supermvo_geometry::pnp::refine_pose(&r, &t, &sp, &sb, 10);
            }
            inlier = inliers_at(&r, &t);
        }
        if self.cfg.robust_refinement {
            // the final pose: a smooth function of every match, not of the selection above
            let thr = thr_sq.sqrt();
            let (r2, t2) = supermvo_geometry::pnp::refine_pose_robust(
                &r,
                &t,
                &all_p,
                &all_b,
                (0.5 * thr, 3.0 * thr),
                10,
            );
            let inlier2 = inliers_at(&r2, &t2);
            if inlier2.iter().filter(|&&x| x).count() >= self.cfg.min_tracked {
                (r, t, inlier) = (r2, t2, inlier2);
            }
        }
        let tracked = inlier.iter().filter(|&&x| x).count();
        if tracked < self.cfg.min_tracked {
            return self.unusable_reference(input, kf, cur, m.pairs.len(), TrackingState::Lost);
        }
        let map_inliers = inlier[pw.len()..].iter().filter(|&&x| x).count();
        if tracing::enabled!(tracing::Level::DEBUG) {
            let mut errs: Vec<f64> = all_p
                .iter()
                .zip(&all_b)
                .map(|(p, b)| reproj_sq(&r, &t, p, b).sqrt() * self.focal())
                .collect();
            errs.sort_by(f64::total_cmp);
            let median = errs.get(errs.len() / 2).copied().unwrap_or(f64::NAN);
            tracing::debug!(
                frame = input.index,
                matches = m.pairs.len(),
                with_landmark = pw.len(),
                keyframe_inliers = est.inlier_count(),
                map_candidates = from_map.len(),
                map_inliers,
                reprojection_median_px = median,
                "tracked"
            );
        }
        if self.lost_streak > 0 {
            // relocalised: the motion since the last tracked pose spans the failed frames
            tracing::debug!(frame = input.index, after = self.lost_streak, "relocalised");
            self.velocity = None;
            self.lost_streak = 0;
        } else {
            let (lr, lt) = self.last_pose;
            let rv = r * lr.transpose();
            self.velocity = Some((rv, t - rv * lt));
        }
        self.last_pose = (r, t);
        self.frames_since_keyframe += 1;
        // the reference keyframe's established landmarks (seen by 3 or more keyframes, as
        // ORB-SLAM counts them; not the ones it has just triangulated)
        let established = || {
            kf.landmark
                .iter()
                .flatten()
                .filter(|id| self.map.landmarks.get(id).is_some_and(|l| l.obs.len() >= 3))
                .count()
        };
        let need_kf = tracked < self.cfg.keyframe_min_tracked
            || self.frames_since_keyframe >= self.cfg.max_frames_between_keyframes
            || (self.cfg.keyframe_ratio > 0.0
                && (tracked as f64) < self.cfg.keyframe_ratio * established() as f64);
        if !need_kf {
            let out = self.output(
                input,
                TrackingState::Tracking,
                Some((r, t)),
                cur.len(),
                (m.pairs.len(), tracked),
                false,
            );
            self.keyframe = Some(kf);
            return out;
        }
        // new keyframe: keep the inlier landmarks (from the keyframe and from the local
        // map), triangulate the other matches
        let cur_id = self.map.new_keyframe_id(r, t);
        let mut landmark = vec![None; cur.len()];
        let observed = with_lm
            .iter()
            .map(|&(_, b, id)| (b, id))
            .chain(from_map.iter().copied())
            .zip(&inlier)
            .filter(|(_, &ok)| ok)
            .map(|(o, _)| o);
        let mut used = std::collections::BTreeSet::new();
        for (b, id) in observed {
            if landmark[b].is_some() || !used.insert(id) {
                continue;
            }
            landmark[b] = Some(id);
            let obs_b = bearing(&self.calib, &cur.keypoints[b]);
            self.map
                .observe_landmark(id, cur_id, obs_b, cur.descriptor(b));
        }
        if self.cfg.reobserve_max_px > 0.0 {
            let gate = self.cfg.reobserve_max_px / self.focal();
            for (k, &(_, b, id)) in with_lm.iter().enumerate() {
                if inlier[k]
                    || landmark[b].is_some()
                    || used.contains(&id)
                    || reproj_sq(&r, &t, &pw[k], &bw[k]).sqrt() >= gate
                {
                    continue;
                }
                let obs_b = bearing(&self.calib, &cur.keypoints[b]);
                if self
                    .map
                    .reobserve_landmark(id, cur_id, obs_b, cur.descriptor(b))
                {
                    used.insert(id);
                    landmark[b] = Some(id);
                }
            }
        }
        let fresh: Vec<(usize, usize)> = m
            .pairs
            .iter()
            .copied()
            .filter(|&(a, b)| kf.landmark[a].is_none() && landmark[b].is_none())
            .collect();
        let keypoints = cur.len();
        let min_parallax = if tracked < self.cfg.keyframe_min_tracked {
            self.cfg.weak_triangulation_parallax_deg
        } else {
            self.cfg.min_triangulation_parallax_deg
        };
        let fresh = (&fresh[..], min_parallax);
        self.insert_keyframe(&kf, cur, (input.index, cur_id), (r, t), landmark, fresh);
        let counts = (m.pairs.len(), tracked);
        self.output(
            input,
            TrackingState::Tracking,
            Some((r, t)),
            keypoints,
            counts,
            true,
        )
    }
}
