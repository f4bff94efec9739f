//! Tracking between keyframes without the matcher: the last frame's landmarks are projected
//! at the motion model's prediction and matched to the frame's keypoints by descriptor
//! (the last frame's own descriptors, whose appearance is closest); then the same steps as
//! with the matcher's matches (a first pose, the local-map search, the refined pose). A frame
//! that this does not track well enough, or that must become a keyframe, is matched after
//! all and tracked as before: the matcher runs where geometry cannot guide.

use super::tracking::{LandmarkMatches, PoseFit};
use super::{FrameMeta, FrameOutput, Keyframe, Tracker, TrackingState};
use supermvo_geometry::Pose;
use supermvo_inference::Features;

/// The landmarks a tracked frame saw (its pose's inliers) with that frame's descriptor of
/// each: what the next frame is tracked from when it has no matches.
#[derive(Debug, Clone, Default)]
pub(crate) struct LastFrame {
    landmarks: Vec<usize>,
    descriptors: Vec<f32>,
    dim: usize,
}

impl LastFrame {
    /// The inlier landmark matches of a tracked frame.
    pub(super) fn tracked(cur: &Features, lm: &LandmarkMatches, fit: &PoseFit) -> Self {
        let seen = lm
            .pairs
            .iter()
            .zip(&fit.inlier)
            .filter(|(_, &ok)| ok)
            .map(|(&(b, id), _)| (b, id));
        Self::from_pairs(cur, seen)
    }

    /// The landmarks of a keyframe.
    pub(super) fn keyframe(kf: &Keyframe) -> Self {
        let seen = kf
            .landmark
            .iter()
            .enumerate()
            .filter_map(|(b, id)| id.map(|id| (b, id)));
        Self::from_pairs(&kf.features, seen)
    }

    fn from_pairs(cur: &Features, pairs: impl Iterator<Item = (usize, usize)>) -> Self {
        let mut out = Self {
            dim: cur.dim,
            ..Default::default()
        };
        for (b, id) in pairs {
            out.landmarks.push(id);
            out.descriptors.extend_from_slice(cur.descriptor(b));
        }
        out
    }

    /// Landmarks seen.
    pub(super) fn len(&self) -> usize {
        self.landmarks.len()
    }
}

impl Tracker {
    /// Tracks a frame without the matcher (see the module docs) when that suffices: `None`
    /// when the frame must be matched after all, because too few of the last frame's
    /// landmarks were found or agree on a pose, or because it must become a keyframe (its
    /// new landmarks come from the matches); the tracker is then unchanged and the frame
    /// goes to [`Tracker::step`] with its matches. Called only when
    /// [`Tracker::wants_matches`] is false.
    pub fn track_without_matches(
        &mut self,
        input: FrameMeta,
        cur: &Features,
    ) -> Option<FrameOutput> {
        self.note_frame(input.index);
        if self.wants_matches() {
            return None;
        }
        let (kf, last, predicted) = (
            self.keyframe.as_ref()?,
            self.last_frame.as_ref()?,
            self.predict()?,
        );
        let mut matches = self.last_frame_matches(last, cur, &predicted);
        let found = matches.pairs.len();
        let (first, pnp) = self.first_pose(&input, &matches)?;
        self.add_local_map_matches(&mut matches, cur, &first);
        let fit = self.refine_pose(&matches, (&first, &pnp))?;
        let tracked = fit.tracked();
        let due = self.needs_keyframe(kf, tracked, self.frames_since_keyframe + 1);
        tracing::debug!(
            frame = input.index,
            from_last_frame = found,
            tracked,
            keyframe_due = due,
            "tracked by projection"
        );
        if due {
            return None;
        }
        self.update_motion_model(&input, &fit);
        self.last_frame = Some(LastFrame::tracked(cur, &matches, &fit));
        let counts = (found, tracked);
        let out = self.output(
            &input,
            TrackingState::Tracking,
            Some(fit.t_cam_world),
            cur.len(),
            counts,
            false,
        );
        Some(self.finish_output(out))
    }

    /// The last frame's landmarks found in `cur` around their projection at `predicted`
    /// (`T_cam_world`), searched again twice as wide when too few are found.
    fn last_frame_matches(
        &self,
        last: &LastFrame,
        cur: &Features,
        predicted: &Pose,
    ) -> LandmarkMatches {
        let taken = vec![false; cur.len()];
        let search = |radius: f64| {
            let candidates = last.landmarks.iter().enumerate().filter_map(|(k, id)| {
                let lm = self.map.landmarks.get(id)?;
                let desc = last.descriptors.get(k * last.dim..(k + 1) * last.dim)?;
                Some((*id, &lm.p, desc))
            });
            let limits = (radius, self.cfg.map_search_ratio);
            self.match_by_projection(cur, predicted, &taken, candidates, limits)
        };
        let mut pairs = search(self.cfg.projection_radius_px);
        if pairs.len() < self.cfg.min_tracked {
            pairs = search(2.0 * self.cfg.projection_radius_px);
        }
        self.landmark_matches(pairs, cur)
    }
}
