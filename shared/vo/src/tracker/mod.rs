//! The monocular tracker: two-view initialisation; between keyframes, tracking of the last
//! frame's landmarks found by projection at the constant-velocity prediction; for keyframes
//! (and frames that projection does not track), PnP against the reference keyframe's
//! landmarks through the matcher's matches (or, when those fail, the prediction); either
//! way followed by a search of the local map by projection; keyframes whose unmatched
//! matches extend pending tracks until they triangulate with enough parallax; a local
//! bundle adjustment with older keyframes as fixed anchors; after a blind frame (too few
//! keypoints) the next frame is tracked against the map kept for it (relocalisation), and
//! any other failure re-initialises.
//!
//! The tracker's own matching (by projection) is a descriptor comparison within a few
//! pixels of a projection, done here because it needs the map; the networks' matches to
//! the reference keyframe come from outside.
//!
//! Frames: `T_cam_world` maps world points into the camera; outputs carry `T_world_cam`.
//! The world frame is the first keyframe's camera; the scale is fixed by the first
//! two-view initialisation (unit baseline) and carried by the landmarks afterwards.
//! A local bundle adjustment refines the last keyframes and their landmarks.
//!
//! The tracker neither detects nor runs the matcher: a frame is first offered without
//! matches ([`Tracker::track_without_matches`]: the last frame's landmarks found by
//! projection, [`projection`]); where that does not suffice or the frame becomes a keyframe,
//! or where [`Tracker::wants_matches`] says so (initialising, after a loss), it comes with
//! its matches to the reference keyframe ([`Tracker::reference`], [`Tracker::step`]).
//! [`Tracker::track_frame`] does both with a matcher callback, as
//! [`crate::pipeline::VoPipeline`] does in process; in the daemon the matches arrive from the
//! matching process on request, and the results are identical because the tracker sees
//! exactly the same numbers.
//!
//! Where each part lives: the map it builds ([`crate::map`]), the settings ([`config`]), the
//! per-frame types ([`frame`]), two-view initialisation ([`initialisation`]) and the frames
//! seen meanwhile, posed once the map exists ([`initialising_frames`]), tracking a
//! frame with matches ([`tracking`]), the keyframe decision and what a keyframe adds to the
//! map ([`keyframe_policy`]), tracking one without
//! ([`projection`]), matching by projection ([`map_search`]), what becomes of a frame that
//! cannot be posed ([`recovery`]: the reference kept, relocalisation, a new map), the
//! local bundle adjustment ([`local_ba`]) and the lens it reads and learns ([`lens`]); this
//! file holds the tracker's state, the keyframe insertion and the per-frame entry points
//! between them.

mod config;
mod covisible_triangulation;
mod frame;
mod initialisation;
mod initialising_frames;
mod keyframe_policy;
mod lens;
mod local_ba;
mod map_search;
mod projection;
mod recovery;
mod tracking;
mod world_updates;

pub use config::TrackerConfig;
pub use frame::{FrameInput, FrameMeta, FrameOutput, LatePose, TrackingState};
pub use lens::LensResidual;
pub(crate) use lens::{bearing, Lens};
pub use local_ba::BaStats;

use crate::map::Map;
use supermvo_dataset::Calibration;
use supermvo_geometry::Pose;
use supermvo_inference::{Features, Matches};

/// The reference keyframe: its features, and per keypoint its landmark or pending track.
struct Keyframe {
    id: usize,
    /// Frame index of the keyframe.
    frame: usize,
    t_cam_world: Pose,
    features: Features,
    landmark: Vec<Option<usize>>,
    /// Per keypoint, the pending track (observations still without enough parallax) it
    /// continues, if any.
    track: Vec<Option<usize>>,
}

