//! Diagnostic views in Foxglove's formats: `supermvo run --record FILE.mcap` (in process, or
//! beside the daemon), `supermvo record FILE.mcap` (attached to a running pipeline, read
//! only) and `supermvo view` (a live Foxglove WebSocket view of a running pipeline). The
//! channels are in `supermvo_record::CHANNELS` and docs/recording.md.

use anyhow::{Context, Result};
use clap::Args;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use supermvo_dataset::GrayImage;
use supermvo_record::{FrameRecord, FrameView, ImageRef, RecordOptions, Recorder, Timing};
use supermvo_vo::loops::LoopEdge;
use supermvo_vo::tracker::FrameOutput;

/// `supermvo run`'s recording flags.
#[derive(Debug, Clone, Args)]
pub struct RunRecordArgs {
    /// Record the run as MCAP (Foxglove schemas: image, keypoints and match flow, pose,
    /// transforms, path, map points, loops, timing; docs/recording.md). Replaces the file.
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    /// With --record: the image of every n-th frame only (0: no images).
    #[arg(long, default_value_t = 1, value_name = "N")]
    pub record_image_every: u64,
    /// With --record: stop recording images after this many MiB of them (poses go on).
    #[arg(long, value_name = "MIB", value_parser = positive_mib)]
    pub record_max_mib: Option<f64>,
}

impl RunRecordArgs {
    /// The options of the recording.
    pub fn options(&self) -> RecordOptions {
        RecordOptions {
            image_every: self.record_image_every,
            max_image_mib: self.record_max_mib,
            ..RecordOptions::default()
        }
    }
}

/// A size limit in MiB: a positive number.
pub fn positive_mib(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("'{s}' is not a positive number of MiB")),
    }
}

/// Recording of an in-process run: each frame's result, image and view as it is tracked, and
/// each loop the loop closer adds.
pub struct InprocessRecording {
    recorder: Recorder,
    path: PathBuf,
    positions: BTreeMap<usize, [f64; 3]>,
    loops_seen: usize,
}

impl std::fmt::Debug for InprocessRecording {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "InprocessRecording({})", self.path.display())
    }
}

impl InprocessRecording {
    /// Opens `path` for writing.
    pub fn create(path: &Path, opts: RecordOptions) -> Result<Self> {
        Ok(Self {
            recorder: Recorder::to_mcap(path, opts)?,
            path: path.to_path_buf(),
            positions: BTreeMap::new(),
            loops_seen: 0,
        })
    }

    /// Records one tracked frame, its image and view, the time it took, and the loops closed
    /// since the last frame.
    pub fn frame(
        &mut self,
        out: &FrameOutput,
        image: Option<&GrayImage>,
        view: Option<&FrameView>,
        frame_ms: f64,
        loops: &[LoopEdge],
    ) {
        let state = serde_json::to_value(out.state).unwrap_or_default();
        let record = FrameRecord {
            seq: out.index as u64,
            frame: out.index as u64,
            stamp: out.stamp,
            state: state.as_str().unwrap_or("unknown"),
            t_world_cam: out.pose,
            keyframe: out.keyframe,
            counts: [out.keypoints, out.matches, out.inliers, out.landmarks].map(|v| v as u64),
            view,
            image: image.map(|i| ImageRef {
                width: i.width as u32,
                height: i.height as u32,
                pixels: &i.data,
            }),
        };
        self.recorder.frame(&record);
        self.recorder.timing(&Timing {
            frame: out.index as u64,
            stamp: out.stamp,
            stage_ms: vec![("frame".into(), frame_ms)],
            ..Timing::default()
        });
        if let Some(p) = out.pose {
            self.positions.insert(out.index, [p[3], p[7], p[11]]);
        }
        for edge in loops.iter().skip(self.loops_seen) {
            let (q, m) = (edge.query_frame, edge.match_frame);
            if let (Some(a), Some(b)) = (self.positions.get(&q), self.positions.get(&m)) {
                self.recorder
                    .loop_closure(out.stamp, (q as u64, m as u64), (*a, *b));
            }
        }
        self.loops_seen = self.loops_seen.max(loops.len());
    }

    /// Closes the file; says what it holds.
    pub fn finish(self) -> Result<()> {
        let path = self.path;
        let s = self
            .recorder
            .finish()
            .with_context(|| format!("closing {}", path.display()))?;
        let stopped = s
            .images_stopped_at
            .map(|f| format!(" (images stopped at frame {f}: size limit)"))
            .unwrap_or_default();
        outln!(
            "recorded {} frames ({} posed, {} images, {:.1} MiB of JPEG){stopped} to {}",
            s.frames,
            s.poses,
            s.images,
            s.image_bytes as f64 / (1024.0 * 1024.0),
            path.display()
        );
        Ok(())
    }
}
