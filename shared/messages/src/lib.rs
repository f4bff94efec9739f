//! What the SuPerMVO pipeline processes say to each other over iceoryx2 shared memory, defined
//! once: the message types, the service names, and each service's quality of service
//! (history, buffer, overflow or back-pressure).
//!
//! Every data message is a slice of plain `#[repr(C)]` values with a fixed-size
//! [`FrameHeader`] as the iceoryx2 user header: the image bytes, the features (keypoints,
//! scores and descriptors in one `f32` slice, see [`FeatureLayout`]) and the matches. A
//! publisher loans a sample in shared memory, writes into it and sends it; the subscriber reads
//! the same memory. Nothing is serialised.
//!
//! Sequence numbers (`seq`) count the frames the ingest stage emitted, without gaps; every
//! stage answers each `seq` exactly once with a message whose [`Status`] says what became of
//! the frame, so a frame is always processed or reported, never silently missing.

pub mod layout;

use iceoryx2::prelude::*;
use std::time::{SystemTime, UNIX_EPOCH};

pub use iceoryx2;

/// Version of the message layouts; every header carries it and receivers reject others.
pub const SCHEMA_VERSION: u32 = 4;

/// Frames in flight between ingest and tracking at most (credit-based flow control). The
/// data services keep at least this much history so a restarted stage can pick up every
/// frame that was in flight when its predecessor died.
pub const MAX_IN_FLIGHT: usize = 8;

/// History kept by the data services, delivered to a (re)started subscriber.
pub const HISTORY: usize = 2 * MAX_IN_FLIGHT;

/// The pipeline stages, in data-flow order. The discriminant indexes
/// [`FrameHeader::t_ns`].
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum StageKind {
    /// Dataset replay or camera.
    Ingest = 0,
    /// Keypoints and descriptors.
    Features = 1,
    /// Matching against the tracker's reference keyframe.
    Matching = 2,
    /// Pose estimation and mapping.
    Tracking = 3,
    /// Trajectory store (and, later, loop closure).
    Backend = 4,
}

impl StageKind {
    /// Every stage in data-flow order.
    pub const ALL: [StageKind; 5] = [
        StageKind::Ingest,
        StageKind::Features,
        StageKind::Matching,
        StageKind::Tracking,
        StageKind::Backend,
    ];

    /// Lower-case name, as used in service, node and binary names.
    pub fn name(self) -> &'static str {
        match self {
            StageKind::Ingest => "ingest",
            StageKind::Features => "features",
            StageKind::Matching => "matching",
            StageKind::Tracking => "tracking",
            StageKind::Backend => "backend",
        }
    }

    /// The stage of a numeric id.
    pub fn from_u32(v: u32) -> Option<Self> {
        Self::ALL.get(v as usize).copied()
    }
}

/// What became of a frame at the stage that sent the message.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Status {
    /// Processed; the payload holds the result.
    Ok = 0,
    /// Dropped by ingest to keep the frame rate (real-time mode), empty payload.
    Dropped = 1,
    /// The image could not be read or has the wrong size, empty payload.
    Unreadable = 2,
    /// Lost inside the pipeline (a stage died with it and no history had it), empty payload.
    Lost = 3,
    /// No frame: the dataset is finished. Its `seq` is one past the last frame.
    EndOfStream = 4,
    /// Matching had no features of the tracker's reference keyframe (after a restart).
    NoReference = 5,
}

impl Status {
    /// The status of a numeric code (unknown codes read as `Lost`).
    pub fn from_u32(v: u32) -> Self {
        match v {
            0 => Status::Ok,
            1 => Status::Dropped,
            2 => Status::Unreadable,
            4 => Status::EndOfStream,
            5 => Status::NoReference,
            _ => Status::Lost,
        }
    }
}

