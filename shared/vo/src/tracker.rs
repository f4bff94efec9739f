//! The monocular tracker: two-view initialisation; PnP tracking against the reference
//! keyframe's landmarks followed by a search of the local map by projection (or, when the
//! keyframe's landmarks fail, a constant-velocity prediction); keyframes whose unmatched
//! matches extend pending tracks until they triangulate with enough parallax; a local
//! bundle adjustment with older keyframes as fixed anchors; after a blind frame (too few
//! keypoints) the next frame is tracked against the map kept for it (relocalisation), and
//! any other failure re-initialises.
//!
//! The tracker's own matching (the local-map search) is a descriptor comparison within a
//! few pixels of a projection, done here because it needs the map; the networks' matches to
//! the reference keyframe still come from outside.
//!
//! Frames: `T_cam_world` maps world points into the camera; outputs carry `T_world_cam`.
//! The world frame is the first keyframe's camera; the scale is fixed by the first
//! two-view initialisation (unit baseline) and carried by the landmarks afterwards.
//! A local bundle adjustment refines the last keyframes and their landmarks.
//!
//! The tracker neither detects nor matches: each step takes the frame's features and their
//! matches against the current reference keyframe ([`Tracker::reference`]). In process,
//! [`VoPipeline`] runs extractor, matcher and tracker one after the other; in the daemon the
//! features and the matches arrive from their own processes, and the results are identical
//! because the tracker sees exactly the same numbers.

use crate::stage::Stage;
use supermvo_dataset::{Calibration, GrayImage};
use supermvo_geometry::essential::{
    find_essential, recover_pose, triangulate_checked, RansacConfig, Triangulated,
};
use supermvo_geometry::pnp::{solve_pnp_ransac, PnpConfig};
use supermvo_geometry::{Mat3, Pose, Vec3};
use supermvo_inference::{Extractor, Features, InferenceError, Matcher, Matches};

/// Tracker settings.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerConfig {
    /// Median keypoint displacement (pixels) needed before two-view initialisation.
    pub min_parallax_px: f64,
    /// Landmarks needed for a successful initialisation.
    pub min_init_landmarks: usize,
    /// PnP inliers below which tracking is lost.
    pub min_tracked: usize,
    /// New keyframe when fewer landmarks than this are tracked.
    pub keyframe_min_tracked: usize,
    /// Minimum parallax angle (degrees) of a newly triangulated landmark.
    pub min_triangulation_parallax_deg: f64,
    /// The same while tracking is weak (fewer than `keyframe_min_tracked` inliers): a wide
    /// baseline gives unbiased depths, but a starving map must take what it can get.
    pub weak_triangulation_parallax_deg: f64,
    /// Minimum parallax angle (degrees) of the landmarks of a two-view initialisation.
    pub min_init_parallax_deg: f64,
    /// New keyframe after at most this many frames.
    pub max_frames_between_keyframes: usize,
    /// New keyframe when fewer landmarks are tracked than this fraction of the reference
    /// keyframe's established ones (seen by 3 or more keyframes; ORB-SLAM's rule, 0.9 there
    /// for monocular): it scales with how many points the front end matches, where
    /// `keyframe_min_tracked` does not; 0 switches it off.
    pub keyframe_ratio: f64,
    /// Keyframes in the local bundle adjustment window (0 disables it).
    pub local_ba_window: usize,
    /// Local-map search: after the pose from the keyframe matches, landmarks of the local
    /// window that the keyframe does not carry are projected into the frame and matched to
    /// keypoints within this radius (pixels) by descriptor; 0 disables it.
    pub map_search_radius_px: f64,
    /// Local BA: observations of the window's points from older keyframes enter the
    /// problem, those keyframes held fixed.
    pub ba_anchors: bool,
    /// Window keyframes held fixed when anchors are present (2 without anchors).
    pub ba_fixed_with_anchors: usize,
    /// Keyframes whose landmarks form the local map (landmarks seen by none of them are
    /// dropped).
    pub local_map_keyframes: usize,
    /// Largest descriptor distance accepted by the local-map search, normalised to [0, 1]:
    /// `1 - cos` for float descriptors, Hamming distance / 256 for ORB.
    pub map_search_max_distance: f32,
    /// The best candidate must be below this times the second best.
    pub map_search_ratio: f32,
    /// A new keyframe's match to a landmark of the reference keyframe that misses the PnP
    /// threshold, but lies within this many pixels of the landmark's projection, is tried as
    /// an observation: kept when the landmark, re-triangulated with it, reprojects within
    /// 2 px in every view. The wider baseline then corrects a depth that a short one got
    /// wrong, instead of the landmark losing its track; 0 disables.
    pub reobserve_max_px: f64,
    /// The frame's pose, last, refined on all its landmark matches under a robust loss
    /// (Huber at half the PnP threshold, nothing beyond three times it) instead of only on
    /// those a hard threshold selected: the pose then depends on the data, not on which
    /// points RANSAC's sample happened to let through, and the run far less on the seed.
    pub robust_refinement: bool,
    /// Relocalisation after blind frames: a frame with fewer keypoints than `min_tracked`
    /// (a black, washed-out or covered image) is lost without ending the map, and the next
    /// frame is tracked against the map and reference keyframe kept for it (PnP on its
    /// matches to the keyframe's landmarks, at the map's own scale) instead of starting a
    /// new map whose scale the median depth only approximates; at most this many blind
    /// frames in a row, then the tracker starts over. Any other failure (a frame whose
    /// matches do not reach the map, or do but disagree with it) starts over at once:
    /// retrying a map the frame contradicts only delays the new one (KITTI 01, where the
    /// first maps fail). 0: blind frames start over too.
    pub relocalisation_frames: usize,
    /// Essential-matrix RANSAC.
    pub ransac: RansacConfig,
    /// PnP RANSAC.
    pub pnp: PnpConfig,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            min_parallax_px: 20.0,
            min_init_landmarks: 80,
            min_tracked: 40,
            keyframe_min_tracked: 100,
            min_triangulation_parallax_deg: 1.5,
            weak_triangulation_parallax_deg: 1.0,
            min_init_parallax_deg: 1.0,
            max_frames_between_keyframes: 3,
            keyframe_ratio: 0.0,
            local_ba_window: 6,
            map_search_radius_px: 10.0,
            map_search_max_distance: 0.25,
            local_map_keyframes: 20,
            ba_anchors: true,
            ba_fixed_with_anchors: 1,
            map_search_ratio: 0.9,
            reobserve_max_px: 6.0,
            robust_refinement: true,
            relocalisation_frames: 5,
            ransac: RansacConfig::default(),
            pnp: PnpConfig::default(),
        }
    }
}

