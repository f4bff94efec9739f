//! The keyframe policy: whether a tracked frame becomes a keyframe, and what it brings to
//! the map when it does (its landmark observations, re-observations of landmarks just
//! outside the PnP gate, and its other matches to the reference as pending tracks or new
//! landmarks).

use super::lens::bearing;
use super::tracking::{LandmarkMatches, PoseFit};
use super::{FrameMeta, FrameOutput, Keyframe, Tracker, TrackingState};
use std::collections::BTreeSet;
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
            || self.keyframe_due_by_count(frames)
            || (self.cfg.keyframe_ratio > 0.0
                && (tracked as f64) < self.cfg.keyframe_ratio * established() as f64)
    }

    /// Whether the frame `frames` frames after the last keyframe becomes one whatever it
    /// tracks (`max_frames_between_keyframes`).
    pub(super) fn keyframe_due_by_count(&self, frames: usize) -> bool {
        frames >= self.cfg.max_frames_between_keyframes
    }

    /// Makes the frame a keyframe: its inlier landmark matches (from the keyframe and from
    /// the local map) become observations, matches just outside the threshold are tried as
    /// re-observations, and its other matches to the reference extend pending tracks or
    /// triangulate new landmarks. With a [`crate::mapping_solver::MappingSolver`] set, the
    /// triangulations these steps need are computed there first.
    pub(super) fn make_keyframe(
        &mut self,
        input: &FrameMeta,
        kf: Keyframe,
        cur: Features,
        m: &Matches,
        (lm, fit): (&LandmarkMatches, &PoseFit),
    ) -> FrameOutput {
        let tracked = fit.tracked();
        let cur_id = self.map.new_keyframe_id(fit.t_cam_world, input.index);
        let (mut landmark, mut used) = observed_landmarks(lm, fit, cur.len());
        let reobserve = self.reobservation_candidates(lm, fit, &landmark, &used);
        self.prefetch_triangulations(&kf, &cur, cur_id, m, (&landmark, &reobserve));
        for (b, id) in landmark
            .iter()
            .enumerate()
            .filter_map(|(b, id)| Some((b, (*id)?)))
        {
            let obs_b = bearing(&self.calib, &cur.keypoints[b]);
            self.map
                .observe_landmark(id, cur_id, obs_b, cur.descriptor(b));
        }
        for &(b, id) in &reobserve {
            if landmark[b].is_some() || used.contains(&id) {
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
        let fresh = fresh_matches(&kf, m, &landmark);
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

    /// The landmark matches tried as re-observations `(keypoint, landmark)`: keyframe
    /// matches outside the PnP gate but within `reobserve_max_px` of the projection, whose
    /// keypoint and landmark the inliers left free (in order; each is tried unless an
    /// earlier one took its keypoint or landmark).
    fn reobservation_candidates(
        &self,
        lm: &LandmarkMatches,
        fit: &PoseFit,
        landmark: &[Option<usize>],
        used: &BTreeSet<usize>,
    ) -> Vec<(usize, usize)> {
        if self.cfg.reobserve_max_px <= 0.0 {
            return Vec::new();
        }
        let Pose { r, t } = fit.t_cam_world;
        let gate = self.cfg.reobserve_max_px / self.focal();
        (0..lm.from_keyframe)
            .filter(|&k| {
                let (b, id) = lm.pairs[k];
                !fit.inlier[k]
                    && landmark[b].is_none()
                    && !used.contains(&id)
                    && reprojection_sq(&r, &t, &lm.points[k], &lm.bearings[k]).sqrt() < gate
            })
            .map(|k| lm.pairs[k])
            .collect()
    }

    /// Hands the triangulations that the new keyframe `cur_id` will need to the mapping
    /// solver, if one is set that takes them, and keeps its answers in the map: the
    /// observed landmarks' re-fits, the re-observations' fits and the pending tracks
    /// extended by the fresh matches (all the matches that may be fresh: a successful
    /// re-observation takes a few out). What it did not answer is triangulated here, with
    /// the same result.
    fn prefetch_triangulations(
        &mut self,
        kf: &Keyframe,
        cur: &Features,
        cur_id: usize,
        m: &Matches,
        (landmark, reobserve): (&[Option<usize>], &[(usize, usize)]),
    ) {
        if !self
            .mapping_solver
            .as_ref()
            .is_some_and(|s| s.triangulates())
        {
            return;
        }
        let bearing_b = |b: usize| (cur_id, bearing(&self.calib, &cur.keypoints[b]));
        let with_b = |mut obs: Vec<(usize, supermvo_geometry::Vec3)>, b| {
            obs.push(bearing_b(b));
            obs
        };
        let landmark_views = |id: &usize| self.map.landmarks.get(id).map(|l| l.obs.clone());
        let observed = landmark
            .iter()
            .enumerate()
            .filter_map(|(b, id)| Some(with_b(landmark_views(&(*id)?)?, b)));
        let reobserved = reobserve
            .iter()
            .filter_map(|(b, id)| Some(with_b(landmark_views(id)?, *b)));
        let tracks = fresh_matches(kf, m, landmark).into_iter().map(|(a, b)| {
            let track = kf.track[a].and_then(|id| self.map.tracks.get(&id).cloned());
            let first = || vec![(kf.id, bearing(&self.calib, &kf.features.keypoints[a]))];
            with_b(track.unwrap_or_else(first), b)
        });
        let queries: Vec<_> = observed.chain(reobserved).chain(tracks).collect();
        let Some(batch) = self.map.triangulation_batch(&queries) else {
            return;
        };
        let answers = self
            .mapping_solver
            .as_mut()
            .and_then(|solver| solver.triangulate(&batch));
        match answers.filter(|a| a.len() == queries.len()) {
            Some(answers) => self.map.prefetch(&queries, answers),
            None => self.triangulations.1 += queries.len(),
        }
    }
}

/// The inlier landmark matches that become the keyframe's observations: per keypoint its
/// landmark (the first inlier match of a keypoint and of a landmark wins), and the
/// landmarks taken.
fn observed_landmarks(
    lm: &LandmarkMatches,
    fit: &PoseFit,
    keypoints: usize,
) -> (Vec<Option<usize>>, BTreeSet<usize>) {
    let mut landmark = vec![None; keypoints];
    let mut used = BTreeSet::new();
    let observed = lm.pairs.iter().zip(&fit.inlier).filter(|(_, &ok)| ok);
    for (&(b, id), _) in observed {
        if landmark[b].is_none() && used.insert(id) {
            landmark[b] = Some(id);
        }
    }
    (landmark, used)
}

/// The matches to the reference `kf` that neither side's landmark explains: they extend
/// pending tracks or triangulate new landmarks.
fn fresh_matches(kf: &Keyframe, m: &Matches, landmark: &[Option<usize>]) -> Vec<(usize, usize)> {
    m.pairs
        .iter()
        .copied()
        .filter(|&(a, b)| kf.landmark[a].is_none() && landmark[b].is_none())
        .collect()
}
