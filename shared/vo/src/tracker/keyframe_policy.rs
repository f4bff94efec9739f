//! The keyframe policy: whether a tracked frame becomes a keyframe, and what it brings to
//! the map when it does (its landmark observations, re-observations of landmarks just
//! outside the PnP gate, and its other matches to the reference as pending tracks or new
//! landmarks).

use super::frame::bearing;
use super::tracking::{LandmarkMatches, PoseFit};
use super::{FrameMeta, FrameOutput, Keyframe, Tracker, TrackingState};
use supermvo_geometry::pnp::reprojection_sq;
use supermvo_geometry::Pose;
use supermvo_inference::{Features, Matches};

impl Tracker {
    /// Whether the frame becomes a keyframe: too few landmarks tracked, too many frames
    /// since the last keyframe, or (when configured) fewer tracked than the ratio of the
    /// reference's established landmarks (seen by 3 or more keyframes, as ORB-SLAM counts
    /// them; not the ones it has just triangulated).
    pub(super) fn needs_keyframe(&self, kf: &Keyframe, tracked: usize, frames: usize) -> bool {
        let established = || {
            kf.landmark
                .iter()
                .flatten()
                .filter(|id| self.map.landmarks.get(id).is_some_and(|l| l.obs.len() >= 3))
                .count()
        };
        tracked < self.cfg.keyframe_min_tracked
            || frames >= self.cfg.max_frames_between_keyframes
            || (self.cfg.keyframe_ratio > 0.0
                && (tracked as f64) < self.cfg.keyframe_ratio * established() as f64)
    }

    /// Makes the frame a keyframe: its inlier landmark matches (from the keyframe and from
    /// the local map) become observations, matches just outside the threshold are tried as
    /// re-observations, and its other matches to the reference extend pending tracks or
    /// triangulate new landmarks.
    pub(super) fn make_keyframe(
        &mut self,
        input: &FrameMeta,
        kf: Keyframe,
        cur: Features,
        m: &Matches,
        (lm, fit): (&LandmarkMatches, &PoseFit),
    ) -> FrameOutput {
        let Pose { r, t } = fit.t_cam_world;
        let tracked = fit.tracked();
        let cur_id = self.map.new_keyframe_id(fit.t_cam_world, input.index);
        let mut landmark = vec![None; cur.len()];
        let observed = lm
            .pairs
            .iter()
            .zip(&fit.inlier)
            .filter(|(_, &ok)| ok)
            .map(|(o, _)| *o);
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
            for k in 0..lm.from_keyframe {
                let (b, id) = lm.pairs[k];
                if fit.inlier[k]
                    || landmark[b].is_some()
                    || used.contains(&id)
                    || reprojection_sq(&r, &t, &lm.points[k], &lm.bearings[k]).sqrt() >= gate
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
        self.insert_keyframe(
            &kf,
            cur,
            (input.index, cur_id),
            fit.t_cam_world,
            landmark,
            fresh,
        );
        let counts = (m.pairs.len(), tracked);
        self.output(
            input,
            TrackingState::Tracking,
            Some(fit.t_cam_world),
            keypoints,
            counts,
            true,
        )
    }
}
