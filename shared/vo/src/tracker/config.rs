//! The tracker's settings, each with its default and why.

use supermvo_geometry::essential::RansacConfig;
use supermvo_geometry::pnp::PnpConfig;

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
    /// The local BA window chosen by covisibility: the new keyframe and the keyframes that
    /// share at least this many landmarks with it, the most shared first, up to
    /// `local_ba_window` in all; 0: the last `local_ba_window` keyframes.
    pub local_ba_min_shared: usize,
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
    /// The matcher (LighterGlue) on every frame against the reference keyframe (the
    /// default). Off, it runs only where geometry cannot guide: for initialisation, for each
    /// new keyframe (its new landmarks), for frames that projection does not track and after
    /// a lost frame; the other frames are tracked by projecting the last frame's landmarks at
    /// the motion model's prediction (`projection_radius_px`) and then the local map. Faster
    /// (1.7-2x on the full-rate KITTI clips), not yet as accurate on sub-sampled ones.
    pub match_every_frame: bool,
    /// Tracking between keyframes: how far (pixels) from its predicted projection a last
    /// frame's landmark is looked for; searched again at twice the radius when fewer than
    /// `min_tracked` are found.
    pub projection_radius_px: f64,
    /// New landmarks between each new keyframe and this many keyframes before its reference
    /// (free keypoints paired along the epipolar line by descriptor, triangulated with the
    /// usual parallax and 2 px checks; `covisible_triangulation`); 0 disables (the default:
    /// better on most KITTI runs, worse on the synthetic drives,
    /// docs/decisions/2026-12-02-covisible-triangulation.md).
    pub covisible_triangulation_keyframes: usize,
    /// Largest distance (pixels) of a keypoint from the epipolar line of its pair there.
    pub epipolar_max_px: f64,
    /// The robust refinement (Huber weights from half the PnP threshold) gives no weight to
    /// a match whose error exceeds this many times the threshold
    /// (docs/decisions/2026-12-02-covisible-triangulation.md measures 1.5 and 2).
    pub robust_cutoff_factor: f64,
    /// A frame whose matches to the keyframe's landmarks agree with fewer than
    /// `min_tracked` within the PnP gate (it would be tracked from the motion model's
    /// prediction, or lost) is tried with the gate widened by this factor, and tracked with
    /// it when that lets more agree: a frame far from its keyframe (low frame rate, fast
    /// motion) sees the landmarks' depth errors magnified. 1 disables.
    pub weak_gate_factor: f64,
    /// Frames seen while initialising (too little parallax to the reference yet) that are
    /// posed once the map exists, on its landmarks (`initialising_frames`): the most recent
    /// this many; 0 leaves them unposed.
    pub backfill_frames: usize,
    /// A frame that reaches the reference keyframe's matches but not its map (PnP fails)
    /// starts a new map from the reference keyframe, whose pose is known, with itself as
    /// the second view; false: from itself, placed at the last tracked pose.
    pub reinitialise_on_reference: bool,
    /// A new map started from the reference keyframe (`reinitialise_on_reference`) takes the
    /// old map's scale from the landmarks that keyframe saw: the median ratio of their old
    /// depths to the new two-view depths of the same keypoints, where 10 or more have both.
    /// Off (or with fewer), the new map's median depth is set to the first map's, which
    /// jumps the scale wherever the view's depths differ from the first map's (in a turn:
    /// 25 % on the synthetic drive, up to 1.8x on KITTI 00 at every third frame). The ratio
    /// of the two maps' median depths is no substitute: the old landmarks and the new
    /// two-view points are different parts of the scene (on `highway`, 20x apart).
    pub reinitialise_at_map_scale: bool,
    /// After each local BA solved in this process (or answered at once by the mapping
    /// solver), read what its observations say about the lens: the radial coefficient they
    /// ask for beyond the calibration ([`crate::ba::LocalBa::radial_residual`]), averaged
    /// over the run by information ([`Tracker::lens_residual`]). A diagnostic: one more
    /// linearisation and two more solves of the window per keyframe (about two of the BA's
    /// ten iterations); it changes no pose.
    pub lens_check: bool,
    /// Learn the radial coefficient the calibration misses from the same readings, taken
    /// from windows that turn, and see every observation through it from then on
    /// (`tracker::lens`). Only where the local BA is solved at once (in process, and the
    /// lossless daemon).
    pub lens_self_calibration: bool,
    /// The rotation a window's keyframes must span (degrees) for its lens reading to teach
    /// the tracker: under forward motion a radial term and depth trade off and the
    /// readings wander.
    pub lens_min_rotation_deg: f64,
    /// The smallest radial error the tracker corrects: it starts learning only once the
    /// turning windows' unattenuated readings (every keyframe free but the two oldest)
    /// average at least this far from the calibration. Below it, keypoint noise biases the
    /// readings by as much as the error (the tracker's scale is better left to the
    /// calibration there).
    pub lens_min_k1: f64,
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
            local_ba_min_shared: 0,
            map_search_radius_px: 10.0,
            map_search_max_distance: 0.25,
            local_map_keyframes: 20,
            ba_anchors: true,
            ba_fixed_with_anchors: 1,
            map_search_ratio: 0.9,
            reobserve_max_px: 6.0,
            robust_refinement: true,
            relocalisation_frames: 5,
            match_every_frame: true,
            projection_radius_px: 15.0,
            covisible_triangulation_keyframes: 0,
            epipolar_max_px: 2.0,
            robust_cutoff_factor: 3.0,
            weak_gate_factor: 1.5,
            backfill_frames: 16,
            reinitialise_on_reference: true,
            reinitialise_at_map_scale: true,
            lens_check: false,
            lens_self_calibration: false,
            lens_min_rotation_deg: 10.0,
            lens_min_k1: 0.005,
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