/// The user header of every data message.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("supermvo::FrameHeader")]
pub struct FrameHeader {
    /// [`SCHEMA_VERSION`].
    pub schema: u32,
    /// [`Status`] code.
    pub status: u32,
    /// Sequence number, from 0, without gaps.
    pub seq: u64,
    /// Frame index in the dataset.
    pub frame: u64,
    /// Capture time from the dataset, seconds.
    pub stamp: f64,
    /// Image width and height in pixels.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Matches: the frame index of the reference they were matched against, or -1.
    pub reference: i64,
    /// Number of keypoints or matches in the payload.
    pub count: u32,
    /// Descriptor length (features).
    pub dim: u32,
    /// Wall-clock nanoseconds at which each stage sent this frame on, by [`StageKind`];
    /// 0 where a stage has not seen it. `t_ns[0]` is the capture (ingest) time.
    pub t_ns: [u64; 5],
}

impl FrameHeader {
    /// A header for `seq` with the given status.
    pub fn new(seq: u64, frame: u64, stamp: f64, status: Status) -> Self {
        Self {
            schema: SCHEMA_VERSION,
            status: status as u32,
            seq,
            frame,
            stamp,
            reference: -1,
            ..Default::default()
        }
    }

    /// The frame's status.
    pub fn status(&self) -> Status {
        Status::from_u32(self.status)
    }

    /// A copy for the next stage: same frame, the given status, payload fields cleared.
    pub fn forward(&self, status: Status) -> Self {
        Self {
            status: status as u32,
            count: 0,
            dim: 0,
            reference: -1,
            ..*self
        }
    }

    /// Checks the schema version.
    pub fn check(&self) -> Result<(), MessageError> {
        if self.schema == SCHEMA_VERSION {
            Ok(())
        } else {
            Err(MessageError::Schema {
                found: self.schema,
                expected: SCHEMA_VERSION,
            })
        }
    }
}

/// One match between the reference keyframe (`a`) and the current frame (`b`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("supermvo::Match")]
pub struct MatchEntry {
    /// Keypoint index in the reference keyframe.
    pub a: u32,
    /// Keypoint index in the current frame.
    pub b: u32,
    /// Confidence.
    pub score: f32,
}

/// The tracker asks for the matches of a frame after all (payload of the `match_requests`
/// service; the header names the frame): it could not track it by projection alone, or the
/// frame becomes a keyframe and its new landmarks come from the matches.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("supermvo::MatchRequest")]
pub struct MatchRequest {
    /// Frame index of the reference keyframe to match against.
    pub reference: i64,
}

/// The tracker's result for one frame (payload of the `poses` service).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("supermvo::PoseMsg")]
pub struct PoseMsg {
    /// Tracking state: 0 initialising, 1 tracking, 2 lost, 3 no frame (see header status).
    pub state: u32,
    /// 1 when `t_world_cam` holds a pose.
    pub has_pose: u32,
    /// `T_world_cam`, 3x4 row-major.
    pub t_world_cam: [f64; 12],
    /// 1 when the frame became a keyframe.
    pub keyframe: u32,
    /// Keypoints detected.
    pub keypoints: u32,
    /// Matches to the reference.
    pub matches: u32,
    /// Inliers of the pose estimate.
    pub inliers: u32,
    /// Landmarks in the map.
    pub landmarks: u64,
    /// Frame index of the reference keyframe the next frame is matched against, or -1.
    pub reference: i64,
    /// 1 when the next frame must be matched against `reference`; 0 when the tracker
    /// tracks it by projection (the matching stage then forwards it without matches).
    pub match_next: u32,
    /// Map scale (median landmark depth at initialisation), or 0 before initialisation.
    pub scale: f64,
    /// How many entries of `backfilled` hold poses.
    pub backfilled_count: u32,
    /// Loop corrections ([`CorrectionMsg`]) the tracker had applied when it posed this
    /// frame: the world frame its poses are in.
    pub corrections: u32,
    /// Earlier frames this frame posed (the first `backfilled_count`): those seen while the
    /// tracker initialised, posed on the map this frame's initialisation built.
    pub backfilled: [BackfilledPose; MAX_BACKFILLED],
}

impl PoseMsg {
    /// [`PoseMsg::state`] of a frame tracking failed on.
    pub const LOST: u32 = 2;