impl TrackerConfig {
    /// The same configuration with RANSAC and PnP sampling seeded from `seed`: 0 keeps the
    /// default seeds, any other value offsets both (the run stays deterministic).
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.ransac.seed = self.ransac.seed.wrapping_add(seed.wrapping_mul(104_729));
        self.pnp.seed = self.pnp.seed.wrapping_add(seed.wrapping_mul(7_919));
        self
    }
}

/// One local bundle adjustment: its size, cost (sum of squared normalised reprojection
/// errors under the robust loss) and wall time including building the problem.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct BaStats {
    /// Keyframes in the window (including the fixed ones).
    pub keyframes: usize,
    /// Landmarks.
    pub points: usize,
    /// Observations.
    pub observations: usize,
    /// Cost before.
    pub cost_before: f64,
    /// Cost after.
    pub cost_after: f64,
    /// Milliseconds.
    pub ms: f64,
}

/// Tracking state of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackingState {
    /// Waiting for enough parallax to initialise.
    Initializing,
    /// Pose estimated.
    Tracking,
    /// Tracking failed on this frame; the tracker tries the next frame against the map it
    /// has (after a blind frame: relocalisation) or re-initialises.
    Lost,
}

/// One input frame.
#[derive(Debug, Clone)]
pub struct FrameInput {
    /// Frame index.
    pub index: usize,
    /// Timestamp, seconds.
    pub stamp: f64,
    /// The image.
    pub image: GrayImage,
}

/// The tracker's result for one frame.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FrameOutput {
    /// Frame index.
    pub index: usize,
    /// Timestamp, seconds.
    pub stamp: f64,
    /// State.
    pub state: TrackingState,
    /// `T_world_cam` as a 3x4 row-major matrix, when estimated.
    pub pose: Option<[f64; 12]>,
    /// Keypoints detected.
    pub keypoints: usize,
    /// Matches to the reference keyframe.
    pub matches: usize,
    /// Inliers of the pose estimate.
    pub inliers: usize,
    /// Whether this frame became a keyframe.
    pub keyframe: bool,
    /// Landmarks in the map.
    pub landmarks: usize,
    /// Frame index of the reference keyframe the next frame is matched against.
    pub reference: Option<usize>,
    /// Scale of the map (median landmark depth at initialisation), once initialised.
    pub scale: Option<f64>,
}

/// A map point with every keyframe observation `(keyframe id, bearing)` of it and the
/// descriptor of its latest observation (for the local-map search).
struct Landmark {
    p: Vec3,
    obs: Vec<(usize, Vec3)>,
    desc: Vec<f32>,
}

struct Keyframe {
    id: usize,
    /// Frame index of the keyframe.
    frame: usize,
    r: Mat3,
    t: Vec3,
    features: Features,
    landmark: Vec<Option<usize>>,
    /// Per keypoint, the pending track (observations still without enough parallax) it
    /// continues, if any.
    track: Vec<Option<usize>>,
}

/// The tracker (see module docs).
pub struct Tracker {
    calib: Calibration,
    cfg: TrackerConfig,
    /// The local map by landmark id: landmarks leave it once none of the last
    /// `local_map_keyframes` keyframes observes them, so memory stays flat on long runs.
    landmarks: std::collections::BTreeMap<usize, Landmark>,
    next_landmark: usize,
    /// Pending tracks by id: keyframe observations of a point that has no landmark yet.
    tracks: std::collections::BTreeMap<usize, Vec<(usize, Vec3)>>,
    next_track: usize,
    /// `T_cam_world` of every keyframe, by id (refined by the local BA).
    keyframe_poses: Vec<(Mat3, Vec3)>,
    /// Id of the first keyframe of the current map: a loss starts a new map (its scale is
    /// only carried by the median depth), which the local BA and the local-map search keep
    /// apart from the old one.
    segment_start: usize,
    keyframe: Option<Keyframe>,
    frames_since_keyframe: usize,
    /// Rotation and translation of `T_cam_world` of the reference used to re-initialise
    /// after a loss (the last tracked pose), so the trajectory continues in one frame.
    last_pose: (Mat3, Vec3),
    /// Motion between the last two tracked frames, `T_last_prev` (rotation, translation):
    /// the constant-velocity prediction used when the keyframe matches fail.
    velocity: Option<(Mat3, Vec3)>,
    /// Blind frames in a row for which the map was kept (relocalisation).
    lost_streak: usize,
    /// The last local BA, until taken.
    last_ba: Option<BaStats>,
    /// Scale of the map (median landmark depth at initialisation), to carry across
    /// re-initialisations.
    scale: Option<f64>,
}

impl std::fmt::Debug for Tracker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Tracker({} landmarks)", self.landmarks.len())
    }
}

