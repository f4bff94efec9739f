//! Tracking a frame against the map, as named steps: the matches to the reference
//! keyframe's landmarks, a first pose (PnP on them, or the motion model), the local-map
//! search around it, the pose refined on every landmark match (robustly, last), the motion
//! model, and the keyframe decision ([`super::keyframe_policy`], which also makes the
//! keyframe).

use super::lens::bearing;
use super::projection::LastFrame;
use super::{FrameMeta, FrameOutput, Keyframe, Tracker, TrackingState};
use supermvo_geometry::pnp::{reprojection_sq, solve_pnp_ransac, PnpConfig, PnpEstimate};
use supermvo_geometry::{Pose, Vec3};
use supermvo_inference::{Features, Matches};

/// The frame's matches to landmarks: those through the reference keyframe's matches first,
/// then those the local-map search found, each with the landmark's position and the
/// keypoint's bearing.
pub(super) struct LandmarkMatches {
    /// `(keypoint of the frame, landmark id)`.
    pub(super) pairs: Vec<(usize, usize)>,
    /// How many of `pairs` (the first ones) come through the keyframe's matches (or,
    /// tracking by projection, from the last frame's landmarks).
    pub(super) from_keyframe: usize,
    /// Landmark positions, world frame.
    pub(super) points: Vec<Vec3>,
    /// Keypoint bearings.
    pub(super) bearings: Vec<Vec3>,
}

/// A frame's pose `T_cam_world` and which landmark matches agree with it (within the PnP
/// threshold).
pub(super) struct PoseFit {
    pub(super) t_cam_world: Pose,
    pub(super) inlier: Vec<bool>,
}

impl PoseFit {
    pub(super) fn tracked(&self) -> usize {
        self.inlier.iter().filter(|&&x| x).count()
    }
}