    /// The earlier frames this frame posed: the `backfilled_count` entries in use.
    pub fn backfilled_poses(&self) -> &[BackfilledPose] {
        let n = (self.backfilled_count as usize).min(MAX_BACKFILLED);
        &self.backfilled[..n]
    }
}

/// Most earlier frames one [`PoseMsg`] poses (the tracker's `pipeline.backfill_frames` is at
/// most this).
pub const MAX_BACKFILLED: usize = 16;

/// The pose of an earlier frame, sent with the frame that made it known.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("supermvo::BackfilledPose")]
pub struct BackfilledPose {
    /// Sequence number of the earlier frame.
    pub seq: u64,
    /// Its `T_world_cam`, 3x4 row-major.
    pub t_world_cam: [f64; 12],
}

/// What the back end has recorded (payload of the `backend` service, history 1): a restarted
/// tracker continues from it.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("supermvo::BackendState")]
pub struct BackendState {
    /// Last sequence number recorded.
    pub seq: u64,
    /// Its frame index.
    pub frame: u64,
    /// 1 when `t_world_cam` holds the last estimated pose.
    pub has_pose: u32,
    /// Loop corrections issued so far; `t_world_cam` is in the world frame after all of
    /// them, so a restarted tracker continues there.
    pub corrections: u32,
    /// Last estimated `T_world_cam`, 3x4 row-major.
    pub t_world_cam: [f64; 12],
    /// Map scale of the tracker at that pose, or 0.
    pub scale: f64,
    /// Frames recorded so far (with or without pose).
    pub recorded: u64,
    /// Tracker state of the last frame recorded (see [`PoseMsg::state`]).
    pub state: u32,
    /// 1 once the end of the stream was recorded and the trajectory written.
    pub finished: u32,
}

/// The back end's verdict on one keyframe (payload of the `corrections` service; the header
/// names the keyframe): whether it closed a loop, and if so the similarity that moves the
/// tracker's map and poses into the corrected world, `x -> scale * rotation * x +
/// translation`. Every keyframe gets one; in lossless mode the tracker waits for it before
/// the next frame, so the daemon stays bit-identical to one process.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("supermvo::CorrectionMsg")]
pub struct CorrectionMsg {
    /// 1 when the keyframe closed a loop and the similarity below is to be applied.
    pub closed: u32,
    /// Corrections issued so far, this one included.
    pub corrections: u32,
    /// Scale of the similarity.
    pub scale: f64,
    /// Rotation, 3x3 row-major.
    pub rotation: [f64; 9],
    /// Translation.
    pub translation: [f64; 3],
    /// Sequence number of the keyframe that recognised the place, or -1.
    pub loop_query: i64,
    /// Sequence number of the earlier keyframe it recognised, or -1.
    pub loop_match: i64,
}

/// What a stage did with one frame, or a life-cycle event (payload of the `progress`
/// service, read by the supervisor and by monitors).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("supermvo::Progress")]
pub struct Progress {
    /// [`StageKind`] code.
    pub stage: u32,
    /// Worker index within the stage.
    pub worker: u32,
    /// Process id.
    pub pid: u32,
    /// [`ProgressEvent`] code.
    pub event: u32,
    /// Sequence number (frame events).
    pub seq: u64,
    /// Frame index.
    pub frame: u64,
    /// Frame [`Status`] code as sent on.
    pub status: u32,
    /// Frames waiting in this stage's input after this one.
    pub queue: u32,
    /// Wall-clock ns when the stage began work on the frame.
    pub t_in_ns: u64,
    /// Wall-clock ns when it sent the result.
    pub t_out_ns: u64,
    /// Capture time of the frame (ingest), wall-clock ns.
    pub t_capture_ns: u64,
    /// CPU time (user + system, all threads) the process had used when it sent this, ns:
    /// between two frame events of one process, what the stage spent per frame, its waiting
    /// and polling included.
    pub cpu_ns: u64,
}