fn bearing(c: &Calibration, p: &[f32; 2]) -> Vec3 {
    Vec3::new(
        (p[0] as f64 - c.cx) / c.fx,
        (p[1] as f64 - c.cy) / c.fy,
        1.0,
    )
}

fn pose_array(r: &Mat3, t: &Vec3) -> [f64; 12] {
    // T_world_cam = (R^T, -R^T t)
    let rw = r.transpose();
    let tw = -(rw * t);
    [
        rw[(0, 0)],
        rw[(0, 1)],
        rw[(0, 2)],
        tw.x,
        rw[(1, 0)],
        rw[(1, 1)],
        rw[(1, 2)],
        tw.y,
        rw[(2, 0)],
        rw[(2, 1)],
        rw[(2, 2)],
        tw.z,
    ]
}

impl Tracker {
    /// A tracker for the given left-camera calibration.
    pub fn new(calib: Calibration, cfg: TrackerConfig) -> Self {
        Self {
            calib,
            cfg,
            landmarks: std::collections::BTreeMap::new(),
            next_landmark: 0,
            tracks: std::collections::BTreeMap::new(),
            next_track: 0,
            keyframe_poses: Vec::new(),
            segment_start: 0,
            keyframe: None,
            frames_since_keyframe: 0,
            last_pose: (Mat3::identity(), Vec3::zeros()),
            velocity: None,
            lost_streak: 0,
            last_ba: None,
            scale: None,
        }
    }

    /// Adds a landmark with its keyframe observations `(keyframe id, bearing)` and the
    /// descriptor of the latest; returns its id.
    fn add_landmark(&mut self, p: Vec3, obs: Vec<(usize, Vec3)>, desc: &[f32]) -> usize {
        let id = self.next_landmark;
        self.next_landmark += 1;
        let desc = desc.to_vec();
        self.landmarks.insert(id, Landmark { p, obs, desc });
        id
    }

