//! The map the tracker builds and reads: landmarks with every keyframe observation and the
//! descriptor of the latest, the keyframes' poses, and the pending tracks (keyframe
//! observations of points without enough parallax for a landmark yet). Keyframes are known
//! by id, the index of their pose; a map segment starts where the last map was dropped.
//!
//! Frames: keyframe poses are `T_cam_world`; landmark positions are in the world frame.

use crate::mapping_solver::{triangulate_views, TriangulationBatch};
use std::cell::Cell;
use std::collections::{BTreeMap, HashMap};
use supermvo_geometry::essential::Triangulated;
use supermvo_geometry::{Pose, Vec3};

/// A map point with every keyframe observation `(keyframe id, bearing)` of it and the
/// descriptor of its latest observation (for the local-map search).
pub(crate) struct Landmark {
    /// Position in the world frame.
    pub(crate) p: Vec3,
    /// `(keyframe id, bearing)` of every observation.
    pub(crate) obs: Vec<(usize, Vec3)>,
    /// Descriptor of the latest observation.
    pub(crate) desc: Vec<f32>,
}

/// What made a landmark (named in its trace event, see [`Map::add_landmark`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum LandmarkSource {
    /// The network's matches between keyframes (a pending track that triangulated).
    Matcher,
    /// Epipolar pairing with an earlier keyframe (`tracker::covisible_triangulation`).
    Covisible,
}

impl LandmarkSource {
    fn as_str(self) -> &'static str {
        match self {
            Self::Matcher => "matcher",
            Self::Covisible => "covisible",
        }
    }
}

/// Landmarks, pending tracks and keyframe poses (see the module docs).
pub(crate) struct Map {
    /// The local map by landmark id: landmarks leave it once none of the last
    /// `local_map_keyframes` keyframes observes them, so memory stays flat on long runs.
    pub(crate) landmarks: BTreeMap<usize, Landmark>,
    next_landmark: usize,
    /// Pending tracks by id: keyframe observations of a point that has no landmark yet.
    pub(crate) tracks: BTreeMap<usize, Vec<(usize, Vec3)>>,
    pub(crate) next_track: usize,
    /// `T_cam_world` of every keyframe, by id (refined by the local BA).
    pub(crate) keyframe_poses: Vec<Pose>,
    /// The frame index of every keyframe, by id.
    keyframe_frames: Vec<usize>,
    /// Keypoints and descriptors of the most recent keyframes, by id, kept for the
    /// triangulation against later keyframes (`tracker::covisible_triangulation`; empty when
    /// it is off).
    pub(crate) keyframe_keypoints: BTreeMap<usize, supermvo_inference::Features>,
    /// Id of the first keyframe of the current map: a loss starts a new map (its scale is
    /// only carried by the median depth), which the local BA and the local-map search keep
    /// apart from the old one.
    pub(crate) segment_start: usize,
    /// Focal length (pixels) that turns the 2 px triangulation gate into bearings.
    focal: f64,
    /// Triangulations computed ahead, elsewhere, for the keyframe being inserted
    /// ([`Map::prefetch`]), by the exact bits of their views.
    prefetched: HashMap<ViewsKey, Option<Triangulated>>,
    /// Triangulations answered from `prefetched`, and computed here while it was set.
    prefetch_use: (Cell<usize>, Cell<usize>),
}

/// The exact bits of a point's views `(keyframe id, bearing)`.
type ViewsKey = Vec<(usize, [u64; 3])>;

fn views_key(obs: &[(usize, Vec3)]) -> ViewsKey {
    obs.iter()
        .map(|(k, b)| (*k, [b.x.to_bits(), b.y.to_bits(), b.z.to_bits()]))
        .collect()
}

impl Map {
    /// An empty map for a camera of focal length `focal` pixels.
    pub(crate) fn new(focal: f64) -> Self {
        Self {
            landmarks: BTreeMap::new(),
            next_landmark: 0,
            tracks: BTreeMap::new(),
            next_track: 0,
            keyframe_poses: Vec::new(),
            keyframe_frames: Vec::new(),
            keyframe_keypoints: BTreeMap::new(),
            segment_start: 0,
            focal,
            prefetched: HashMap::new(),
            prefetch_use: Default::default(),
        }
    }

