//! Diagnostic views of a SuPerMVO run in the Foxglove schemas: an MCAP file
//! ([`Recorder::to_mcap`], read by Foxglove, the `mcap` CLI and its Python and C++ readers) or
//! a live view served over the Foxglove WebSocket protocol ([`Recorder::serve`], opened by
//! Foxglove's "Open connection"). Both carry the same channels ([`CHANNELS`]); the records
//! come from an in-process run or from a subscriber attached to the daemon, and know nothing
//! about either.
//!
//! Times: every message is stamped, and logged, at the frame's dataset time (`times.txt`), so
//! a recording replays at the camera's rate and two recordings of one run are alike.

mod channels;

pub use channels::CHANNELS;
pub use supermvo_features::FrameView;
pub use supermvo_geometry::Pose;

use channels::Channels;
use foxglove::{Context, McapWriterHandle, WebSocketServer, WebSocketServerHandle};
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Errors of a recorder.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The MCAP file could not be created or written.
    #[error(
        "{path}: cannot write the recording ({detail}); check the folder exists and is writable"
    )]
    File {
        /// The file.
        path: PathBuf,
        /// Why.
        detail: String,
    },
    /// The live view could not listen.
    #[error("live view on {host}:{port}: {detail}; choose another --port, or 0 for any free one")]
    Serve {
        /// Address.
        host: String,
        /// Port.
        port: u16,
        /// Why.
        detail: String,
    },
    /// A channel could not be opened.
    #[error("opening channel: {0}")]
    Channel(String),
}

/// What is recorded, and how much.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordOptions {
    /// Record the image of every n-th frame only (1: every frame; 0: none). Poses,
    /// annotations and timing are recorded for every frame.
    pub image_every: u64,
    /// Stop recording images (and their annotations) once this many MiB of them were written;
    /// poses, map points and timing go on. `None`: no limit.
    pub max_image_mib: Option<f64>,
    /// JPEG quality, 1-100.
    pub jpeg_quality: u8,
}

impl Default for RecordOptions {
    fn default() -> Self {
        Self {
            image_every: 1,
            max_image_mib: None,
            jpeg_quality: 80,
        }
    }
}

/// A grey image: `width * height` bytes, row-major.
#[derive(Debug, Clone, Copy)]
pub struct ImageRef<'a> {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Pixels.
    pub pixels: &'a [u8],
}

/// One frame's result, as a recorder takes it.
#[derive(Debug, Clone, Copy)]
pub struct FrameRecord<'a> {
    /// Sequence number in the run.
    pub seq: u64,
    /// Frame index in the dataset.
    pub frame: u64,
    /// Dataset time, seconds.
    pub stamp: f64,
    /// Tracking state ("initialising", "tracking", "lost", ...).
    pub state: &'a str,
    /// The camera's pose in the world, when posed.
    pub t_world_cam: Option<Pose>,
    /// Whether the frame became a keyframe.
    pub keyframe: bool,
    /// Keypoints detected, matches to the reference, pose inliers, landmarks in the map.
    pub counts: [u64; 4],
    /// Keypoints, flow and map points, when known.
    pub view: Option<&'a FrameView>,
    /// The camera image, when known.
    pub image: Option<ImageRef<'a>>,
}

/// Per-frame timing, as a recorder takes it.
#[derive(Debug, Clone, Default)]
pub struct Timing {
    /// Frame index.
    pub frame: u64,
    /// Dataset time, seconds.
    pub stamp: f64,
    /// Time per stage (or "frame" in process), milliseconds.
    pub stage_ms: Vec<(String, f64)>,
    /// Capture to pose, milliseconds (the daemon).
    pub capture_to_pose_ms: Option<f64>,
    /// Frames dropped at ingest so far.
    pub dropped: u64,
    /// Frames lost in the pipeline so far.
    pub lost: u64,
}

/// What a recorder wrote.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RecordSummary {
    /// Frames recorded.
    pub frames: u64,
    /// Frames with a pose.
    pub poses: u64,
    /// Images recorded.
    pub images: u64,
    /// Bytes of JPEG written.
    pub image_bytes: u64,
    /// The frame at which images stopped (size limit), if they did.
    pub images_stopped_at: Option<u64>,
}

enum Sink {
    Mcap(McapWriterHandle<BufWriter<std::fs::File>>, PathBuf),
    Live(WebSocketServerHandle),
}