/// The user header of a `view` message: the frame, the tracker's result, the lengths of the
/// payload's parts ([`ViewLayout`]) and the loop closed at this frame, if any.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("supermvo::ViewHeader")]
pub struct ViewHeader {
    /// The frame (seq, index, stamp, stage times).
    pub frame: FrameHeader,
    /// The tracker's result.
    pub pose: PoseMsg,
    /// Keypoints in the payload.
    pub keypoints: u32,
    /// Flow lines (matches to the reference keyframe) in the payload.
    pub flow: u32,
    /// Map points in the payload (keyframes only).
    pub map_points: u32,
    /// 1 when `map_points` holds the local map (a keyframe).
    pub has_map: u32,
    /// Frame index of the keyframe that closed a loop here, or -1.
    pub loop_query: i64,
    /// Frame index of the earlier keyframe it recognised, or -1.
    pub loop_match: i64,
}

/// How a [`supermvo_features::FrameView`] lies in the `view` payload: `2 * keypoints`
/// coordinates, `4 * flow` values (`x_ref, y_ref, x, y` per match), `3 * map_points`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ViewLayout;

impl ViewLayout {
    /// Payload length of `v`.
    pub fn len(v: &supermvo_features::FrameView) -> usize {
        2 * v.keypoints.len() + 4 * v.flow.len() + 3 * v.map_points.as_ref().map_or(0, Vec::len)
    }

    /// Writes `v` into `out` (of length [`ViewLayout::len`]) and its counts into `h`.
    pub fn write(v: &supermvo_features::FrameView, h: &mut ViewHeader, out: &mut [f32]) {
        let points = v.map_points.as_deref().unwrap_or_default();
        (h.keypoints, h.flow, h.map_points) = (
            v.keypoints.len() as u32,
            v.flow.len() as u32,
            points.len() as u32,
        );
        h.has_map = v.map_points.is_some() as u32;
        let values = v
            .keypoints
            .iter()
            .flatten()
            .chain(v.flow.iter().flatten())
            .chain(points.iter().flatten());
        for (o, x) in out.iter_mut().zip(values) {
            *o = *x;
        }
    }

    /// Reads the view back; `None` when the payload disagrees with the header.
    pub fn read(h: &ViewHeader, data: &[f32]) -> Option<supermvo_features::FrameView> {
        let (k, f, m) = (h.keypoints as usize, h.flow as usize, h.map_points as usize);
        if data.len() != 2 * k + 4 * f + 3 * m {
            return None;
        }
        let (kp, rest) = data.split_at(2 * k);
        let (fl, mp) = rest.split_at(4 * f);
        Some(supermvo_features::FrameView {
            keypoints: kp.chunks_exact(2).map(|c| [c[0], c[1]]).collect(),
            flow: fl
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
            map_points: (h.has_map == 1)
                .then(|| mp.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()),
        })
    }
}

/// Kinds of [`Progress`] message.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgressEvent {
    /// The stage is up and subscribed (sent once after start or restart).
    Started = 0,
    /// A frame was handled (see the status).
    Frame = 1,
    /// The stage forwarded the end of the stream and is done.
    Finished = 2,
    /// Alive and idle (sent when no frame was handled for a while).
    Heartbeat = 3,
}

/// Errors of the messaging layer.
#[derive(Debug, thiserror::Error)]
pub enum MessageError {
    /// A message written by a different version of SuPerMVO.
    #[error("message schema version {found}, this build speaks {expected}: run one build of SuPerMVO for every stage")]
    Schema {
        /// Version in the message.
        found: u32,
        /// Our version.
        expected: u32,
    },
    /// A features payload whose length disagrees with its header.
    #[error("features message for seq {seq}: payload of {len} floats does not hold {count} keypoints of dimension {dim}")]
    FeatureLayout {
        /// Sequence number.
        seq: u64,
        /// Payload length.
        len: usize,
        /// Keypoints in the header.
        count: u32,
        /// Descriptor length in the header.
        dim: u32,
    },
    /// An iceoryx2 call failed.
    #[error("{what}: {detail}")]
    Ipc {
        /// What was being done.
        what: String,
        /// iceoryx2's error.
        detail: String,
    },
}