    /// The triangulations of points with views `queries` `(keyframe id, bearing)`, as a
    /// batch that a [`crate::mapping_solver::MappingSolver`] can compute elsewhere
    /// (`None` when a query names an unknown keyframe).
    pub(crate) fn triangulation_batch(
        &self,
        queries: &[Vec<(usize, Vec3)>],
    ) -> Option<TriangulationBatch> {
        let mut slot: BTreeMap<usize, usize> = BTreeMap::new();
        let mut poses = Vec::new();
        let mut indexed = Vec::with_capacity(queries.len());
        for views in queries {
            let mut q = Vec::with_capacity(views.len());
            for &(k, b) in views {
                let pose = *self.keyframe_poses.get(k)?;
                let next = slot.len();
                let i = *slot.entry(k).or_insert_with(|| {
                    poses.push(pose);
                    next
                });
                q.push((i, b));
            }
            indexed.push(q);
        }
        Some(TriangulationBatch {
            poses,
            queries: indexed,
            max_error: self.max_error(),
        })
    }

    /// Takes the answers to `queries` (computed elsewhere from [`Map::triangulation_batch`]
    /// with the keyframe poses as they are now): until [`Map::end_prefetch`],
    /// [`Map::triangulate_observations`] returns them for those exact views instead of
    /// computing them again.
    pub(crate) fn prefetch(
        &mut self,
        queries: &[Vec<(usize, Vec3)>],
        answers: Vec<Option<Triangulated>>,
    ) {
        self.prefetched = queries.iter().map(|q| views_key(q)).zip(answers).collect();
    }

    /// Forgets the prefetched triangulations (the poses they used are about to change);
    /// how many were used, and how many triangulations were computed here meanwhile.
    pub(crate) fn end_prefetch(&mut self) -> (usize, usize) {
        self.prefetched.clear();
        (self.prefetch_use.0.take(), self.prefetch_use.1.take())
    }

    /// Replaces the bearing of every observation the map holds (landmarks' and pending
    /// tracks') by `f` of it: the camera's lens model changed (`tracker::lens`).
    pub(crate) fn remap_bearings(&mut self, f: impl Fn(&Vec3) -> Vec3) {
        let views = self
            .landmarks
            .values_mut()
            .flat_map(|lm| lm.obs.iter_mut())
            .chain(self.tracks.values_mut().flatten());
        for (_, b) in views {
            *b = f(b);
        }
        self.prefetched.clear();
    }

    fn max_error(&self) -> f64 {
        2.0 / self.focal
    }