/// Writes the records of a run to an MCAP file or serves them live (see the crate docs).
pub struct Recorder {
    _ctx: Arc<Context>,
    channels: Channels,
    sink: Option<Sink>,
    opts: RecordOptions,
    summary: RecordSummary,
    last_position: Option<[f64; 3]>,
    /// Camera position of every posed frame, by frame index (for loop edges).
    positions: std::collections::BTreeMap<u64, [f64; 3]>,
    /// The most recent frames recorded without a pose, by sequence number: `(frame,
    /// stamp)`, for a pose that comes later ([`Recorder::late_pose`]).
    unposed: std::collections::BTreeMap<u64, (u64, f64)>,
}

/// Unposed frames a recorder remembers for poses that come later (the tracker poses at most
/// 16 frames late).
const UNPOSED_KEPT: usize = 64;

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Recorder({:?})", self.summary)
    }
}

impl Recorder {
    /// A recorder writing `path` (replaced if it exists).
    pub fn to_mcap(path: &Path, opts: RecordOptions) -> Result<Self, RecordError> {
        let file_error = |detail: String| RecordError::File {
            path: path.to_path_buf(),
            detail,
        };
        let file = std::fs::File::create(path).map_err(|e| file_error(e.to_string()))?;
        let ctx = Context::new();
        let handle = ctx
            .mcap_writer()
            .create(BufWriter::new(file))
            .map_err(|e| file_error(e.to_string()))?;
        Self::with_sink(ctx, Sink::Mcap(handle, path.to_path_buf()), opts)
    }

    /// A recorder serving a live view on `host:port` (port 0: any free one; see
    /// [`Recorder::port`]).
    pub fn serve(host: &str, port: u16, opts: RecordOptions) -> Result<Self, RecordError> {
        let ctx = Context::new();
        let handle = WebSocketServer::new()
            .name("supermvo")
            .context(&ctx)
            .bind(host, port)
            .start_blocking()
            .map_err(|e| RecordError::Serve {
                host: host.into(),
                port,
                detail: e.to_string(),
            })?;
        Self::with_sink(ctx, Sink::Live(handle), opts)
    }

    fn with_sink(ctx: Arc<Context>, sink: Sink, opts: RecordOptions) -> Result<Self, RecordError> {
        let channels = Channels::open(&ctx).map_err(|e| RecordError::Channel(e.to_string()))?;
        Ok(Self {
            _ctx: ctx,
            channels,
            sink: Some(sink),
            opts,
            summary: RecordSummary::default(),
            last_position: None,
            positions: std::collections::BTreeMap::new(),
            unposed: std::collections::BTreeMap::new(),
        })
    }

    /// The port of a live view (`None` for a file).
    pub fn port(&self) -> Option<u16> {
        match &self.sink {
            Some(Sink::Live(h)) => Some(h.port()),
            _ => None,
        }
    }

    /// Records one frame: state, pose, transform, path segment, and where known the image
    /// with its annotations and the map's points.
    pub fn frame(&mut self, f: &FrameRecord<'_>) {
        let at = channels::at(f.stamp);
        let state = serde_json::json!({
            "seq": f.seq, "frame": f.frame, "stamp": f.stamp, "state": f.state,
            "keyframe": f.keyframe, "keypoints": f.counts[0], "matches": f.counts[1],
            "inliers": f.counts[2], "landmarks": f.counts[3],
        });
        self.channels
            .frame
            .log_with_meta(state.to_string().as_bytes(), at);
        self.summary.frames += 1;
        match &f.t_world_cam {
            Some(t) => self.pose(f, t),
            None => {
                self.unposed.insert(f.seq, (f.frame, f.stamp));
                if self.unposed.len() > UNPOSED_KEPT {
                    self.unposed.pop_first();
                }
            }
        }
        if let Some(points) = f.view.and_then(|v| v.map_points.as_ref()) {
            let cloud = channels::point_cloud(f.stamp, points);
            self.channels.map.log_with_meta(&cloud, at);
        }
        self.image(f);
    }

    /// The pose of an earlier frame (sequence number `seq`), recorded without one, that a
    /// later frame made known (the tracker poses the frames seen while it initialised once
    /// the map exists): its pose and transform at that frame's time. Ignored for a frame not
    /// among the last unposed ones recorded.
    pub fn late_pose(&mut self, seq: u64, t_world_cam: &Pose) {
        let Some((frame, stamp)) = self.unposed.remove(&seq) else {
            return;
        };
        self.pose_at(stamp, t_world_cam);
        self.positions.insert(frame, position(t_world_cam));
    }