impl MessageError {
    /// Wraps an iceoryx2 error with what was being done.
    pub fn ipc(what: impl Into<String>, e: impl std::fmt::Debug) -> Self {
        MessageError::Ipc {
            what: what.into(),
            detail: format!("{e:?}"),
        }
    }
}

/// How the keypoints, scores and descriptors of `n` features of dimension `d` lie in one
/// `f32` slice: `2n` coordinates, then `n` scores, then `n * d` descriptor values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FeatureLayout {
    /// Keypoints.
    pub n: usize,
    /// Descriptor length.
    pub dim: usize,
}

impl FeatureLayout {
    /// Slice length.
    pub fn len(&self) -> usize {
        self.n * (3 + self.dim)
    }

    /// Whether there are no features.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Writes `f` into `out` (of length [`FeatureLayout::len`]).
    pub fn write(f: &supermvo_features::Features, out: &mut [f32]) {
        let n = f.len();
        for (i, k) in f.keypoints.iter().enumerate() {
            out[2 * i] = k[0];
            out[2 * i + 1] = k[1];
        }
        out[2 * n..3 * n].copy_from_slice(&f.scores);
        out[3 * n..3 * n + f.descriptors.len()].copy_from_slice(&f.descriptors);
    }

    /// Reads features back from a payload and its header.
    pub fn read(
        h: &FrameHeader,
        data: &[f32],
    ) -> Result<supermvo_features::Features, MessageError> {
        let layout = FeatureLayout {
            n: h.count as usize,
            dim: h.dim as usize,
        };
        if data.len() != layout.len() {
            return Err(MessageError::FeatureLayout {
                seq: h.seq,
                len: data.len(),
                count: h.count,
                dim: h.dim,
            });
        }
        let n = layout.n;
        Ok(supermvo_features::Features {
            keypoints: (0..n).map(|i| [data[2 * i], data[2 * i + 1]]).collect(),
            scores: data[2 * n..3 * n].to_vec(),
            descriptors: data[3 * n..].to_vec(),
            dim: layout.dim,
            image_size: (h.width as usize, h.height as usize),
        })
    }
}

/// Wall-clock time in nanoseconds since the Unix epoch (comparable across processes).
pub fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

/// The services of one pipeline, by name. Two pipelines with different names do not see each
/// other; a second pipeline under a running one's name is refused by the supervisor.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Services {
    /// Pipeline name.
    pub pipeline: String,
}

/// The data services, with their payloads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Topic {
    /// `[u8]` image rows, ingest → features.
    Frames,
    /// `[f32]` features ([`FeatureLayout`]), features → matching and tracking.
    Features,
    /// `[MatchEntry]`, matching → tracking.
    Matches,
    /// `PoseMsg`, tracking → matching (reference), back end, ingest (credits), monitors.
    Poses,
    /// `MatchRequest`, tracking → matching: a frame the tracker needs matched after all.
    MatchRequests,
    /// `[f32]` features of each new keyframe ([`FeatureLayout`]), tracking → back end.
    Keyframes,
    /// `CorrectionMsg`, back end → tracking: the loop-closing verdict on each keyframe.
    Corrections,
    /// `[f64]` a keyframe's local-mapping work (its triangulations, its local bundle
    /// adjustment), tracking → back end.
    MappingRequests,
    /// `[f64]` the answer to each, back end → tracking.
    MappingReplies,
    /// `BackendState`, back end → tracking (restore), monitors.
    Backend,
    /// `Progress`, every stage → supervisor and monitors.
    Progress,
    /// `u64` liveness token, created by the supervisor while it runs.
    Control,
    /// `[f32]` diagnostic view of each tracked frame ([`ViewLayout`], header [`ViewHeader`]),
    /// tracking → `supermvo record` / `view`; lossy, published only while someone listens.
    View,
    /// `[u8]` camera images for diagnostic views, ingest → `supermvo record` / `view`; lossy,
    /// published only while someone listens.
    ViewImages,
}