/// The tracker (see module docs).
pub struct Tracker {
    calib: Lens,
    cfg: TrackerConfig,
    /// Landmarks, pending tracks and keyframe poses.
    map: Map,
    keyframe: Option<Keyframe>,
    frames_since_keyframe: usize,
    /// `T_cam_world` of the last tracked frame: the reference used to re-initialise after a
    /// loss, so the trajectory continues in one frame.
    last_t_cam_world: Pose,
    /// Motion between the last two tracked frames, `T_last_prev`: the constant-velocity
    /// prediction used when the keyframe matches fail.
    velocity: Option<Pose>,
    /// Blind frames in a row for which the map was kept (relocalisation).
    lost_streak: usize,
    /// The index of the last frame handed to the tracker, and how many frames since the
    /// last tracked one never reached it (dropped upstream by a real-time pipeline): the
    /// motion model spans them.
    last_index: Option<usize>,
    unseen: usize,
    /// The last local BA, until taken.
    last_ba: Option<BaStats>,
    /// The local BAs' readings of the lens (`TrackerConfig::lens_check`,
    /// `lens_self_calibration`).
    lens_readings: lens::LensReadings,
    /// Scale of the map (median landmark depth at initialisation), to carry across
    /// re-initialisations.
    scale: Option<f64>,
    /// When tracking failed against a reference keyframe that keeps serving as the new
    /// map's first view: its id and, per keypoint, the depth of the old map's landmark it
    /// saw (`TrackerConfig::reinitialise_at_map_scale`).
    reference_depths: Option<(usize, Vec<Option<f64>>)>,
    /// The landmarks the last frame saw, when it was tracked: what the next frame is
    /// tracked from by projection when it comes without matches.
    last_frame: Option<projection::LastFrame>,
    /// Frames seen while initialising against the current reference, posed once the map
    /// exists.
    initialising: initialising_frames::InitialisingFrames,
    /// Where the local mapping's triangulations and BA run (`None`: here), and the window
    /// handed off, if any.
    mapping_solver: Option<Box<dyn crate::mapping_solver::MappingSolver>>,
    pending_ba: Option<local_ba::PendingBa>,
    /// Keyframe triangulations answered by the mapping solver, and computed here although
    /// one was set (it declined, or a view changed after it was asked).
    triangulations: (usize, usize),
}

impl std::fmt::Debug for Tracker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Tracker({} landmarks)", self.map.landmarks.len())
    }
}

impl Tracker {
    /// A tracker for the given left-camera calibration.
    pub fn new(calib: Calibration, cfg: TrackerConfig) -> Self {
        Self {
            calib: Lens::from(calib),
            cfg,
            map: Map::new(0.5 * (calib.fx + calib.fy)),
            keyframe: None,
            frames_since_keyframe: 0,
            last_t_cam_world: Pose::identity(),
            velocity: None,
            lost_streak: 0,
            last_index: None,
            unseen: 0,
            last_ba: None,
            lens_readings: Default::default(),
            scale: None,
            reference_depths: None,
            last_frame: None,
            initialising: Default::default(),
            mapping_solver: None,
            pending_ba: None,
            triangulations: (0, 0),
        }
    }

    /// Counts the frames that never reached the tracker before this one (`index` jumps);
    /// a frame handed over twice (tried without matches, then stepped) counts once.
    fn note_frame(&mut self, index: usize) {
        match self.last_index {
            Some(last) if last == index => return,
            Some(last) => self.unseen += index.saturating_sub(last + 1),
            None => {}
        }
        self.last_index = Some(index);
    }

    /// The pose of the next frame under constant velocity (`None` until two frames were
    /// tracked in a row), across the frames that failed or never arrived since the last
    /// tracked one.
    fn predict(&self) -> Option<Pose> {
        let velocity = self.velocity?;
        let mut t_cam_world = self.last_t_cam_world;
        for _ in 0..=self.lost_streak + self.unseen {
            t_cam_world = velocity.compose(&t_cam_world);
        }
        Some(t_cam_world)
    }

    fn focal(&self) -> f64 {
        0.5 * (self.calib.fx + self.calib.fy)
    }

    /// The reference keyframe the next frame must be matched against: its frame index and
    /// features (`None` before the first frame and right after a loss).
    pub fn reference(&self) -> Option<(usize, &Features)> {
        self.keyframe.as_ref().map(|k| (k.frame, &k.features))
    }