    /// Pose and transform messages at `stamp`.
    fn pose_at(&mut self, stamp: f64, t: &Pose) {
        let at = channels::at(stamp);
        let pose = foxglove::messages::PoseInFrame {
            timestamp: Some(channels::timestamp(stamp)),
            frame_id: "world".into(),
            pose: Some(channels::pose(t)),
        };
        self.channels.pose.log_with_meta(&pose, at);
        self.channels
            .tf
            .log_with_meta(&channels::transform(stamp, t), at);
        self.summary.poses += 1;
    }

    fn pose(&mut self, f: &FrameRecord<'_>, t: &Pose) {
        let at = channels::at(f.stamp);
        self.pose_at(f.stamp, t);
        let position = position(t);
        if let Some(prev) = self.last_position {
            let id = format!("trajectory/{}", f.seq);
            let segment = channels::segment(f.stamp, id, prev, position, false);
            self.channels.trajectory.log_with_meta(&segment, at);
        }
        self.last_position = Some(position);
        self.positions.insert(f.frame, position);
    }

    fn image(&mut self, f: &FrameRecord<'_>) {
        let Some(image) = f.image else {
            return;
        };
        if self.opts.image_every == 0 || !f.seq.is_multiple_of(self.opts.image_every) {
            return;
        }
        if self.summary.images_stopped_at.is_some() {
            return;
        }
        let limit = self
            .opts
            .max_image_mib
            .map(|m| (m * 1024.0 * 1024.0) as u64);
        if limit.is_some_and(|l| self.summary.image_bytes >= l) {
            self.summary.images_stopped_at = Some(f.frame);
            let text = format!(
                "images stopped at frame {}: {} MiB limit reached; poses, map and timing go on",
                f.frame,
                self.opts.max_image_mib.unwrap_or_default()
            );
            tracing::warn!("{text}");
            self.channels
                .log
                .log_with_meta(&channels::log(f.stamp, text), channels::at(f.stamp));
            return;
        }
        let Some(jpeg) = channels::compressed(f.stamp, &image, self.opts.jpeg_quality) else {
            return;
        };
        let at = channels::at(f.stamp);
        self.summary.image_bytes += jpeg.data.len() as u64;
        self.summary.images += 1;
        self.channels.image.log_with_meta(&jpeg, at);
        if let Some(view) = f.view {
            let notes = channels::annotations(f.stamp, view);
            self.channels.features.log_with_meta(&notes, at);
        }
    }

    /// Records a closed loop between two recorded frames `(query, match)`: a line between
    /// their camera positions (when both were posed) and a log line.
    pub fn loop_closure(&mut self, stamp: f64, frames: (u64, u64)) {
        let at = channels::at(stamp);
        if let (Some(a), Some(b)) = (self.positions.get(&frames.0), self.positions.get(&frames.1)) {
            let id = format!("loop/{}-{}", frames.0, frames.1);
            let edge = channels::segment(stamp, id, *a, *b, true);
            self.channels.loops.log_with_meta(&edge, at);
        }
        let text = format!(
            "loop closed: frame {} recognised frame {}",
            frames.0, frames.1
        );
        self.channels
            .log
            .log_with_meta(&channels::log(stamp, text), at);
    }

    /// Records one frame's timing.
    pub fn timing(&mut self, t: &Timing) {
        let stages: serde_json::Map<String, serde_json::Value> = t
            .stage_ms
            .iter()
            .map(|(k, v)| (k.clone(), serde_json::json!(v)))
            .collect();
        let msg = serde_json::json!({
            "frame": t.frame, "stamp": t.stamp, "stage_ms": stages,
            "capture_to_pose_ms": t.capture_to_pose_ms, "dropped": t.dropped, "lost": t.lost,
        });
        self.channels
            .timing
            .log_with_meta(msg.to_string().as_bytes(), channels::at(t.stamp));
    }

    /// What was recorded so far.
    pub fn summary(&self) -> RecordSummary {
        self.summary
    }

    /// Closes the file (or stops the live view); returns what was recorded.
    pub fn finish(mut self) -> Result<RecordSummary, RecordError> {
        match self.sink.take() {
            Some(Sink::Mcap(handle, path)) => {
                handle.close().map_err(|e| RecordError::File {
                    path,
                    detail: e.to_string(),
                })?;
            }
            Some(Sink::Live(handle)) => {
                let _ = handle.stop();
            }
            None => {}
        }
        Ok(self.summary)
    }
}

/// The camera's position in the world, as a trajectory point.
fn position(t_world_cam: &Pose) -> [f64; 3] {
    [t_world_cam.t.x, t_world_cam.t.y, t_world_cam.t.z]
}