impl Topic {
    /// Every topic.
    pub const ALL: [Topic; 14] = [
        Topic::Frames,
        Topic::Features,
        Topic::Matches,
        Topic::Poses,
        Topic::MatchRequests,
        Topic::Keyframes,
        Topic::Corrections,
        Topic::MappingRequests,
        Topic::MappingReplies,
        Topic::Backend,
        Topic::Progress,
        Topic::Control,
        Topic::View,
        Topic::ViewImages,
    ];

    /// Name within the pipeline.
    pub fn name(self) -> &'static str {
        match self {
            Topic::Frames => "frames",
            Topic::Features => "features",
            Topic::Matches => "matches",
            Topic::Poses => "poses",
            Topic::MatchRequests => "match_requests",
            Topic::Keyframes => "keyframes",
            Topic::Corrections => "corrections",
            Topic::MappingRequests => "mapping_requests",
            Topic::MappingReplies => "mapping_replies",
            Topic::Backend => "backend",
            Topic::Progress => "progress",
            Topic::Control => "control",
            Topic::View => "view",
            Topic::ViewImages => "view_images",
        }
    }
}

/// Service type used by every process.
pub type Ipc = ipc::Service;
/// A pipeline node.
pub type IpcNode = Node<Ipc>;

type PubSub<P> = iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, P, ()>;
/// The `view` service's port factory.
pub type PubSubView =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, [f32], ViewHeader>;
type PubSubH<P> =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, P, FrameHeader>;

/// Quality of service of the data topics.
#[derive(Debug, Clone, Copy)]
struct Qos {
    history: usize,
    buffer: usize,
    safe_overflow: bool,
}

type PubSubBuilder<P, H> = iceoryx2::service::builder::publish_subscribe::Builder<P, H, Ipc>;

impl Qos {
    /// The settings every topic shares, with this topic's history, buffer and overflow.
    fn apply<P, H>(self, b: PubSubBuilder<P, H>) -> PubSubBuilder<P, H>
    where
        P: std::fmt::Debug + IceoryxSend + ?Sized,
        H: std::fmt::Debug + ZeroCopySend,
    {
        b.history_size(self.history)
            .subscriber_max_buffer_size(self.buffer)
            .subscriber_max_borrowed_samples(4)
            .enable_safe_overflow(self.safe_overflow)
            .max_publishers(16)
            .max_subscribers(16)
            .max_nodes(32)
    }
}

impl Services {
    /// The services of pipeline `name`.
    pub fn new(pipeline: &str) -> Self {
        Self {
            pipeline: pipeline.to_string(),
        }
    }

    /// Full iceoryx2 service name of a topic.
    pub fn service_name(&self, topic: Topic) -> Result<ServiceName, MessageError> {
        let s = format!("supermvo/{}/{}", self.pipeline, topic.name());
        s.as_str()
            .try_into()
            .map_err(|e| MessageError::ipc(format!("service name '{s}'"), e))
    }

    /// Node name of a stage worker.
    pub fn node_name(&self, stage: &str, worker: u32) -> Result<NodeName, MessageError> {
        let s = format!("supermvo/{}/{stage}/{worker}", self.pipeline);
        s.as_str()
            .try_into()
            .map_err(|e| MessageError::ipc(format!("node name '{s}'"), e))
    }

    /// The samples a topic keeps for subscribers that join late (what one may request).
    pub fn history(topic: Topic) -> usize {
        Self::qos(topic).history
    }