    /// Adds a landmark with its keyframe observations `(keyframe id, bearing)` and the
    /// descriptor of the latest, made by `source`; returns its id.
    pub(crate) fn add_landmark(
        &mut self,
        p: Vec3,
        obs: Vec<(usize, Vec3)>,
        desc: &[f32],
        source: LandmarkSource,
    ) -> usize {
        let id = self.next_landmark;
        self.next_landmark += 1;
        self.trace_new_landmark(&p, &obs, source);
        let desc = desc.to_vec();
        self.landmarks.insert(id, Landmark { p, obs, desc });
        id
    }
    /// Adds keyframe `kf_id`'s observation `(bearing, descriptor)` to landmark `id` and
    /// re-triangulates it from all its observations when each still reprojects within 2 px.
    pub(crate) fn observe_landmark(&mut self, id: usize, kf_id: usize, b: Vec3, desc: &[f32]) {
        let Some(lm) = self.landmarks.get_mut(&id) else {
            return;
        };
        lm.obs.push((kf_id, b));
        lm.desc.clear();
        lm.desc.extend_from_slice(desc);
        let fit = self
            .landmarks
            .get(&id)
            .and_then(|lm| self.triangulate_observations(&lm.obs));
        if let (Some(tri), Some(lm)) = (fit, self.landmarks.get_mut(&id)) {
            lm.p = tri.point;
        }
    }
    /// Adds keyframe `kf_id`'s observation of landmark `id` that tracking did not accept
    /// (see `TrackerConfig::reobserve_max_px`) when the landmark, re-triangulated from all its
    /// observations and this one, reprojects within 2 px in every view; then the landmark
    /// takes the new position. Otherwise nothing changes and `false` is returned.
    pub(crate) fn reobserve_landmark(
        &mut self,
        id: usize,
        kf_id: usize,
        b: Vec3,
        desc: &[f32],
    ) -> bool {
        let Some(mut obs) = self.landmarks.get(&id).map(|lm| lm.obs.clone()) else {
            return false;
        };
        obs.push((kf_id, b));
        let (Some(tri), Some(lm)) = (
            self.triangulate_observations(&obs),
            self.landmarks.get_mut(&id),
        ) else {
            return false;
        };
        lm.p = tri.point;
        lm.obs = obs;
        lm.desc.clear();
        lm.desc.extend_from_slice(desc);
        true
    }
    /// The point that keyframe observations `(keyframe id, bearing)` triangulate to when it
    /// lies in front of every view and reprojects within 2 px in each (`None` otherwise, or
    /// when a keyframe is unknown).
    pub(crate) fn triangulate_observations(&self, obs: &[(usize, Vec3)]) -> Option<Triangulated> {
        if !self.prefetched.is_empty() {
            if let Some(answer) = self.prefetched.get(&views_key(obs)) {
                self.prefetch_use.0.set(self.prefetch_use.0.get() + 1);
                return *answer;
            }
            self.prefetch_use.1.set(self.prefetch_use.1.get() + 1);
        }
        triangulate_views(|k| self.keyframe_poses.get(k), obs, self.max_error())
    }
    /// The world point of a track's keyframe observations when it lies in front of every
    /// view, reprojects within 2 px in each and has the configured parallax between the
    /// first and the last view.
    pub(crate) fn triangulate_track(
        &self,
        obs: &[(usize, Vec3)],
        min_parallax_deg: f64,
    ) -> Option<Vec3> {
        self.triangulate_observations(obs)
            .filter(|tri| tri.parallax_deg > min_parallax_deg)
            .map(|tri| tri.point)
    }
    /// Keeps keyframe `id`'s keypoints for later triangulations, dropping those of keyframes
    /// older than the last `keep`.
    pub(crate) fn keep_keypoints(
        &mut self,
        id: usize,
        features: &supermvo_inference::Features,
        keep: usize,
    ) {
        self.keyframe_keypoints.insert(id, features.clone());
        let oldest = (id + 1).saturating_sub(keep);
        self.keyframe_keypoints.retain(|&k, _| k >= oldest);
    }
    /// The covisibility of keyframe `kf`: every other keyframe of the current map segment
    /// that observes a landmark `kf` observes, with how many such landmarks (the weight of
    /// their edge in the covisibility graph), the most shared first (ties: the newer first).
    /// Derived from the landmarks' observations, so it is never out of date.
    pub(crate) fn covisible(&self, kf: usize) -> Vec<(usize, usize)> {
        let mut shared: BTreeMap<usize, usize> = BTreeMap::new();
        for lm in self.landmarks.values() {
            if !lm.obs.iter().any(|(k, _)| *k == kf) {
                continue;
            }
            let mut seen: Vec<usize> = lm
                .obs
                .iter()
                .map(|(k, _)| *k)
                .filter(|&k| k != kf && k >= self.segment_start)
                .collect();
            seen.sort_unstable();
            seen.dedup();
            for k in seen {
                *shared.entry(k).or_default() += 1;
            }
        }
        let mut by_weight: Vec<(usize, usize)> = shared.into_iter().collect();
        by_weight.sort_by(|a, b| b.1.cmp(&a.1).then(b.0.cmp(&a.0)));
        by_weight
    }
    /// Forgets every keyframe (their poses, frames and kept keypoints): the next one
    /// registered is id 0 again.
    pub(crate) fn forget_keyframes(&mut self) {
        self.keyframe_poses.clear();
        self.keyframe_frames.clear();
        self.keyframe_keypoints.clear();
    }
    /// Registers the `T_cam_world` of frame `frame`, a new keyframe, and returns its id.
    pub(crate) fn new_keyframe_id(&mut self, t_cam_world: Pose, frame: usize) -> usize {
        self.keyframe_poses.push(t_cam_world);
        self.keyframe_frames.push(frame);
        self.keyframe_poses.len() - 1
    }
    /// A trace event (target `supermvo::landmarks`) for each new landmark: its source, the
    /// frames of its first and last observation with their bearings, how many keyframes
    /// observe it, and its depth in the last over the distance between the two camera
    /// centres (scale-free, so it can be compared with the ground truth's;
    /// `tools/landmark_depth_check.py`).
    fn trace_new_landmark(&self, p: &Vec3, obs: &[(usize, Vec3)], source: LandmarkSource) {
        if !tracing::enabled!(target: "supermvo::landmarks", tracing::Level::TRACE) {
            return;
        }
        let (Some(&(first, b0)), Some(&(last, b1))) = (obs.first(), obs.last()) else {
            return;
        };
        let (Some(pose0), Some(pose1), Some(first_frame), Some(last_frame)) = (
            self.keyframe_poses.get(first),
            self.keyframe_poses.get(last),
            self.keyframe_frames.get(first),
            self.keyframe_frames.get(last),
        ) else {
            return;
        };
        let baseline = (pose1.inverse().t - pose0.inverse().t).norm();
        let depth = pose1.transform(p).z;
        tracing::trace!(
            target: "supermvo::landmarks",
            source = source.as_str(),
            first_frame,
            last_frame,
            observations = obs.len(),
            first_x = b0.x / b0.z,
            first_y = b0.y / b0.z,
            last_x = b1.x / b1.z,
            last_y = b1.y / b1.z,
            depth_over_baseline = depth / baseline.max(1e-12),
            "new landmark"
        );
    }
}

#[cfg(test)]
mod tests;