#[cfg(test)]
mod tests {
    use super::*;
    use supermvo_geometry::{Mat3, Vec3};

    fn record_frames(path: &Path, opts: RecordOptions, n: u64) -> RecordSummary {
        let mut rec = Recorder::to_mcap(path, opts).unwrap();
        // a textured image, so that the JPEGs are of realistic size
        let (w, h) = (320u32, 240u32);
        let pixels: Vec<u8> = (0..w * h).map(|i| ((i * 7919) % 251) as u8).collect();
        let view = FrameView {
            keypoints: vec![[10.0, 20.0], [30.5, 40.5]],
            flow: vec![[9.0, 19.0, 10.0, 20.0]],
            map_points: Some(vec![[0.0, 1.0, 2.0]]),
        };
        for i in 0..n {
            let t = Pose::new(Mat3::identity(), Vec3::new(0.0, 0.0, i as f64 * 0.5));
            rec.frame(&FrameRecord {
                seq: i,
                frame: i,
                stamp: i as f64 * 0.1,
                state: "tracking",
                t_world_cam: Some(t),
                keyframe: i % 3 == 0,
                counts: [2, 1, 1, 1],
                view: Some(&view),
                image: Some(ImageRef {
                    width: w,
                    height: h,
                    pixels: &pixels,
                }),
            });
        }
        rec.loop_closure(n as f64 * 0.1, (n - 1, 0));
        rec.finish().unwrap()
    }

    /// Messages per topic, read back with the `mcap` crate.
    fn counts(path: &Path) -> BTreeMap<String, usize> {
        let bytes = std::fs::read(path).unwrap();
        let mut out = BTreeMap::new();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            *out.entry(m.unwrap().channel.topic.clone()).or_default() += 1;
        }
        out
    }

    use std::collections::BTreeMap;

    #[test]
    fn every_frame_is_recorded_and_images_follow_the_options() {
        let dir = tempfile::tempdir().unwrap();
        let all = dir.path().join("all.mcap");
        let s = record_frames(&all, RecordOptions::default(), 10);
        assert_eq!((s.frames, s.poses, s.images), (10, 10, 10));
        let c = counts(&all);
        assert_eq!(c["/camera/pose"], 10);
        assert_eq!(c["/tf"], 10);
        assert_eq!(c["/trajectory"], 9, "one segment between consecutive poses");
        assert_eq!(c["/camera/image"], 10);
        assert_eq!(c["/camera/features"], 10);
        assert_eq!(c["/map/points"], 10);
        assert_eq!(c["/loops"], 1);
        assert_eq!(c["/log"], 1);
        assert_eq!(c["/supermvo/frame"], 10);

        let every3 = dir.path().join("every3.mcap");
        let opts = RecordOptions {
            image_every: 3,
            ..RecordOptions::default()
        };
        let s = record_frames(&every3, opts, 10);
        assert_eq!(s.images, 4, "frames 0, 3, 6, 9");
        assert_eq!(counts(&every3)["/camera/pose"], 10, "poses of every frame");
    }

    #[test]
    fn images_stop_at_the_size_limit_and_poses_go_on() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("limited.mcap");
        let one = record_frames(&dir.path().join("one.mcap"), RecordOptions::default(), 1);
        // room for about two and a half images
        let opts = RecordOptions {
            max_image_mib: Some(2.5 * one.image_bytes as f64 / (1024.0 * 1024.0)),
            ..RecordOptions::default()
        };
        let s = record_frames(&path, opts, 10);
        assert_eq!(s.images, 3, "{s:?}");
        assert_eq!(s.images_stopped_at, Some(3));
        let c = counts(&path);
        assert_eq!(c["/camera/image"], 3);
        assert_eq!(c["/camera/pose"], 10);
        assert_eq!(c["/log"], 2, "the stop is logged (and the loop)");
    }

    #[test]
    fn an_unwritable_path_is_one_clear_error() {
        let err = Recorder::to_mcap(
            Path::new("/nonexistent-dir/x.mcap"),
            RecordOptions::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("/nonexistent-dir/x.mcap") && err.contains("writable"),
            "{err}"
        );
    }

    /// docs/recording.md's channel table is [`CHANNELS`], row for row.
    #[test]
    fn the_documented_channels_are_the_channels() {
        let doc = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../docs/recording.md"
        ))
        .unwrap();
        for (topic, schema, what) in CHANNELS {
            let row = format!("| `{topic}` | `{schema}` | {what} |");
            assert!(doc.contains(&row), "docs/recording.md lacks {row}");
        }
    }
}