    fn qos(topic: Topic) -> Qos {
        match topic {
            // data: lossless, back-pressure instead of overflow; history for restarts
            Topic::Frames
            | Topic::Features
            | Topic::Matches
            | Topic::Poses
            | Topic::MatchRequests
            | Topic::Keyframes
            | Topic::Corrections => Qos {
                history: HISTORY,
                buffer: 4 * HISTORY,
                safe_overflow: false,
            },
            // requests answered at once: no history (work no one did in time the tracker
            // does itself), never block the sender
            Topic::MappingRequests | Topic::MappingReplies => Qos {
                history: 0,
                buffer: 4,
                safe_overflow: true,
            },
            // last state only
            Topic::Backend | Topic::Control => Qos {
                history: 1,
                buffer: 4,
                safe_overflow: true,
            },
            // diagnostics: never block a stage, drop the oldest
            Topic::Progress => Qos {
                history: 0,
                buffer: 1024,
                safe_overflow: true,
            },
            // views: never block a stage; a little history for a viewer that attaches late
            Topic::View => Qos {
                history: 4,
                buffer: 32,
                safe_overflow: true,
            },
            Topic::ViewImages => Qos {
                history: 2,
                buffer: 8,
                safe_overflow: true,
            },
        }
    }

    /// Opens (or, with `create`, opens or creates) the `view` topic.
    pub fn view_topic(&self, node: &IpcNode, create: bool) -> Result<PubSubView, MessageError> {
        let topic = Topic::View;
        let b = Self::qos(topic).apply(
            node.service_builder(&self.service_name(topic)?)
                .publish_subscribe::<[f32]>()
                .user_header::<ViewHeader>(),
        );
        if create {
            b.open_or_create().map_err(|e| self.open_error(topic, e))
        } else {
            b.open().map_err(|e| self.open_error(topic, e))
        }
    }

    /// Opens (or, with `create`, opens or creates) a slice topic with frame headers.
    pub fn slice_topic<P>(
        &self,
        node: &IpcNode,
        topic: Topic,
        create: bool,
    ) -> Result<PubSubH<[P]>, MessageError>
    where
        P: std::fmt::Debug + ZeroCopySend + 'static,
    {
        let q = Self::qos(topic);
        let b = q.apply(
            node.service_builder(&self.service_name(topic)?)
                .publish_subscribe::<[P]>()
                .user_header::<FrameHeader>(),
        );
        if create {
            b.open_or_create().map_err(|e| self.open_error(topic, e))
        } else {
            b.open().map_err(|e| self.open_error(topic, e))
        }
    }

    /// Opens (or, with `create`, opens or creates) a fixed-size topic with frame headers.
    pub fn header_topic<P>(
        &self,
        node: &IpcNode,
        topic: Topic,
        create: bool,
    ) -> Result<PubSubH<P>, MessageError>
    where
        P: std::fmt::Debug + ZeroCopySend + 'static,
    {
        let q = Self::qos(topic);
        let b = q.apply(
            node.service_builder(&self.service_name(topic)?)
                .publish_subscribe::<P>()
                .user_header::<FrameHeader>(),
        );
        if create {
            b.open_or_create().map_err(|e| self.open_error(topic, e))
        } else {
            b.open().map_err(|e| self.open_error(topic, e))
        }
    }

    /// Opens (or creates) a fixed-size topic without header.
    pub fn plain_topic<P>(
        &self,
        node: &IpcNode,
        topic: Topic,
        create: bool,
    ) -> Result<PubSub<P>, MessageError>
    where
        P: std::fmt::Debug + ZeroCopySend + 'static,
    {
        let q = Self::qos(topic);
        let b = q.apply(
            node.service_builder(&self.service_name(topic)?)
                .publish_subscribe::<P>(),
        );
        if create {
            b.open_or_create().map_err(|e| self.open_error(topic, e))
        } else {
            b.open().map_err(|e| self.open_error(topic, e))
        }
    }

    fn open_error(&self, topic: Topic, e: impl std::fmt::Debug) -> MessageError {
        let detail = format!("{e:?}");
        if detail.contains("DoesNotExist") {
            MessageError::Ipc {
                what: format!(
                    "pipeline '{}' is not running (no service '{}')",
                    self.pipeline,
                    topic.name()
                ),
                detail: "start it with `supermvo run --mode multiprocess`, or check the name with `supermvo inspect`".into(),
            }
        } else {
            MessageError::Ipc {
                what: format!("service '{}' of pipeline '{}'", topic.name(), self.pipeline),
                detail,
            }
        }
    }
}