    /// How many keyframe triangulations the mapping solver answered, and how many were
    /// computed here although one was set (see [`Tracker::set_mapping_solver`]).
    pub fn triangulation_counts(&self) -> (usize, usize) {
        self.triangulations
    }

    /// Positions (world frame) of the local map's landmarks, for diagnostic views.
    pub fn map_points(&self) -> Vec<[f32; 3]> {
        self.map
            .landmarks
            .values()
            .map(|l| l.p.cast::<f32>().into())
            .collect()
    }

    /// Whether the next frame must come with the matcher's matches to [`Tracker::reference`]
    /// (otherwise [`Tracker::track_without_matches`] is tried first): always with
    /// `match_every_frame`; otherwise while initialising, after a lost frame, when there
    /// is no motion model or too little of the last frame to track by projection, and when
    /// the next frame becomes a keyframe whatever it tracks (`max_frames_between_keyframes`:
    /// its new landmarks come from the matches, so tracking it by projection first would be
    /// work thrown away).
    pub fn wants_matches(&self) -> bool {
        let initialised = self
            .keyframe
            .as_ref()
            .is_some_and(|k| k.landmark.iter().any(|l| l.is_some()));
        self.cfg.match_every_frame
            || !initialised
            || self.lost_streak > 0
            || self.velocity.is_none()
            || self
                .last_frame
                .as_ref()
                .is_none_or(|l| l.len() < self.cfg.min_tracked)
            || self.keyframe_due_by_count(self.frames_since_keyframe + 1)
    }

    /// Tracks one frame, calling `matcher(reference, frame)` for its matches to the
    /// reference keyframe only where they are needed: the in-process form of
    /// [`Tracker::track_without_matches`] followed, when that declines, by
    /// [`Tracker::step`].
    pub fn track_frame<E>(
        &mut self,
        meta: FrameMeta,
        cur: Features,
        matcher: impl FnOnce(&Features, &Features) -> Result<Matches, E>,
    ) -> Result<FrameOutput, E> {
        if let Some(out) = self.track_without_matches(meta, &cur) {
            return Ok(out);
        }
        let matches = match self.reference() {
            Some((_, reference)) => Some(matcher(reference, &cur)?),
            None => None,
        };
        Ok(self.step(meta, cur, matches.as_ref()))
    }

    fn output(
        &self,
        input: &FrameMeta,
        state: TrackingState,
        t_cam_world: Option<Pose>,
        keypoints: usize,
        (matches, inliers): (usize, usize),
        keyframe: bool,
    ) -> FrameOutput {
        FrameOutput {
            index: input.index,
            stamp: input.stamp,
            state,
            t_world_cam: t_cam_world.map(|p| p.inverse()),
            keypoints,
            matches,
            inliers,
            keyframe,
            landmarks: self.map.landmarks.len(),
            reference: None,
            match_next: true,
            scale: None,
            backfilled: Vec::new(),
        }
    }

    /// Makes `cur` the reference keyframe at `t_cam_world`, without landmarks
    /// (initialisation starts from it) and without an old map's depths (the caller that
    /// has them sets them after).
    fn set_reference(&mut self, frame: usize, t_cam_world: Pose, cur: Features) {
        let id = self.map.new_keyframe_id(t_cam_world, frame);
        self.initialising.clear();
        self.reference_depths = None;
        let (landmark, track) = (vec![None; cur.len()], vec![None; cur.len()]);
        self.keyframe = Some(Keyframe {
            id,
            frame,
            t_cam_world,
            features: cur,
            landmark,
            track,
        });
    }

