//! Frames seen while the tracker initialises, posed once the map exists. Until the matches
//! to the reference keyframe move far enough for the two-view initialisation, a frame gets
//! no pose (the first 3-5 frames of KITTI 01 and 07); each keeps its matches to the
//! reference, whose keypoints the initialisation then turns into landmarks, so it is posed
//! afterwards exactly as a tracked frame is (PnP RANSAC on its landmark matches, the gate
//! widened for a weak frame, the robust refinement) and reported with the frame that
//! initialised ([`super::FrameOutput::backfilled`]). The reference frame of a new map after
//! a loss is not among them: its pose is the assumed last pose the new map starts from.

use super::lens::bearing;
use super::tracking::{LandmarkMatches, PoseFit};
use super::{FrameMeta, LatePose, Tracker};
use std::collections::{HashMap, VecDeque};
use supermvo_geometry::Vec3;
use supermvo_inference::{Features, Matches};

/// A frame seen while initialising: its index and time, and its matches to the reference
/// keyframe as `(reference keypoint, bearing of the frame's keypoint)`.
pub(super) struct InitialisingFrame {
    meta: FrameMeta,
    pairs: Vec<(usize, Vec3)>,
}

/// The most recent frames seen while initialising (at most `backfill_frames`).
pub(super) type InitialisingFrames = VecDeque<InitialisingFrame>;

impl Tracker {
    /// Keeps a frame that waits for the initialisation (its matches `m` to the reference), so
    /// that it can be posed once the map exists; the oldest goes beyond `backfill_frames`.
    pub(super) fn keep_initialising_frame(
        &mut self,
        meta: &FrameMeta,
        cur: &Features,
        m: &Matches,
    ) {
        if self.cfg.backfill_frames == 0 {
            return;
        }
        let pairs = m
            .pairs
            .iter()
            .map(|&(a, b)| (a, bearing(&self.calib, &cur.keypoints[b])))
            .collect();
        if self.initialising.len() == self.cfg.backfill_frames {
            self.initialising.pop_front();
        }
        self.initialising
            .push_back(InitialisingFrame { meta: *meta, pairs });
    }

    /// Poses the kept initialising frames on the map just built, whose landmarks
    /// `reference_landmarks` gives as `(reference keypoint, landmark id)`; frames too few of
    /// whose matches agree on a pose stay unposed. Forgets the frames.
    pub(super) fn pose_initialising_frames(
        &mut self,
        reference_landmarks: &[(usize, usize)],
    ) -> Vec<LatePose> {
        let frames = std::mem::take(&mut self.initialising);
        let landmark_of: HashMap<usize, usize> = reference_landmarks.iter().copied().collect();
        let mut posed = Vec::new();
        for f in frames {
            let lm = self.initialising_landmark_matches(&f, &landmark_of);
            let fit = self.pose_on_landmarks(&lm);
            tracing::debug!(
                frame = f.meta.index,
                landmark_matches = lm.pairs.len(),
                tracked = fit.as_ref().map_or(0, |f| f.tracked()),
                "initialising frame tried on the new map"
            );
            if let Some(fit) = fit {
                posed.push(LatePose {
                    index: f.meta.index,
                    stamp: f.meta.stamp,
                    t_world_cam: fit.t_cam_world.inverse(),
                });
            }
        }
        posed
    }

    /// A kept frame's matches that reach the new map, `landmark_of` a reference keypoint's
    /// landmark (the frame's pairs are numbered by their position in its kept matches).
    fn initialising_landmark_matches(
        &self,
        f: &InitialisingFrame,
        landmark_of: &HashMap<usize, usize>,
    ) -> LandmarkMatches {
        let (mut pairs, mut points, mut bearings) = (Vec::new(), Vec::new(), Vec::new());
        for (k, (a, b)) in f.pairs.iter().enumerate() {
            let Some((&id, lm)) = landmark_of
                .get(a)
                .and_then(|id| self.map.landmarks.get(id).map(|lm| (id, lm)))
            else {
                continue;
            };
            pairs.push((k, id));
            points.push(lm.p);
            bearings.push(*b);
        }
        LandmarkMatches {
            from_keyframe: pairs.len(),
            pairs,
            points,
            bearings,
        }
    }

    /// The pose a tracked frame would get from these landmark matches: PnP RANSAC (the gate
    /// widened for a weak frame), then the refinement; `None` below `min_tracked` inliers.
    fn pose_on_landmarks(&self, lm: &LandmarkMatches) -> Option<PoseFit> {
        let (est, pnp) = self.pnp_with_weak_gate(lm);
        est.filter(|e| e.inlier_count() >= self.cfg.min_tracked)
            .and_then(|e| self.refine_pose(lm, (&e, &pnp)))
    }
}
