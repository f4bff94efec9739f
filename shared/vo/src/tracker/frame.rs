//! What the tracker takes and returns per frame, and the conversions between keypoints,
//! bearings and the `T_world_cam` poses it reports.

use supermvo_dataset::GrayImage;
use supermvo_geometry::Pose;

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
    /// The camera's pose in the world, when estimated (`pose` in reports: its 3x4
    /// row-major matrix).
    #[serde(rename = "pose")]
    pub t_world_cam: Option<Pose>,
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
    /// Whether the next frame must come with the matcher's matches to `reference`
    /// ([`crate::tracker::Tracker::wants_matches`]); without, it is tracked by projection.
    pub match_next: bool,
    /// Scale of the map (median landmark depth at initialisation), once initialised.
    pub scale: Option<f64>,
    /// Earlier frames posed by this frame: those seen while the tracker initialised (too
    /// little parallax to the reference yet), posed against the map this frame's
    /// initialisation built; empty on every other frame.
    pub backfilled: Vec<LatePose>,
}

/// The pose of an earlier frame, known only once a later frame built the map it is posed on.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct LatePose {
    /// Frame index.
    pub index: usize,
    /// Timestamp, seconds.
    pub stamp: f64,
    /// The camera's pose in the world (`pose` in reports).
    #[serde(rename = "pose")]
    pub t_world_cam: Pose,
}

impl FrameOutput {
    /// Every pose this output gives, `(frame index, T_world_cam)`: the frames it
    /// [backfilled](FrameOutput::backfilled) (in frame order), then its own.
    pub fn poses(&self) -> impl Iterator<Item = (usize, Pose)> + '_ {
        let own = self.t_world_cam.map(|p| (self.index, p));
        self.backfilled
            .iter()
            .map(|l| (l.index, l.t_world_cam))
            .chain(own)
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