    /// Adds keyframe `kf_id`'s observation `(bearing, descriptor)` to landmark `id` and
    /// re-triangulates it from all its observations when each still reprojects within 2 px.
    fn observe_landmark(&mut self, id: usize, kf_id: usize, b: Vec3, desc: &[f32]) {
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
    fn reobserve_landmark(&mut self, id: usize, kf_id: usize, b: Vec3, desc: &[f32]) -> bool {
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
    fn triangulate_observations(&self, obs: &[(usize, Vec3)]) -> Option<Triangulated> {
        let views = obs
            .iter()
            .map(|(k, b)| self.keyframe_poses.get(*k).map(|&(r, t)| (r, t, *b)))
            .collect::<Option<Vec<(Mat3, Vec3, Vec3)>>>()?;
        triangulate_checked(&views, 2.0 / self.focal())
    }

    /// The pose of the next frame under constant velocity (`None` until two frames were
    /// tracked in a row), across the frames that failed since the last tracked one.
    fn predict(&self) -> Option<(Mat3, Vec3)> {
        let (rv, tv) = self.velocity?;
        let (mut r, mut t) = self.last_pose;
        for _ in 0..=self.lost_streak {
            (r, t) = (rv * r, rv * t + tv);
        }
        Some((r, t))
    }

    /// The local-map search: projects every landmark of the local map not in `skip` into
    /// the frame at `T_cam_world = (r, t)` and pairs it with the free keypoint (`taken` false)
    /// within the search radius whose descriptor is nearest, when that distance passes the
    /// threshold and the ratio test. Each keypoint keeps its nearest landmark. Returns
    /// `(keypoint, landmark id)` pairs in keypoint order.
    fn search_local_map(
        &self,
        cur: &Features,
        (r, t): (&Mat3, &Vec3),
        taken: &[bool],
        skip: &std::collections::BTreeSet<usize>,
        radius: f64,
    ) -> Vec<(usize, usize)> {
        let (w, h) = cur.image_size;
        if radius <= 0.0 || cur.is_empty() || w == 0 || h == 0 {
            return Vec::new();
        }
        // keypoints bucketed in cells of the search radius
        let cell = radius.max(1.0);
        let (gw, gh) = (
            (w as f64 / cell).ceil() as usize + 1,
            (h as f64 / cell).ceil() as usize + 1,
        );
        let mut grid: Vec<Vec<usize>> = vec![Vec::new(); gw * gh];
        let cell_of = |x: f64, y: f64| -> Option<(usize, usize)> {
            let (cx, cy) = ((x / cell).floor(), (y / cell).floor());
            (cx >= 0.0 && cy >= 0.0 && (cx as usize) < gw && (cy as usize) < gh)
                .then_some((cx as usize, cy as usize))
        };
        for (i, kp) in cur.keypoints.iter().enumerate() {
            if taken[i] {
                continue;
            }
            if let Some((cx, cy)) = cell_of(kp[0] as f64, kp[1] as f64) {
                grid[cy * gw + cx].push(i);
            }
        }
        let c = &self.calib;
        let mut best_for: Vec<Option<(f32, usize)>> = vec![None; cur.len()];
        for (&id, lm) in &self.landmarks {
            if skip.contains(&id) || lm.desc.len() != cur.dim {
                continue;
            }
            let q = r * lm.p + t;
            if q.z <= 1e-6 {
                continue;
            }
            let (u, v) = (c.fx * q.x / q.z + c.cx, c.fy * q.y / q.z + c.cy);
            if u < 0.0 || v < 0.0 || u >= w as f64 || v >= h as f64 {
                continue;
            }
            let Some((gx, gy)) = cell_of(u, v) else {
                continue;
            };
            let (mut best, mut second) = ((f32::INFINITY, usize::MAX), f32::INFINITY);
            for y in gy.saturating_sub(1)..(gy + 2).min(gh) {
                for x in gx.saturating_sub(1)..(gx + 2).min(gw) {
                    for &i in &grid[y * gw + x] {
                        let kp = cur.keypoints[i];
                        if (kp[0] as f64 - u).hypot(kp[1] as f64 - v) > radius {
                            continue;
                        }
                        let d =
                            supermvo_inference::descriptor_distance(&lm.desc, cur.descriptor(i));
                        if d < best.0 {
                            second = best.0;
                            best = (d, i);
                        } else if d < second {
                            second = d;
                        }
                    }
                }
            }
            let (d, i) = best;
            if i == usize::MAX
                || d > self.cfg.map_search_max_distance
                || d >= self.cfg.map_search_ratio * second
            {
                continue;
            }
            if best_for[i].is_none_or(|(d0, _)| d < d0) {
                best_for[i] = Some((d, id));
            }
        }
        best_for
            .iter()
            .enumerate()
            .filter_map(|(i, b)| b.map(|(_, id)| (i, id)))
            .collect()
    }

    /// Registers a keyframe pose and returns its id.
    fn new_keyframe_id(&mut self, r: Mat3, t: Vec3) -> usize {
        self.keyframe_poses.push((r, t));
        self.keyframe_poses.len() - 1
    }

    /// Local bundle adjustment over the last `local_ba_window` keyframes (the two oldest fixed) and
    /// the landmarks they observe at least twice; writes the refined poses and points back.
    fn local_ba(&mut self) {
        let started = std::time::Instant::now();
        let window = self.cfg.local_ba_window;
        let n = self.keyframe_poses.len();
        if window < 3 || n < 3 {
            return;
        }
        let first = n.saturating_sub(window).max(self.segment_start);
        if n - first < 3 {
            return;
        }
        // Points seen in the window; their observations from older keyframes of this map
        // enter too, with those keyframes held fixed as anchors (they carry the scale).
        let mut point_ids = Vec::new();
        let mut observations = Vec::new();
        let mut slot: std::collections::BTreeMap<usize, usize> =
            (first..n).enumerate().map(|(i, k)| (k, i)).collect();
        let mut anchors = Vec::new();
        for (&id, lm) in self.landmarks.iter() {
            let in_window = lm.obs.iter().filter(|(k, _)| *k >= first).count();
            let usable: Vec<&(usize, Vec3)> = lm
                .obs
                .iter()
                .filter(|(k, _)| *k >= self.segment_start && (self.cfg.ba_anchors || *k >= first))
                .collect();
            if in_window < 1 || usable.len() < 2 {
                continue;
            }
            let pi = point_ids.len();
            point_ids.push(id);
            for (k, b) in usable {
                let next = slot.len();
                let kf = *slot.entry(*k).or_insert_with(|| {
                    anchors.push(*k);
                    next
                });
                observations.push(crate::ba::Observation {
                    kf,
                    point: pi,
                    bearing: *b,
                });
            }
        }
        if point_ids.len() < 20 {
            return;
        }
        let window_fixed = if anchors.is_empty() {
            2
        } else {
            self.cfg.ba_fixed_with_anchors
        };
        let mut poses = self.keyframe_poses[first..].to_vec();
        poses.extend(anchors.iter().map(|&k| self.keyframe_poses[k]));
        let mut ba = crate::ba::LocalBa {
            poses,
            fixed: (first..n)
                .map(|k| k < first + window_fixed)
                .chain(anchors.iter().map(|_| true))
                .collect(),
            points: point_ids.iter().map(|id| self.landmarks[id].p).collect(),
            observations,
            huber: 2.0 / self.focal(),
        };
        let (c0, c1) = ba.solve(10);
        let stats = BaStats {
            keyframes: n - first,
            points: point_ids.len(),
            observations: ba.observations.len(),
            cost_before: c0,
            cost_after: c1,
            ms: 0.0,
        };
        tracing::debug!(
            keyframes = n - first,
            points = point_ids.len(),
            observations = ba.observations.len(),
            cost_before = c0,
            cost_after = c1,
            "local BA"
        );
        self.keyframe_poses[first..].copy_from_slice(&ba.poses[..n - first]);
        for (i, &id) in point_ids.iter().enumerate() {
            if let Some(lm) = self.landmarks.get_mut(&id) {
                lm.p = ba.points[i];
            }
        }
        if let Some(kf) = self.keyframe.as_mut() {
            (kf.r, kf.t) = self.keyframe_poses[kf.id];
            self.last_pose = (kf.r, kf.t);
        }
        self.last_ba = Some(BaStats {
            ms: started.elapsed().as_secs_f64() * 1e3,
            ..stats
        });
    }

    /// What the last local bundle adjustment did, taken (for benchmarks and diagnostics:
    /// `None` when no window was solved since the last call).
    pub fn take_ba_stats(&mut self) -> Option<BaStats> {
        self.last_ba.take()
    }

    fn focal(&self) -> f64 {
        0.5 * (self.calib.fx + self.calib.fy)
    }

    /// Triangulates matched keypoints between a keyframe and the current frame (both
    /// `T_cam_world`), returning world points for pairs that are in front of both cameras,
    /// reproject within 2 px and have the configured parallax.
    fn triangulate_pairs(
        &self,
        (kf_r, kf_t): (&Mat3, &Vec3),
        kf_keypoints: &[[f32; 2]],
        cur: &Features,
        r: &Mat3,
        t: &Vec3,
        pairs: &[(usize, usize)],
    ) -> Vec<(usize, usize, Vec3)> {
        // relative pose T_cur_kf = T_cur_world * T_world_kf
        let r_rel = r * kf_r.transpose();
        let t_rel = t - r_rel * kf_t;
        let thr = 2.0 / self.focal();
        let mut out = Vec::new();
        for &(a, b) in pairs {
            let (x1, x2) = (
                bearing(&self.calib, &kf_keypoints[a]),
                bearing(&self.calib, &cur.keypoints[b]),
            );
            let views = [(Mat3::identity(), Vec3::zeros(), x1), (r_rel, t_rel, x2)];
            let Some(tri) = triangulate_checked(&views, thr) else {
                continue;
            };
            if tri.parallax_deg > self.cfg.min_init_parallax_deg {
                // world point: p_world = R_kf^T (p_kf - t_kf)
                out.push((a, b, kf_r.transpose() * (tri.point - kf_t)));
            }
        }
        out
    }

    /// The reference keyframe the next frame must be matched against: its frame index and
    /// features (`None` before the first frame and right after a loss).
    pub fn reference(&self) -> Option<(usize, &Features)> {
        self.keyframe.as_ref().map(|k| (k.frame, &k.features))
    }

    /// Restarts from `T_world_cam` with the map scale of an earlier run (a restarted tracking
    /// process continues the trajectory the back end recorded). Clears map and reference.
    pub fn restore(&mut self, t_world_cam: &Pose, scale: Option<f64>) {
        let r = t_world_cam.r.transpose();
        let t = -(r * t_world_cam.t);
        self.last_pose = (r, t);
        self.velocity = None;
        self.lost_streak = 0;
        self.scale = scale;
        self.keyframe = None;
        self.landmarks.clear();
        self.tracks.clear();
        self.keyframe_poses.clear();
        self.segment_start = 0;
        self.frames_since_keyframe = 0;
    }

    /// Moves the whole map (landmarks, keyframe poses, the reference and the last pose) by
    /// the similarity `x -> s R x + t`: the loop closer's correction of the world frame, so
    /// that tracking continues in the corrected world at the corrected scale.
    pub fn apply_correction(&mut self, c: &supermvo_optim::lie::Sim3) {
        let move_pose = |(r, t): (Mat3, Vec3)| {
            let centre = -(r.transpose() * t);
            let centre = c.s * (c.r * centre) + c.t;
            let r2 = r * c.r.transpose();
            (r2, -(r2 * centre))
        };
        for p in self.keyframe_poses.iter_mut() {
            *p = move_pose(*p);
        }
        for lm in self.landmarks.values_mut() {
            lm.p = c.s * (c.r * lm.p) + c.t;
        }
        if let Some(kf) = self.keyframe.as_mut() {
            (kf.r, kf.t) = move_pose((kf.r, kf.t));
        }
        self.last_pose = move_pose(self.last_pose);
        if let Some(v) = self.velocity.as_mut() {
            v.1 *= c.s;
        }
        self.scale = self.scale.map(|s| s * c.s);
    }

    fn output(
        &self,
        input: &FrameMeta,
        state: TrackingState,
        pose: Option<(Mat3, Vec3)>,
        keypoints: usize,
        (matches, inliers): (usize, usize),
        keyframe: bool,
    ) -> FrameOutput {
        FrameOutput {
            index: input.index,
            stamp: input.stamp,
            state,
            pose: pose.map(|(r, t)| pose_array(&r, &t)),
            keypoints,
            matches,
            inliers,
            keyframe,
            landmarks: self.landmarks.len(),
            reference: None,
            scale: None,
        }
    }

    /// Makes `cur` the reference keyframe at `(r, t)`, without landmarks (initialisation
    /// starts from it).
    fn set_reference(&mut self, frame: usize, r: Mat3, t: Vec3, cur: Features) {
        let id = self.new_keyframe_id(r, t);
        let (landmark, track) = (vec![None; cur.len()], vec![None; cur.len()]);
        self.keyframe = Some(Keyframe {
            id,
            frame,
            r,
            t,
            features: cur,
            landmark,
            track,
        });
    }

    /// Makes `cur` (frame index `frame`, registered as keyframe `cur_id` at `(r, t)`) the new
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
        (r, t): (Mat3, Vec3),
        mut landmark: Vec<Option<usize>>,
        (candidates, min_parallax_deg): (&[(usize, usize)], f64),
    ) {
        let mut track = vec![None; cur.len()];
        for &(a, b) in candidates {
            if landmark[b].is_some() || kf.landmark[a].is_some() {
                continue;
            }
            let (id, mut obs) = match kf.track[a].and_then(|id| self.tracks.remove_entry(&id)) {
                Some(entry) => entry,
                None => {
                    self.next_track += 1;
                    let first = (kf.id, bearing(&self.calib, &kf.features.keypoints[a]));
                    (self.next_track - 1, vec![first])
                }
            };
            obs.push((cur_id, bearing(&self.calib, &cur.keypoints[b])));
            match self.triangulate_track(&obs, min_parallax_deg) {
                Some(p) => landmark[b] = Some(self.add_landmark(p, obs, cur.descriptor(b))),
                None => {
                    self.tracks.insert(id, obs);
                    track[b] = Some(id);
                }
            }
        }
        self.last_pose = (r, t);
        self.keyframe = Some(Keyframe {
            id: cur_id,
            frame,
            r,
            t,
            features: cur,
            landmark,
            track,
        });
        self.frames_since_keyframe = 0;
        self.local_ba();
        self.prune_map();
    }

    /// The world point of a track's keyframe observations when it lies in front of every
    /// view, reprojects within 2 px in each and has the configured parallax between the
    /// first and the last view.
    fn triangulate_track(&self, obs: &[(usize, Vec3)], min_parallax_deg: f64) -> Option<Vec3> {
        self.triangulate_observations(obs)
            .filter(|tri| tri.parallax_deg > min_parallax_deg)
            .map(|tri| tri.point)
    }

    /// Drops landmarks that none of the last `local_map_keyframes` keyframes observes, so
    /// memory stays flat on long runs; the rest form the local map that the search by
    /// projection can find again (after a pan, a stop, an occlusion).
    fn prune_map(&mut self) {
        let n = self.keyframe_poses.len();
        let keep_from = n.saturating_sub(self.cfg.local_map_keyframes.max(1));
        self.landmarks
            .retain(|_, lm| lm.obs.iter().any(|(k, _)| *k >= keep_from));
        // a track not continued by the newest keyframe is over
        let newest = n.saturating_sub(1);
        self.tracks
            .retain(|_, obs| obs.last().is_some_and(|(k, _)| *k >= newest));
    }

    /// This frame has no pose and the reference `kf` stays: not enough for the two-view
    /// initialisation yet (`Initializing`), or a blind frame while tracking (`Lost`).
    fn keep_reference(
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

    fn initialise(&mut self, input: &FrameMeta, cur: Features, m: Option<&Matches>) -> FrameOutput {
        let Some(kf) = self.keyframe.take() else {
            // first frame (or first after a loss): becomes the reference at the last pose
            let (r, t) = self.last_pose;
            let out = self.output(
                input,
                TrackingState::Initializing,
                Some((r, t)),
                cur.len(),
                (0, 0),
                true,
            );
            self.set_reference(input.index, r, t, cur);
            return out;
        };
        let Some(m) = m else {
            // no matches to the reference: start again from this frame
            return self.lost(input, cur, 0);
        };
        let mut disp: Vec<f64> = m
            .pairs
            .iter()
            .map(|&(a, b)| {
                let (p, q) = (kf.features.keypoints[a], cur.keypoints[b]);
                ((p[0] - q[0]) as f64).hypot((p[1] - q[1]) as f64)
            })
            .collect();
        disp.sort_by(f64::total_cmp);
        let parallax = disp.get(disp.len() / 2).copied().unwrap_or(0.0);
        tracing::debug!(
            frame = input.index,
            matches = m.pairs.len(),
            median_displacement_px = parallax,
            "initialising"
        );
        if m.pairs.len() < self.cfg.min_init_landmarks {
            // too few matches left for this reference ever to initialise (the view has moved
            // on, e.g. after a failed attempt in a turn): start again from this frame, unless
            // the frame is blind
            let state = TrackingState::Initializing;
            return self.unusable_reference(input, kf, cur, m.pairs.len(), state);
        }
        if parallax < self.cfg.min_parallax_px {
            return self.keep_reference(
                input,
                kf,
                TrackingState::Initializing,
                cur.len(),
                (m.pairs.len(), 0),
            );
        }
        let x1: Vec<Vec3> = m
            .pairs
            .iter()
            .map(|&(a, _)| bearing(&self.calib, &kf.features.keypoints[a]))
            .collect();
        let x2: Vec<Vec3> = m
            .pairs
            .iter()
            .map(|&(_, b)| bearing(&self.calib, &cur.keypoints[b]))
            .collect();
        let Some(est) = find_essential(&x1, &x2, self.focal(), &self.cfg.ransac) else {
            return self.keep_reference(
                input,
                kf,
                TrackingState::Initializing,
                cur.len(),
                (m.pairs.len(), 0),
            );
        };
        let (r_rel, t_rel, _) = recover_pose(&est.e, &x1, &x2, &est.inliers, 1e3);
        // scale: unit baseline at the first initialisation; afterwards keep the map's scale
        // by scaling the baseline so the median depth matches the last map's median depth
        let inl: Vec<(usize, usize)> = m
            .pairs
            .iter()
            .zip(&est.inliers)
            .filter(|(_, &b)| b)
            .map(|(p, _)| *p)
            .collect();
        let identity = (&Mat3::identity(), &Vec3::zeros());
        let unit =
            self.triangulate_pairs(identity, &kf.features.keypoints, &cur, &r_rel, &t_rel, &inl);
        if unit.len() < self.cfg.min_init_landmarks {
            return self.keep_reference(
                input,
                kf,
                TrackingState::Initializing,
                cur.len(),
                (m.pairs.len(), unit.len()),
            );
        }
        let mut depths: Vec<f64> = unit.iter().map(|(_, _, p)| p.z).collect();
        depths.sort_by(f64::total_cmp);
        let median = depths[depths.len() / 2];
        let s = match self.scale {
            Some(target) => target / median,
            None => {
                self.scale = Some(median);
                1.0
            }
        };
        // current camera: T_cur_world = T_cur_kf * T_kf_world
        let t_rel = t_rel * s;
        let r = r_rel * kf.r;
        let t = r_rel * kf.t + t_rel;
        let cur_id = self.new_keyframe_id(r, t);
        let (keypoints, landmark) = (cur.len(), vec![None; cur.len()]);
        let init = (&inl[..], self.cfg.min_init_parallax_deg);
        self.insert_keyframe(&kf, cur, (input.index, cur_id), (r, t), landmark, init);
        let counts = (m.pairs.len(), est.inlier_count());
        self.output(
            input,
            TrackingState::Tracking,
            Some((r, t)),
            keypoints,
            counts,
            true,
        )
    }

    fn track(&mut self, input: &FrameMeta, cur: Features, m: Option<&Matches>) -> FrameOutput {
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
            .map(|(_, _, id)| self.landmarks[id].p)
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
            .chain(from_map.iter().map(|(_, id)| self.landmarks[id].p))
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
                .filter(|id| self.landmarks.get(id).is_some_and(|l| l.obs.len() >= 3))
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
        let cur_id = self.new_keyframe_id(r, t);
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
            self.observe_landmark(id, cur_id, obs_b, cur.descriptor(b));
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
                if self.reobserve_landmark(id, cur_id, obs_b, cur.descriptor(b)) {
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

impl Tracker {
    /// A frame that could not use the reference `kf` (`matches` to it), reported as `state`:
    /// `Initializing` while the reference waits to initialise, `Lost` when tracking against
    /// it failed. A blind frame (fewer keypoints than tracking needs: black, washed out,
    /// covered) says nothing about the reference, which stays: while initialising, and while
    /// tracking for at most `relocalisation_frames` blind frames in a row, with its map, so
    /// that the next frame relocalises on it at the map's scale. Any other frame starts over
    /// from itself at the last known pose.
    fn unusable_reference(
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
    fn lost(&mut self, input: &FrameMeta, cur: Features, matches: usize) -> FrameOutput {
        self.start_over(input, cur, matches, TrackingState::Lost)
    }

    /// Drops the map and makes this frame the reference at the last known pose, in a new
    /// segment (the next frames initialise against it); the frame itself has no pose and is
    /// reported in `state`.
    fn start_over(
        &mut self,
        input: &FrameMeta,
        cur: Features,
        matches: usize,
        state: TrackingState,
    ) -> FrameOutput {
        let out = self.output(input, state, None, cur.len(), (matches, 0), false);
        let (r, t) = self.last_pose;
        self.velocity = None;
        self.lost_streak = 0;
        self.landmarks.clear();
        self.tracks.clear();
        self.segment_start = self.keyframe_poses.len();
        self.set_reference(input.index, r, t, cur);
        self.frames_since_keyframe = 0;
        out
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
        let initialised = self
            .keyframe
            .as_ref()
            .is_some_and(|k| k.landmark.iter().any(|l| l.is_some()));
        let mut out = if initialised {
            self.track(&meta, cur, matches)
        } else {
            self.initialise(&meta, cur, matches)
        };
        out.reference = self.keyframe.as_ref().map(|k| k.frame);
        out.scale = self.scale;
        out
    }
}

/// Index and time of a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameMeta {
    /// Frame index.
    pub index: usize,
    /// Timestamp, seconds.
    pub stamp: f64,
}

/// Extractor, matcher and tracker in one process, one after the other: the reference
/// implementation the multi-process daemon must reproduce bit for bit.
pub struct VoPipeline {
    extractor: Box<dyn Extractor + Send>,
    matcher: Box<dyn Matcher + Send>,
    tracker: Tracker,
    loops: Option<crate::loops::LoopCloser>,
}

impl std::fmt::Debug for VoPipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "VoPipeline({:?}, {:?})", self.tracker, self.loops)
    }
}

impl VoPipeline {
    /// A pipeline over the given front end; with a loop closer, keyframes go to it and its
    /// corrections go back to the tracker.
    pub fn new(
        extractor: Box<dyn Extractor + Send>,
        matcher: Box<dyn Matcher + Send>,
        tracker: Tracker,
        loops: Option<crate::loops::LoopCloser>,
    ) -> Self {
        Self {
            extractor,
            matcher,
            tracker,
            loops,
        }
    }

    /// The loop closer, when there is one.
    pub fn loop_closer(&self) -> Option<&crate::loops::LoopCloser> {
        self.loops.as_ref()
    }
}

/// Hands one tracked frame to the loop closer and applies the correction it returns to the
/// tracker: the feedback of the back end, shared by the in-process pipeline and the daemon.
pub fn close_loops(
    loops: &mut crate::loops::LoopCloser,
    tracker: &mut Tracker,
    out: &FrameOutput,
) -> Option<crate::loops::Correction> {
    let pose = output_pose(out)?;
    if !out.keyframe {
        loops.add_frame(out.index, &pose);
        return None;
    }
    let (_, features) = tracker.reference()?;
    let correction = loops.add_keyframe(out.index, &pose, features)?;
    tracker.apply_correction(&correction.sim3);
    Some(correction)
}

impl Stage for VoPipeline {
    type Input = FrameInput;
    type Output = FrameOutput;
    type Error = InferenceError;

    fn name(&self) -> &'static str {
        "vo"
    }

    fn process(&mut self, input: FrameInput) -> Result<FrameOutput, InferenceError> {
        let cur = self.extractor.extract(&input.image)?;
        let matches = match self.tracker.reference() {
            Some((_, reference)) => Some(self.matcher.match_features(reference, &cur)?),
            None => None,
        };
        let meta = FrameMeta {
            index: input.index,
            stamp: input.stamp,
        };
        let out = self.tracker.step(meta, cur, matches.as_ref());
        if let Some(loops) = self.loops.as_mut() {
            close_loops(loops, &mut self.tracker, &out);
        }
        Ok(out)
    }
}

/// The pose of an output as a [`Pose`].
pub fn output_pose(o: &FrameOutput) -> Option<Pose> {
    o.pose.map(|p| {
        Pose::new(
            Mat3::new(p[0], p[1], p[2], p[4], p[5], p[6], p[8], p[9], p[10]),
            Vec3::new(p[3], p[7], p[11]),
        )
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
    use super::*;

    const F: f64 = 700.0;

    /// `T_cam_world` of an unrotated camera centred at `c`.
    fn at(c: Vec3) -> (Mat3, Vec3) {
        (Mat3::identity(), -c)
    }

    /// A camera of focal length `F` with principal point `(cx, cy)`.
    fn calibration(cx: f64, cy: f64) -> Calibration {
        Calibration {
            fx: F,
            fy: F,
            cx,
            cy,
        }
    }

    /// Bearing of world point `p` seen from the camera centred at `c`, moved by `(du, dv)` px.
    fn seen(p: &Vec3, c: &Vec3, (du, dv): (f64, f64)) -> Vec3 {
        let q = p - c;
        Vec3::new(q.x / q.z + du / F, q.y / q.z + dv / F, 1.0)
    }

    /// A tracker with keyframes 0 and 1 (0.5 m apart sideways, 1.4 degrees of parallax at
    /// 20 m) holding one landmark triangulated from them with 0.7 px of noise in keyframe 1,
    /// and keyframe 2 another 2.5 m on; returns it, the landmark id and the true point.
    fn short_baseline_landmark() -> (Tracker, usize, Vec3) {
        let mut tr = Tracker::new(calibration(0.0, 0.0), TrackerConfig::default());
        let centres = [
            Vec3::zeros(),
            Vec3::new(0.5, 0.0, 0.0),
            Vec3::new(3.0, 0.0, 0.0),
        ];
        for c in centres {
            let (r, t) = at(c);
            tr.new_keyframe_id(r, t);
        }
        let truth = Vec3::new(1.0, 0.5, 20.0);
        let obs = vec![
            (0, seen(&truth, &centres[0], (0.0, 0.0))),
            (1, seen(&truth, &centres[1], (0.7, 0.0))),
        ];
        let views: Vec<_> = obs
            .iter()
            .map(|(k, b)| (tr.keyframe_poses[*k].0, tr.keyframe_poses[*k].1, *b))
            .collect();
        let p = triangulate_checked(&views, 2.0 / F).unwrap().point;
        let id = tr.add_landmark(p, obs, &[0.0; 4]);
        (tr, id, truth)
    }

    fn reprojection_px(tr: &Tracker, id: usize, kf: usize, b: &Vec3) -> f64 {
        let (r, t) = tr.keyframe_poses[kf];
        supermvo_geometry::pnp::reprojection_sq(&r, &t, &tr.landmarks[&id].p, b).sqrt() * F
    }

    #[test]
    fn a_wider_baseline_corrects_a_landmark_that_tracking_rejected() {
        let (mut tr, id, truth) = short_baseline_landmark();
        let b = seen(&truth, &Vec3::new(3.0, 0.0, 0.0), (0.0, 0.0));
        let before = (tr.landmarks[&id].p - truth).norm();
        // the short baseline's depth error puts the landmark beyond the 2 px PnP threshold
        // from keyframe 2, within the 6 px re-observation gate
        let miss = reprojection_px(&tr, id, 2, &b);
        assert!(miss > 2.0 && miss < 6.0, "reprojection {miss} px");
        assert!(tr.reobserve_landmark(id, 2, b, &[1.0; 4]));
        let after = (tr.landmarks[&id].p - truth).norm();
        assert!(after < 0.25 * before, "error {before} m -> {after} m");
        assert_eq!(tr.landmarks[&id].obs.len(), 3);
        assert_eq!(tr.landmarks[&id].desc, vec![1.0; 4]);
    }

    #[test]
    fn a_match_inconsistent_with_the_other_views_is_not_added() {
        let (mut tr, id, truth) = short_baseline_landmark();
        let p = tr.landmarks[&id].p;
        // 5 px off across the epipolar line: no point fits all three views within 2 px
        let b = seen(&truth, &Vec3::new(3.0, 0.0, 0.0), (0.0, 5.0));
        assert!(!tr.reobserve_landmark(id, 2, b, &[1.0; 4]));
        assert_eq!(tr.landmarks[&id].p, p);
        assert_eq!(tr.landmarks[&id].obs.len(), 2);
        // an unknown keyframe or landmark changes nothing either
        assert!(!tr.reobserve_landmark(id, 7, b, &[1.0; 4]));
        assert!(!tr.reobserve_landmark(id + 1, 2, b, &[1.0; 4]));
    }

    fn features(n: usize, shift: f32) -> Features {
        Features {
            keypoints: (0..n)
                .map(|i| [(i % 40) as f32 * 30.0 + shift, (i / 40) as f32 * 30.0])
                .collect(),
            scores: vec![1.0; n],
            descriptors: vec![0.0; n * 4],
            dim: 4,
            image_size: (1241, 376),
        }
    }

    /// A reference that too few matches reach (fewer than `min_init_landmarks`) can never
    /// initialise: the frame becomes the new reference instead of the tracker waiting on the
    /// old one for the rest of the run (as ORB on KITTI 03 did after a failed attempt in
    /// the turn).
    #[test]
    fn initialisation_restarts_when_the_reference_loses_its_matches() {
        let mut tr = Tracker::new(calibration(620.0, 188.0), TrackerConfig::default());
        let meta = |index| FrameMeta {
            index,
            stamp: index as f64 * 0.1,
        };
        tr.step(meta(0), features(400, 0.0), None);
        assert_eq!(tr.reference().map(|r| r.0), Some(0));
        // many matches, too little parallax: keep waiting on frame 0
        let matches = |n: usize| Matches {
            pairs: (0..n).map(|i| (i, i)).collect(),
            scores: vec![1.0; n],
        };
        let many = matches(300);
        let out = tr.step(meta(1), features(400, 2.0), Some(&many));
        assert_eq!(out.state, TrackingState::Initializing);
        assert_eq!(tr.reference().map(|r| r.0), Some(0));
        // fewer matches than an initialisation needs: frame 2 becomes the reference
        let few = matches(50);
        let out = tr.step(meta(2), features(400, 40.0), Some(&few));
        assert_eq!(out.state, TrackingState::Initializing);
        assert!(out.pose.is_none());
        assert_eq!(tr.reference().map(|r| r.0), Some(2));
        // a blind frame (no keypoints, so no matches) says nothing about the reference: it
        // stays
        let none = matches(0);
        let out = tr.step(meta(3), features(0, 0.0), Some(&none));
        assert_eq!(out.state, TrackingState::Initializing);
        assert_eq!(tr.reference().map(|r| r.0), Some(2));
        // a frame with keypoints that do not reach the reference does replace it
        tr.step(meta(4), features(400, 0.0), Some(&none));
        assert_eq!(tr.reference().map(|r| r.0), Some(4));
    }
}
