//! What becomes of a frame the tracker cannot pose: while initialising, or for a blind
//! frame (too few keypoints: black, washed out, covered), the reference keyframe stays and
//! the map is kept for the next frame to relocalise on; a frame whose matches reach the
//! reference keyframe but not its map starts a new map from that keyframe, with itself as
//! the second view; any other frame starts a new map from itself, at the last tracked pose.

use super::{FrameMeta, FrameOutput, Keyframe, Tracker, TrackingState};
use supermvo_inference::{Features, Matches};

impl Tracker {
    /// A frame whose matches `m` reach the reference `kf` but do not agree with its map. A
    /// blind frame goes to [`Tracker::unusable_reference`] (relocalisation); otherwise, with
    /// `reinitialise_on_reference`, a new map starts from the reference keyframe, whose pose
    /// is known, and the frame is tried as the second view of its two-view initialisation
    /// at once (posed when it initialises, kept to be posed later when it waits for
    /// parallax); without, the frame itself becomes the reference, at the last tracked pose.
    pub(super) fn tracking_failed(
        &mut self,
        input: &FrameMeta,
        kf: Keyframe,
        cur: Features,
        m: &Matches,
    ) -> FrameOutput {
        let blind = cur.len() < self.cfg.min_tracked;
        if blind || !self.cfg.reinitialise_on_reference {
            return self.unusable_reference(input, kf, cur, m.pairs.len(), TrackingState::Lost);
        }
        tracing::debug!(
            frame = input.index,
            reference = kf.frame,
            matches = m.pairs.len(),
            "tracking failed: a new map from the reference keyframe"
        );
        self.velocity = None;
        self.lost_streak = 0;
        self.unseen = 0;
        let depths = self
            .cfg
            .reinitialise_at_map_scale
            .then(|| self.landmark_depths(&kf));
        self.map.landmarks.clear();
        self.map.tracks.clear();
        self.map.segment_start = self.map.keyframe_poses.len();
        self.last_frame = None;
        self.set_reference(kf.frame, kf.t_cam_world, kf.features);
        self.reference_depths = depths.zip(self.keyframe.as_ref()).map(|(d, k)| (k.id, d));
        self.frames_since_keyframe = 0;
        let mut out = self.initialise(input, cur, Some(m));
        if out.t_world_cam.is_none() {
            out.state = TrackingState::Lost;
        }
        out
    }

    /// Per keypoint of `kf`, the depth in its camera of the landmark it observes, if any.
    fn landmark_depths(&self, kf: &Keyframe) -> Vec<Option<f64>> {
        let t = &kf.t_cam_world;
        kf.landmark
            .iter()
            .map(|id| {
                let p = self.map.landmarks.get(id.as_ref()?)?.p;
                Some((t.r * p + t.t).z).filter(|z| *z > 0.0)
            })
            .collect()
    }

    /// This frame has no pose and the reference `kf` stays: not enough for the two-view
    /// initialisation yet (`Initializing`), or a blind frame while tracking (`Lost`).
    pub(super) fn keep_reference(
        &mut self,
        input: &FrameMeta,
        kf: Keyframe,
        state: TrackingState,
        keypoints: usize,
        counts: (usize, usize),
    ) -> FrameOutput {
        let out = self.output(input, state, None, keypoints, counts, false);
        self.keyframe = Some(kf);
        out
    }

    /// A frame that could not use the reference `kf` (`matches` to it), reported as `state`:
    /// `Initializing` while the reference waits to initialise, `Lost` when tracking against
    /// it failed. A blind frame (fewer keypoints than tracking needs: black, washed out,
    /// covered) says nothing about the reference, which stays: while initialising, and while
    /// tracking for at most `relocalisation_frames` blind frames in a row, with its map, so
    /// that the next frame relocalises on it at the map's scale. Any other frame starts over
    /// from itself at the last known pose.
    pub(super) fn unusable_reference(
        &mut self,
        input: &FrameMeta,
        kf: Keyframe,
        cur: Features,
        matches: usize,
        state: TrackingState,
    ) -> FrameOutput {
        let blind = cur.len() < self.cfg.min_tracked;
        let initialising = state == TrackingState::Initializing;
        if blind && (initialising || self.lost_streak < self.cfg.relocalisation_frames) {
            if !initialising {
                self.lost_streak += 1;
                tracing::debug!(
                    frame = input.index,
                    keypoints = cur.len(),
                    streak = self.lost_streak,
                    "blind frame: keeping the map to relocalise"
                );
            }
            return self.keep_reference(input, kf, state, cur.len(), (matches, 0));
        }
        tracing::debug!(
            frame = input.index,
            reference = kf.frame,
            matches,
            ?state,
            "starting over from this frame"
        );
        self.start_over(input, cur, matches, state)
    }

    /// Lost: re-initialise from this frame at the last known pose.
    pub(super) fn lost(&mut self, input: &FrameMeta, cur: Features, matches: usize) -> FrameOutput {
        self.start_over(input, cur, matches, TrackingState::Lost)
    }

    /// Drops the map and makes this frame the reference at the last known pose, in a new
    /// segment (the next frames initialise against it); the frame itself has no pose and is
    /// reported in `state`.
    pub(super) fn start_over(
        &mut self,
        input: &FrameMeta,
        cur: Features,
        matches: usize,
        state: TrackingState,
    ) -> FrameOutput {
        let out = self.output(input, state, None, cur.len(), (matches, 0), false);
        let t_cam_world = self.last_t_cam_world;
        self.velocity = None;
        self.lost_streak = 0;
        self.unseen = 0;
        self.map.landmarks.clear();
        self.map.tracks.clear();
        self.map.segment_start = self.map.keyframe_poses.len();
        self.set_reference(input.index, t_cam_world, cur);
        self.frames_since_keyframe = 0;
        out
    }
}