    /// Makes `cur` (frame index `frame`, registered as keyframe `cur_id` at `t_cam_world`) the new
    /// keyframe. Each match in `candidates` to `kf` without a landmark extends the pending
    /// track of its keypoint in `kf` (or starts one there); a track becomes a landmark once
    /// its observations triangulate with enough parallax, otherwise it waits for the next
    /// keyframe, so slow or forward motion still builds landmarks from a wider baseline.
    /// Then the local BA runs.
    fn insert_keyframe(
        &mut self,
        kf: &Keyframe,
        cur: Features,
        (frame, cur_id): (usize, usize),
        t_cam_world: Pose,
        mut landmark: Vec<Option<usize>>,
        (candidates, min_parallax_deg): (&[(usize, usize)], f64),
    ) {
        let mut track = vec![None; cur.len()];
        for &(a, b) in candidates {
            if landmark[b].is_some() || kf.landmark[a].is_some() {
                continue;
            }
            let (id, mut obs) = match kf.track[a].and_then(|id| self.map.tracks.remove_entry(&id)) {
                Some(entry) => entry,
                None => {
                    self.map.next_track += 1;
                    let first = (kf.id, bearing(&self.calib, &kf.features.keypoints[a]));
                    (self.map.next_track - 1, vec![first])
                }
            };
            obs.push((cur_id, bearing(&self.calib, &cur.keypoints[b])));
            match self.map.triangulate_track(&obs, min_parallax_deg) {
                Some(p) => {
                    landmark[b] = Some(self.map.add_landmark(
                        p,
                        obs,
                        cur.descriptor(b),
                        crate::map::LandmarkSource::Matcher,
                    ))
                }
                None => {
                    self.map.tracks.insert(id, obs);
                    track[b] = Some(id);
                }
            }
        }
        self.last_t_cam_world = t_cam_world;
        self.keyframe = Some(Keyframe {
            id: cur_id,
            frame,
            t_cam_world,
            features: cur,
            landmark,
            track,
        });
        self.frames_since_keyframe = 0;
        self.triangulate_with_earlier_keyframes();
        let (answered, here) = self.map.end_prefetch();
        self.triangulations.0 += answered;
        self.triangulations.1 += here;
        self.local_ba();
        self.prune_map();
    }

    /// Drops landmarks that none of the last `local_map_keyframes` keyframes observes, so
    /// memory stays flat on long runs; the rest form the local map that the search by
    /// projection can find again (after a pan, a stop, an occlusion).
    fn prune_map(&mut self) {
        let n = self.map.keyframe_poses.len();
        let keep_from = n.saturating_sub(self.cfg.local_map_keyframes.max(1));
        self.map
            .landmarks
            .retain(|_, lm| lm.obs.iter().any(|(k, _)| *k >= keep_from));
        // a track not continued by the newest keyframe is over
        let newest = n.saturating_sub(1);
        self.map
            .tracks
            .retain(|_, obs| obs.last().is_some_and(|(k, _)| *k >= newest));
    }

    /// Processes one frame: its features and their matches against [`Tracker::reference`]
    /// (`a` indexes the reference, `b` this frame). `matches` is ignored when there is no
    /// reference; when there is one and `matches` is `None` (the matcher could not provide
    /// them) the frame counts as lost and the tracker starts again from it.
    pub fn step(
        &mut self,
        meta: FrameMeta,
        cur: Features,
        matches: Option<&Matches>,
    ) -> FrameOutput {
        self.note_frame(meta.index);
        let initialised = self
            .keyframe
            .as_ref()
            .is_some_and(|k| k.landmark.iter().any(|l| l.is_some()));
        let out = if initialised {
            self.track(&meta, cur, matches)
        } else {
            self.initialise(&meta, cur, matches)
        };
        if out.t_world_cam.is_none() {
            self.last_frame = None;
        } else if out.keyframe {
            self.last_frame = self.keyframe.as_ref().map(projection::LastFrame::keyframe);
        }
        self.finish_output(out)
    }

    /// Adds what the tracker decided for the next frame (reference, whether it must be
    /// matched) and the map scale to a frame's output.
    fn finish_output(&self, mut out: FrameOutput) -> FrameOutput {
        out.reference = self.keyframe.as_ref().map(|k| k.frame);
        out.match_next = self.wants_matches();
        out.scale = self.scale;
        out
    }
}

#[cfg(test)]
mod tests;
