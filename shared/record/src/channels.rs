//! The channels a recording or live view carries, and how each record becomes a Foxglove
//! message. Frames: `world` is the first keyframe's camera (the trajectory's frame), `camera`
//! the current camera (x right, y down, z forward, as images are annotated).

use foxglove::messages::{
    Color, CompressedImage, FrameTransform, FrameTransforms, ImageAnnotations, LinePrimitive, Log,
    PackedElementField, Point2, Point3, PointCloud, PointsAnnotation, Pose, PoseInFrame,
    Quaternion, SceneEntity, SceneUpdate, Timestamp, Vector3,
};
use foxglove::{Channel, Context, PartialMetadata, RawChannel, Schema};
use std::sync::Arc;

/// Every channel: topic, schema, what it carries (the table in docs/recording.md).
pub const CHANNELS: [(&str, &str, &str); 10] = [
    (
        "/camera/image",
        "foxglove.CompressedImage",
        "the grey camera image, JPEG (every `image_every`-th frame)",
    ),
    (
        "/camera/features",
        "foxglove.ImageAnnotations",
        "keypoints (points) and the flow of the matches to the reference keyframe (line list)",
    ),
    (
        "/camera/pose",
        "foxglove.PoseInFrame",
        "`T_world_cam` of every posed frame, in `world`",
    ),
    (
        "/tf",
        "foxglove.FrameTransforms",
        "the transform `world` -> `camera` of every posed frame",
    ),
    (
        "/trajectory",
        "foxglove.SceneUpdate",
        "the path, one line segment per posed frame (entity `trajectory/<seq>`)",
    ),
    (
        "/map/points",
        "foxglove.PointCloud",
        "the local map's points in `world` (x, y, z float32), on keyframes",
    ),
    (
        "/loops",
        "foxglove.SceneUpdate",
        "a line between the two camera positions of each closed loop",
    ),
    (
        "/log",
        "foxglove.Log",
        "events: loop closures, images stopped at the size limit",
    ),
    (
        "/supermvo/frame",
        "supermvo.Frame (JSON)",
        "per frame: seq, frame, state, keyframe, keypoints, matches, inliers, landmarks",
    ),
    (
        "/supermvo/timing",
        "supermvo.Timing (JSON)",
        "per frame: each stage's time, capture-to-pose latency, frames dropped and lost so far",
    ),
];

const FRAME_SCHEMA: &str = r#"{"type":"object","properties":{"seq":{"type":"integer"},"frame":{"type":"integer"},"stamp":{"type":"number"},"state":{"type":"string"},"keyframe":{"type":"boolean"},"keypoints":{"type":"integer"},"matches":{"type":"integer"},"inliers":{"type":"integer"},"landmarks":{"type":"integer"}}}"#;
const TIMING_SCHEMA: &str = r#"{"type":"object","properties":{"frame":{"type":"integer"},"stamp":{"type":"number"},"stage_ms":{"type":"object","additionalProperties":{"type":"number"}},"capture_to_pose_ms":{"type":["number","null"]},"dropped":{"type":"integer"},"lost":{"type":"integer"}}}"#;

/// The open channels of one recorder.
pub(crate) struct Channels {
    pub(crate) image: Channel<CompressedImage>,
    pub(crate) features: Channel<ImageAnnotations>,
    pub(crate) pose: Channel<PoseInFrame>,
    pub(crate) tf: Channel<FrameTransforms>,
    pub(crate) trajectory: Channel<SceneUpdate>,
    pub(crate) map: Channel<PointCloud>,
    pub(crate) loops: Channel<SceneUpdate>,
    pub(crate) log: Channel<Log>,
    pub(crate) frame: Arc<RawChannel>,
    pub(crate) timing: Arc<RawChannel>,
}

impl Channels {
    /// Opens every channel of [`CHANNELS`] on `ctx`.
    pub(crate) fn open(ctx: &Arc<Context>) -> Result<Self, foxglove::FoxgloveError> {
        let json = |topic: &str, name: &str, schema: &'static str| {
            ctx.channel_builder(topic)
                .message_encoding("json")
                .schema(Schema::new(name, "jsonschema", schema.as_bytes()))
                .build_raw()
        };
        Ok(Self {
            image: ctx.channel_builder(CHANNELS[0].0).build(),
            features: ctx.channel_builder(CHANNELS[1].0).build(),
            pose: ctx.channel_builder(CHANNELS[2].0).build(),
            tf: ctx.channel_builder(CHANNELS[3].0).build(),
            trajectory: ctx.channel_builder(CHANNELS[4].0).build(),
            map: ctx.channel_builder(CHANNELS[5].0).build(),
            loops: ctx.channel_builder(CHANNELS[6].0).build(),
            log: ctx.channel_builder(CHANNELS[7].0).build(),
            frame: json(CHANNELS[8].0, "supermvo.Frame", FRAME_SCHEMA)?,
            timing: json(CHANNELS[9].0, "supermvo.Timing", TIMING_SCHEMA)?,
        })
    }
}

/// A dataset time in seconds as a Foxglove timestamp (negative times clamp to 0).
pub(crate) fn timestamp(stamp: f64) -> Timestamp {
    let s = stamp.max(0.0);
    let sec = s.floor();
    Timestamp::new(
        sec as u32,
        ((s - sec) * 1e9).round().min(999_999_999.0) as u32,
    )
}