impl Tracker {
    /// Tracks one frame against the reference keyframe and the local map (see the module
    /// docs); a frame that cannot be tracked goes to [`Tracker::unusable_reference`].
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
        let mut matches = self.keyframe_landmark_matches(&kf, &cur, m);
        let Some((first, pnp)) = self.first_pose(input, &matches) else {
            return self.tracking_failed(input, kf, cur, m);
        };
        self.add_local_map_matches(&mut matches, &cur, &first);
        let Some(fit) = self.refine_pose(&matches, (&first, &pnp)) else {
            return self.tracking_failed(input, kf, cur, m);
        };
        self.log_tracked(input, m, &matches, &first, &fit);
        self.update_motion_model(input, &fit);
        let tracked = fit.tracked();
        if !self.needs_keyframe(&kf, tracked, self.frames_since_keyframe) {
            self.last_frame = Some(LastFrame::tracked(&cur, &matches, &fit));
            let counts = (m.pairs.len(), tracked);
            let out = self.output(
                input,
                TrackingState::Tracking,
                Some(fit.t_cam_world),
                cur.len(),
                counts,
                false,
            );
            self.keyframe = Some(kf);
            return out;
        }
        self.make_keyframe(input, kf, cur, m, (&matches, &fit))
    }

    /// The matches to the reference keyframe whose keyframe keypoint carries a landmark.
    fn keyframe_landmark_matches(
        &self,
        kf: &Keyframe,
        cur: &Features,
        m: &Matches,
    ) -> LandmarkMatches {
        let pairs: Vec<(usize, usize)> = m
            .pairs
            .iter()
            .filter_map(|&(a, b)| kf.landmark[a].map(|id| (b, id)))
            .collect();
        self.landmark_matches(pairs, cur)
    }

    /// `(keypoint of cur, landmark id)` pairs with the landmarks' positions and the
    /// keypoints' bearings, all counted as the first set (`from_keyframe`).
    pub(super) fn landmark_matches(
        &self,
        pairs: Vec<(usize, usize)>,
        cur: &Features,
    ) -> LandmarkMatches {
        let points = pairs
            .iter()
            .map(|(_, id)| self.map.landmarks[id].p)
            .collect();
        let bearings = pairs
            .iter()
            .map(|&(b, _)| bearing(&self.calib, &cur.keypoints[b]))
            .collect();
        LandmarkMatches {
            from_keyframe: pairs.len(),
            pairs,
            points,
            bearings,
        }
    }

    /// PnP RANSAC on the keyframe's landmark matches; when too few agree, the motion model's
    /// prediction with no inliers (`None` without a motion model either). Returned with the
    /// PnP settings the frame is tracked with: the configured gate, or, when fewer than
    /// `min_tracked` matches agree within it, the gate widened by `weak_gate_factor` if
    /// that lets more agree (a frame far from its keyframe, where the landmarks' depth
    /// errors show more).
    pub(super) fn first_pose(
        &self,
        input: &FrameMeta,
        lm: &LandmarkMatches,
    ) -> Option<(PnpEstimate, PnpConfig)> {
        let (est, pnp) = self.pnp_with_weak_gate(lm);
        est.filter(|e| e.inlier_count() >= self.cfg.min_tracked)
            .or_else(|| {
                // the keyframe's landmarks do not suffice: predict the pose with constant
                // velocity and search the whole local map around it
                let predicted = self.predict()?;
                tracing::debug!(frame = input.index, "keyframe PnP failed: motion model");
                Some(PnpEstimate {
                    t_cam_world: predicted,
                    inliers: vec![false; lm.points.len()],
                })
            })
            .map(|e| (e, pnp))
    }

    /// PnP RANSAC on `lm` at the configured gate, or at the gate widened by
    /// `weak_gate_factor` when fewer than `min_tracked` matches agree and the wider gate
    /// lets more agree; with the settings used.
    pub(super) fn pnp_with_weak_gate(
        &self,
        lm: &LandmarkMatches,
    ) -> (Option<PnpEstimate>, PnpConfig) {
        let solve = |pnp: &PnpConfig| solve_pnp_ransac(&lm.points, &lm.bearings, self.focal(), pnp);
        let count = |e: &Option<PnpEstimate>| e.as_ref().map_or(0, |e| e.inlier_count());
        let mut pnp = self.cfg.pnp;
        let mut est = solve(&pnp);
        if self.cfg.weak_gate_factor > 1.0 && count(&est) < self.cfg.min_tracked {
            let wide = PnpConfig {
                threshold_px: pnp.threshold_px * self.cfg.weak_gate_factor,
                ..pnp
            };
            let e = solve(&wide);
            if count(&e) > count(&est) {
                (est, pnp) = (e, wide);
            }
        }
        (est, pnp)
    }

    /// Adds the local-map search's matches around `first`: landmarks of the window that the
    /// keyframe's inliers do not already give, to keypoints those inliers do not take.
    pub(super) fn add_local_map_matches(
        &self,
        lm: &mut LandmarkMatches,
        cur: &Features,
        first: &PnpEstimate,
    ) {
        let mut taken = vec![false; cur.len()];
        let mut skip = std::collections::BTreeSet::new();
        for (k, &(b, id)) in lm.pairs.iter().enumerate() {
            if first.inliers[k] {
                taken[b] = true;
                skip.insert(id);
            }
        }
        // a prediction is coarser than a PnP pose: search twice as far
        let predicted = first.inlier_count() == 0;
        let radius = self.cfg.map_search_radius_px * if predicted { 2.0 } else { 1.0 };
        let from_map = self.search_local_map(cur, &first.t_cam_world, &taken, &skip, radius);
        for &(b, id) in &from_map {
            lm.pairs.push((b, id));
            lm.points.push(self.map.landmarks[&id].p);
        }
        lm.bearings.extend(
            from_map
                .iter()
                .map(|&(b, _)| bearing(&self.calib, &cur.keypoints[b])),
        );
    }

    /// The pose refined on every landmark match: after a motion-model prediction a PnP
    /// RANSAC over them all; then two rounds of refinement on the matches within the PnP
    /// threshold; last, when configured, the robust refinement on every match. `None` when
    /// fewer than `min_tracked` matches agree.
    pub(super) fn refine_pose(
        &self,
        lm: &LandmarkMatches,
        (first, pnp): (&PnpEstimate, &PnpConfig),
    ) -> Option<PoseFit> {
        let (all_p, all_b) = (&lm.points, &lm.bearings);
        let from_map = lm.pairs.len() - lm.from_keyframe;
        let thr_sq = (pnp.threshold_px / self.focal()).powi(2);
        let agrees = |pose: &Pose, i: usize| {
            reprojection_sq(&pose.r, &pose.t, &all_p[i], &all_b[i]) < thr_sq
        };
        let inliers_at =
            |pose: &Pose| -> Vec<bool> { (0..all_p.len()).map(|i| agrees(pose, i)).collect() };
        let mut t_cam_world = first.t_cam_world;
        if first.inlier_count() == 0 {
            // motion-model prediction: a PnP RANSAC over the local map's matches
            let e = solve_pnp_ransac(all_p, all_b, self.focal(), pnp)
                .filter(|e| e.inlier_count() >= self.cfg.min_tracked)?;
            t_cam_world = e.t_cam_world;
        }
        let mut inlier: Vec<bool> = first
            .inliers
            .iter()
            .copied()
            .chain(std::iter::repeat_n(false, from_map))
            .collect();
        if from_map > 0 {
            // refine the pose on both sets, re-selecting inliers with the refined pose
            for _ in 0..2 {
                let sel: Vec<usize> = (0..all_p.len())
                    .filter(|&i| agrees(&t_cam_world, i))
                    .collect();
                if sel.len() < self.cfg.min_tracked {
                    break;
                }
                let sp: Vec<Vec3> = sel.iter().map(|&i| all_p[i]).collect();
                let sb: Vec<Vec3> = sel.iter().map(|&i| all_b[i]).collect();
                t_cam_world = supermvo_geometry::pnp::refine_pose(&t_cam_world, &sp, &sb, 10);
            }
            inlier = inliers_at(&t_cam_world);
        }
        if self.cfg.robust_refinement {
            // the final pose: a smooth function of every match, not of the selection above
            let thr = thr_sq.sqrt();
            let robust = supermvo_geometry::pnp::refine_pose_robust(
                &t_cam_world,
                all_p,
                all_b,
                (0.5 * thr, self.cfg.robust_cutoff_factor * thr),
                10,
            );
            let inlier2 = inliers_at(&robust);
            if inlier2.iter().filter(|&&x| x).count() >= self.cfg.min_tracked {
                (t_cam_world, inlier) = (robust, inlier2);
            }
        }
        let fit = PoseFit {
            t_cam_world,
            inlier,
        };
        (fit.tracked() >= self.cfg.min_tracked).then_some(fit)
    }

    /// The debug log line of a tracked frame (match counts, inliers, median reprojection).
    fn log_tracked(
        &self,
        input: &FrameMeta,
        m: &Matches,
        lm: &LandmarkMatches,
        first: &PnpEstimate,
        fit: &PoseFit,
    ) {
        if !tracing::enabled!(tracing::Level::DEBUG) {
            return;
        }
        let mut errs: Vec<f64> = lm
            .points
            .iter()
            .zip(&lm.bearings)
            .map(|(p, b)| {
                reprojection_sq(&fit.t_cam_world.r, &fit.t_cam_world.t, p, b).sqrt() * self.focal()
            })
            .collect();
        errs.sort_by(f64::total_cmp);
        let median = errs.get(errs.len() / 2).copied().unwrap_or(f64::NAN);
        tracing::debug!(
            frame = input.index,
            matches = m.pairs.len(),
            with_landmark = lm.from_keyframe,
            keyframe_inliers = first.inlier_count(),
            map_candidates = lm.pairs.len() - lm.from_keyframe,
            map_inliers = fit.inlier[lm.from_keyframe..]
                .iter()
                .filter(|&&x| x)
                .count(),
            reprojection_median_px = median,
            "tracked"
        );
    }

    /// The frame's pose becomes the last pose; the motion since the last tracked one the
    /// constant-velocity model, per frame when frames were dropped before this one (after a
    /// relocalisation the gap spans failed frames, so the model starts again).
    pub(super) fn update_motion_model(&mut self, input: &FrameMeta, fit: &PoseFit) {
        let Pose { r, t } = fit.t_cam_world;
        if self.lost_streak > 0 {
            // relocalised: the motion since the last tracked pose spans the failed frames
            tracing::debug!(frame = input.index, after = self.lost_streak, "relocalised");
            self.velocity = None;
            self.lost_streak = 0;
        } else {
            let last = self.last_t_cam_world;
            let rv = r * last.r.transpose();
            let tv = t - rv * last.t;
            self.velocity = Some(if self.unseen == 0 {
                Pose::new(rv, tv)
            } else {
                // frames dropped upstream: the motion per frame over the gap
                let steps = (self.unseen + 1) as f64;
                let r_step = supermvo_geometry::so3_exp(&(supermvo_geometry::so3_log(&rv) / steps));
                Pose::new(r_step, tv / steps)
            });
        }
        self.unseen = 0;
        self.last_t_cam_world = fit.t_cam_world;
        self.frames_since_keyframe += 1;
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)] // test code
    use super::*;
    use crate::tracker::TrackerConfig;
    use supermvo_dataset::Calibration;
    use supermvo_geometry::Mat3;

    /// 60 landmarks 10-40 m ahead of a camera at the origin; the keypoints of 54 of them lie
    /// 2.4 px from their projections in scattered directions (beyond the 2 px gate, within
    /// 1.5 times it), those of the other 6 on them.
    fn matches() -> LandmarkMatches {
        let (mut points, mut bearings) = (Vec::new(), Vec::new());
        for i in 0..60 {
            let a = i as f64 * 2.399; // golden-angle spiral: spread, deterministic
            let z = 10.0 + 30.0 * (i as f64 / 60.0);
            let p = Vec3::new(0.6 * z * a.cos() * 0.5, 0.2 * z * a.sin() * 0.5, z);
            let off = if i % 10 == 0 { 0.0 } else { 2.4 / 700.0 };
            let ang = ((i * i * 7919 + 13 * i) % 360) as f64 * std::f64::consts::PI / 180.0;
            bearings.push(Vec3::new(
                p.x / p.z + off * ang.cos(),
                p.y / p.z + off * ang.sin(),
                1.0,
            ));
            points.push(p);
        }
        LandmarkMatches {
            pairs: (0..60).map(|i| (i, i)).collect(),
            from_keyframe: 60,
            points,
            bearings,
        }
    }

    fn tracker(weak_gate_factor: f64) -> Tracker {
        let calib = Calibration {
            fx: 700.0,
            fy: 700.0,
            cx: 620.0,
            cy: 188.0,
        };
        Tracker::new(
            calib,
            TrackerConfig {
                weak_gate_factor,
                ..TrackerConfig::default()
            },
        )
    }

    /// Fewer than `min_tracked` (40) matches within the 2 px gate: the frame is tracked
    /// with the gate widened to 3 px, where (nearly) all agree; without widening (and
    /// without a motion model to fall back on) it has no pose.
    #[test]
    fn a_weak_frame_is_tracked_with_the_gate_widened() {
        let meta = FrameMeta {
            index: 7,
            stamp: 0.7,
        };
        let lm = matches();
        let (est, pnp) = tracker(1.5).first_pose(&meta, &lm).unwrap();
        assert_eq!(pnp.threshold_px, 3.0);
        assert!(est.inlier_count() >= 40, "{} inliers", est.inlier_count());
        let fit = tracker(1.5).refine_pose(&lm, (&est, &pnp)).unwrap();
        assert!(fit.tracked() >= 55, "{} tracked", fit.tracked());
        // measured: 48 PnP inliers, 60 after the refinement, 7 cm from the true position
        let Pose { r, t } = fit.t_cam_world;
        assert!(t.norm() < 0.15 && (r - Mat3::identity()).norm() < 5e-3);
        assert!(tracker(1.0).first_pose(&meta, &lm).is_none());
    }
}
