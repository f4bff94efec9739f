//! The loop closer's settings.

/// Loop-closure settings.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopConfig {
    /// Keypoints of each keyframe that place recognition and verification use: its
    /// strongest (the first) this many; `None`: all of them.
    pub keypoints: Option<usize>,
    /// Words of the VLAD vocabulary.
    pub vocabulary_size: usize,
    /// Keyframes whose descriptors train the vocabulary.
    pub vocabulary_keyframes: usize,
    /// Keyframes that must separate a query from a candidate (recent places are not loops).
    pub min_separation: usize,
    /// Best-scoring candidates verified per keyframe.
    pub candidates: usize,
    /// Minimum cosine similarity of mutually nearest descriptors.
    pub min_cosine: f32,
    /// 3D-3D inliers a loop needs.
    pub min_inliers: usize,
    /// Reprojection threshold of the verification, pixels.
    pub reprojection_px: f64,
    /// Consecutive keyframes that must see the same place before a loop is accepted.
    pub consistency: usize,
    /// Keyframes after a correction during which further loops are only added to the pose
    /// graph: driving on along a place seen before, every other keyframe confirms a loop,
    /// and solving the graph and correcting the tracker for each (ORB-SLAM instead ignores
    /// loops for 10 keyframes) cost the back end a core and kept the tracker absorbing
    /// corrections. The next correction after the cool-down, and the final trajectory,
    /// use every loop found.
    pub cooldown: usize,
    /// A keyframe whose place is verified against an earlier keyframe's (a revisit) is
    /// dropped from place recognition once no later keyframe triangulates against it (four
    /// keyframes on): its descriptors, keypoints, points and VLAD vector are freed and it is
    /// never a candidate again, the earlier keyframe standing for the place. Its pose stays
    /// in the pose graph. Memory and the cost of scoring candidates then grow with the
    /// places seen, not with the time spent driving through them (a replay looped for ten
    /// minutes otherwise grows the back end by 225 kB per keyframe).
    pub cull_revisits: bool,
    /// Keyframes before the newest one that a solved loop tied to the map that stay free in
    /// the next solve of the pose graph (the keyframes after it are free, the older ones
    /// held; see `pose_graph::solve`).
    pub pose_graph_margin: usize,
}

impl Default for LoopConfig {
    fn default() -> Self {
        Self {
            keypoints: None,
            vocabulary_size: 32,
            vocabulary_keyframes: 10,
            min_separation: 40,
            candidates: 3,
            min_cosine: 0.8,
            min_inliers: 20,
            reprojection_px: 3.0,
            consistency: 2,
            cooldown: 10,
            cull_revisits: true,
            pose_graph_margin: 20,
        }
    }
}