/// Limits iceoryx2's own log to errors (it warns that it runs on its built-in default
/// configuration, which is what SuPerMVO intends).
pub fn quiet_ipc_logs() {
    set_log_level(LogLevel::Error);
}

/// Creates a node for a pipeline process. iceoryx2's own signal handling is on, so SIGINT
/// and SIGTERM end `node.wait` and the process shuts down cleanly.
pub fn create_node(name: &NodeName) -> Result<IpcNode, MessageError> {
    quiet_ipc_logs();
    NodeBuilder::new()
        .name(name)
        .create::<Ipc>()
        .map_err(|e| MessageError::ipc(format!("creating node '{name}'"), e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use supermvo_features::Features;

    #[test]
    fn features_round_trip_through_the_flat_layout() {
        let f = Features {
            keypoints: vec![[1.5, 2.5], [3.0, 4.0]],
            scores: vec![0.9, 0.5],
            descriptors: (0..8).map(|v| v as f32 * 0.25).collect(),
            dim: 4,
            image_size: (640, 480),
        };
        let layout = FeatureLayout { n: 2, dim: 4 };
        let mut buf = vec![0.0; layout.len()];
        FeatureLayout::write(&f, &mut buf);
        let mut h = FrameHeader::new(3, 7, 0.7, Status::Ok);
        (h.count, h.dim, h.width, h.height) = (2, 4, 640, 480);
        let back = FeatureLayout::read(&h, &buf).unwrap();
        assert_eq!(back.keypoints, f.keypoints);
        assert_eq!(back.scores, f.scores);
        assert_eq!(back.descriptors, f.descriptors);
        assert_eq!(back.image_size, f.image_size);
        h.count = 3;
        assert!(matches!(
            FeatureLayout::read(&h, &buf),
            Err(MessageError::FeatureLayout { .. })
        ));
    }

    #[test]
    fn views_round_trip_through_the_flat_layout() {
        let v = supermvo_features::FrameView {
            keypoints: vec![[1.0, 2.0], [3.0, 4.0]],
            flow: vec![[5.0, 6.0, 7.0, 8.0]],
            map_points: Some(vec![[9.0, 10.0, 11.0]]),
        };
        let mut h = ViewHeader::default();
        let mut buf = vec![0.0; ViewLayout::len(&v)];
        ViewLayout::write(&v, &mut h, &mut buf);
        assert_eq!(ViewLayout::read(&h, &buf), Some(v.clone()));
        let no_map = supermvo_features::FrameView {
            map_points: None,
            ..v
        };
        let mut buf = vec![0.0; ViewLayout::len(&no_map)];
        ViewLayout::write(&no_map, &mut h, &mut buf);
        assert_eq!(ViewLayout::read(&h, &buf), Some(no_map));
        assert_eq!(ViewLayout::read(&h, &buf[1..]), None);
    }

    #[test]
    fn headers_reject_other_schema_versions() {
        let mut h = FrameHeader::new(0, 0, 0.0, Status::Ok);
        assert!(h.check().is_ok());
        h.schema = 99;
        assert!(h.check().unwrap_err().to_string().contains("99"));
    }

    #[test]
    fn status_and_stage_codes_round_trip() {
        for s in [
            Status::Ok,
            Status::Dropped,
            Status::Unreadable,
            Status::Lost,
            Status::EndOfStream,
            Status::NoReference,
        ] {
            assert_eq!(Status::from_u32(s as u32), s);
        }
        for k in StageKind::ALL {
            assert_eq!(StageKind::from_u32(k as u32), Some(k));
        }
    }

    #[test]
    fn a_pipeline_that_is_not_running_is_a_clear_error() {
        let svc = Services::new(&format!("absent-{}", std::process::id()));
        let node = create_node(&svc.node_name("test", 0).unwrap()).unwrap();
        let err = svc
            .slice_topic::<u8>(&node, Topic::Frames, false)
            .unwrap_err()
            .to_string();
        assert!(err.contains("is not running"), "{err}");
    }
}