/// The log time of a message stamped `stamp` seconds.
pub(crate) fn at(stamp: f64) -> PartialMetadata {
    PartialMetadata::with_log_time((stamp.max(0.0) * 1e9).round() as u64)
}

/// Position and orientation of the camera in the world.
pub(crate) fn pose(t_world_cam: &supermvo_geometry::Pose) -> Pose {
    let q = t_world_cam.quaternion();
    Pose {
        position: Some(Vector3 {
            x: t_world_cam.t.x,
            y: t_world_cam.t.y,
            z: t_world_cam.t.z,
        }),
        orientation: Some(Quaternion {
            x: q.i,
            y: q.j,
            z: q.k,
            w: q.w,
        }),
    }
}

/// `T_world_cam` as the transform `world` -> `camera`.
pub(crate) fn transform(stamp: f64, t_world_cam: &supermvo_geometry::Pose) -> FrameTransforms {
    let p = pose(t_world_cam);
    FrameTransforms {
        transforms: vec![FrameTransform {
            timestamp: Some(timestamp(stamp)),
            parent_frame_id: "world".into(),
            child_frame_id: "camera".into(),
            translation: p.position,
            rotation: p.orientation,
        }],
    }
}

const GREEN: Color = Color {
    r: 0.2,
    g: 0.9,
    b: 0.3,
    a: 1.0,
};
const ORANGE: Color = Color {
    r: 1.0,
    g: 0.6,
    b: 0.1,
    a: 0.8,
};
const BLUE: Color = Color {
    r: 0.2,
    g: 0.5,
    b: 1.0,
    a: 1.0,
};
const RED: Color = Color {
    r: 1.0,
    g: 0.2,
    b: 0.2,
    a: 1.0,
};

/// Keypoints as points, the match flow as a line list, on the image.
pub(crate) fn annotations(stamp: f64, view: &supermvo_features::FrameView) -> ImageAnnotations {
    let ts = Some(timestamp(stamp));
    let keypoints = PointsAnnotation {
        timestamp: ts,
        r#type: 1, // points
        points: view
            .keypoints
            .iter()
            .map(|k| Point2 {
                x: k[0] as f64,
                y: k[1] as f64,
            })
            .collect(),
        outline_color: Some(GREEN),
        thickness: 3.0,
        ..Default::default()
    };
    let flow = PointsAnnotation {
        timestamp: ts,
        r#type: 4, // line list
        points: view
            .flow
            .iter()
            .flat_map(|f| {
                [
                    Point2 {
                        x: f[0] as f64,
                        y: f[1] as f64,
                    },
                    Point2 {
                        x: f[2] as f64,
                        y: f[3] as f64,
                    },
                ]
            })
            .collect(),
        outline_color: Some(ORANGE),
        thickness: 1.0,
        ..Default::default()
    };
    ImageAnnotations {
        timestamp: ts,
        points: vec![keypoints, flow],
        ..Default::default()
    }
}

/// A line segment from `from` to `to` in `world`, as a scene entity `id`.
pub(crate) fn segment(
    stamp: f64,
    id: String,
    from: [f64; 3],
    to: [f64; 3],
    loop_edge: bool,
) -> SceneUpdate {
    let p = |v: [f64; 3]| Point3 {
        x: v[0],
        y: v[1],
        z: v[2],
    };
    SceneUpdate {
        entities: vec![SceneEntity {
            timestamp: Some(timestamp(stamp)),
            frame_id: "world".into(),
            id,
            lines: vec![LinePrimitive {
                r#type: 0, // line strip
                thickness: if loop_edge { 4.0 } else { 2.0 },
                scale_invariant: true,
                points: vec![p(from), p(to)],
                color: Some(if loop_edge { RED } else { BLUE }),
                ..Default::default()
            }],
            ..Default::default()
        }],
        ..Default::default()
    }
}

/// Points in `world` as a point cloud of float32 x, y, z.
pub(crate) fn point_cloud(stamp: f64, points: &[[f32; 3]]) -> PointCloud {
    let mut data = Vec::with_capacity(points.len() * 12);
    for p in points {
        for v in p {
            data.extend_from_slice(&v.to_le_bytes());
        }
    }
    let field = |name: &str, offset: u32| PackedElementField {
        name: name.into(),
        offset,
        r#type: 7, // float32
    };
    PointCloud {
        timestamp: Some(timestamp(stamp)),
        frame_id: "world".into(),
        pose: None,
        point_stride: 12,
        fields: vec![field("x", 0), field("y", 4), field("z", 8)],
        data: data.into(),
    }
}

/// An info-level log line.
pub(crate) fn log(stamp: f64, message: String) -> Log {
    Log {
        timestamp: Some(timestamp(stamp)),
        level: 2, // info
        message,
        name: "supermvo".into(),
        ..Default::default()
    }
}

/// A JPEG of the grey image.
pub(crate) fn compressed(
    stamp: f64,
    image: &crate::ImageRef<'_>,
    quality: u8,
) -> Option<CompressedImage> {
    let mut jpeg = Vec::new();
    let ok = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, quality)
        .encode(
            image.pixels,
            image.width,
            image.height,
            image::ExtendedColorType::L8,
        )
        .map_err(|e| tracing::warn!("image of stamp {stamp}: JPEG encoding failed: {e}"))
        .is_ok();
    ok.then(|| CompressedImage {
        timestamp: Some(timestamp(stamp)),
        frame_id: "camera".into(),
        data: jpeg.into(),
        format: "jpeg".into(),
    })
}
