//! Diagnostic views in Foxglove's formats: `supermvo run --record FILE.mcap` (in process, or
//! beside the daemon), `supermvo record FILE.mcap` (attached to a running pipeline, read
//! only) and `supermvo view` (a live Foxglove WebSocket view of a running pipeline). The
//! channels are in `supermvo_record::CHANNELS` and docs/recording.md.

use anyhow::{Context, Result};
use clap::Args;
use std::path::{Path, PathBuf};
use supermvo_dataset::GrayImage;
use supermvo_record::{FrameRecord, FrameView, ImageRef, Pose, RecordOptions, Recorder, Timing};
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
            t_world_cam: out.t_world_cam,
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
        for late in &out.backfilled {
            self.recorder
                .late_pose(late.index as u64, &late.t_world_cam);
        }
        self.recorder.timing(&Timing {
            frame: out.index as u64,
            stamp: out.stamp,
            stage_ms: vec![("frame".into(), frame_ms)],
            ..Timing::default()
        });
        for edge in loops.iter().skip(self.loops_seen) {
            let frames = (edge.query_frame as u64, edge.match_frame as u64);
            self.recorder.loop_closure(out.stamp, frames);
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

/// What `record` and `view` keep of a running pipeline.
#[derive(Debug, Clone, Args)]
pub struct ViewOptionArgs {
    /// The image of every n-th frame only (0: no images).
    #[arg(long, default_value_t = 1, value_name = "N")]
    pub image_every: u64,
    /// Stop sending images after this many MiB of them (poses go on).
    #[arg(long, value_name = "MIB", value_parser = positive_mib)]
    pub max_image_mib: Option<f64>,
    /// Pipeline name (`pipeline.name` of the running daemon).
    #[arg(long, default_value = "supermvo")]
    pub name: String,
    /// Seconds to wait for the pipeline to start.
    #[arg(long, default_value_t = 60.0, value_name = "S")]
    pub wait: f64,
}

impl ViewOptionArgs {
    fn options(&self) -> RecordOptions {
        RecordOptions {
            image_every: self.image_every,
            max_image_mib: self.max_image_mib,
            ..RecordOptions::default()
        }
    }

    fn attach(&self) -> Result<Viewer> {
        let wait = std::time::Duration::from_secs_f64(self.wait.max(0.0));
        Viewer::attach(&self.name, wait).with_context(|| {
            format!(
                "attaching to pipeline '{}' (start it with `supermvo run SEQ --name {}`)",
                self.name, self.name
            )
        })
    }
}

/// `supermvo record`: attach to a running pipeline and record it as MCAP until its end.
#[derive(Debug, Args)]
pub struct RecordArgs {
    /// The MCAP file to write (replaced if it exists).
    file: PathBuf,
    #[command(flatten)]
    view: ViewOptionArgs,
}

/// `supermvo view`: serve a running pipeline live over the Foxglove WebSocket protocol.
#[derive(Debug, Args)]
pub struct ViewArgs {
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1")]
    host: String,
    /// Port to listen on (0: any free one, printed).
    #[arg(long, default_value_t = 8765)]
    port: u16,
    #[command(flatten)]
    view: ViewOptionArgs,
}

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use supermvo_pipeline::viewer::{ViewEvent, Viewer};

/// Ctrl-C (or SIGTERM) sets the returned flag.
fn stop_on_ctrl_c() -> Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst))
        .context("installing the Ctrl-C handler")?;
    Ok(stop)
}

/// Runs `supermvo record`.
pub fn record(args: &RecordArgs) -> Result<()> {
    let stop = stop_on_ctrl_c()?;
    let mut viewer = args.view.attach()?;
    let mut recorder = Recorder::to_mcap(&args.file, args.view.options())?;
    outln!(
        "recording pipeline '{}' to {} (Ctrl-C stops)",
        args.view.name,
        args.file.display()
    );
    let end = follow(&mut viewer, &mut recorder, &stop, &args.view.name)?;
    let s = recorder.finish()?;
    outln!(
        "recorded {} frames ({} posed, {} images) to {} ({end})",
        s.frames,
        s.poses,
        s.images,
        args.file.display()
    );
    Ok(())
}

/// Runs `supermvo view`.
pub fn view(args: &ViewArgs) -> Result<()> {
    let stop = stop_on_ctrl_c()?;
    let mut viewer = args.view.attach()?;
    let mut recorder = Recorder::serve(&args.host, args.port, args.view.options())?;
    let port = recorder.port().unwrap_or(args.port);
    outln!(
        "live view of pipeline '{}' on ws://{}:{port} (Foxglove: Open connection; Ctrl-C stops)",
        args.view.name,
        args.host
    );
    let end = follow(&mut viewer, &mut recorder, &stop, &args.view.name)?;
    let s = recorder.finish()?;
    outln!("served {} frames ({end})", s.frames);
    Ok(())
}

/// Records beside a daemon run (`supermvo run --record` without `--mode inprocess`): a thread
/// attached to pipeline `name` until [`DaemonRecording::finish`].
pub struct DaemonRecording {
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<Result<String>>,
}

impl std::fmt::Debug for DaemonRecording {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "DaemonRecording")
    }
}

impl DaemonRecording {
    /// Starts recording pipeline `name` (which may not have started yet) to `path`.
    pub fn start(name: &str, path: &Path, opts: RecordOptions) -> Result<Self> {
        let mut recorder = Recorder::to_mcap(path, opts)?;
        let stop = Arc::new(AtomicBool::new(false));
        let stop_thread = stop.clone();
        let (name, path) = (name.to_string(), path.to_path_buf());
        let thread = std::thread::spawn(move || -> Result<String> {
            let wait = std::time::Duration::from_secs(300);
            let mut viewer = Viewer::attach(&name, wait)?;
            let end = follow(&mut viewer, &mut recorder, &stop_thread, &name)?;
            let s = recorder.finish()?;
            Ok(format!(
                "recorded {} frames ({} posed, {} images) to {} ({end})",
                s.frames,
                s.poses,
                s.images,
                path.display()
            ))
        });
        Ok(Self { stop, thread })
    }

    /// Once the daemon has stopped: takes what is left and closes the file.
    pub fn finish(self) -> Result<()> {
        self.stop.store(true, Ordering::SeqCst);
        let line = self
            .thread
            .join()
            .map_err(|_| anyhow::anyhow!("the recording thread panicked"))??;
        outln!("{line}");
        Ok(())
    }
}

/// Feeds the viewer's frames to the recorder until the pipeline's end of stream, `stop`
/// (after a last poll), or the pipeline's nodes being gone; says which.
fn follow(
    viewer: &mut Viewer,
    rec: &mut Recorder,
    stop: &AtomicBool,
    name: &str,
) -> Result<&'static str> {
    // records what a poll found; true at the end of the stream
    let take = |rec: &mut Recorder, events: Vec<ViewEvent>| {
        for e in events {
            match e {
                ViewEvent::End => return true,
                ViewEvent::Frame(f) => record_viewed(rec, &f),
            }
        }
        false
    };
    let mut last_check = std::time::Instant::now();
    loop {
        let stopping = stop.load(Ordering::SeqCst);
        let events = viewer.poll()?;
        let idle = events.is_empty();
        if take(rec, events) {
            return Ok("end of stream");
        }
        if stopping {
            return Ok("stopped");
        }
        if idle {
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        if last_check.elapsed() > std::time::Duration::from_secs(2) {
            last_check = std::time::Instant::now();
            if supermvo_pipeline::supervisor::live_nodes(name)?.is_empty() {
                // one last look: the end may have come with the nodes' exit
                if take(rec, viewer.poll()?) {
                    return Ok("end of stream");
                }
                tracing::warn!("pipeline '{name}' stopped without reaching its end");
                return Ok("the pipeline stopped before its end");
            }
        }
    }
}

/// One viewed frame into the recorder: frame, timing, and the loop it closed.
fn record_viewed(rec: &mut Recorder, f: &supermvo_pipeline::viewer::ViewedFrame) {
    let (h, p) = (&f.header.frame, &f.header.pose);
    let state = match p.state {
        0 => "initializing",
        1 => "tracking",
        2 => "lost",
        _ => "no frame",
    };
    let pose = (p.has_pose == 1).then(|| Pose::from_row_major_3x4(&p.t_world_cam));
    rec.frame(&FrameRecord {
        seq: h.seq,
        frame: h.frame,
        stamp: h.stamp,
        state,
        t_world_cam: pose,
        keyframe: p.keyframe == 1,
        counts: [
            p.keypoints as u64,
            p.matches as u64,
            p.inliers as u64,
            p.landmarks,
        ],
        view: Some(&f.view),
        image: f.image.as_ref().map(|(w, hh, px)| ImageRef {
            width: *w,
            height: *hh,
            pixels: px,
        }),
    });
    for b in p.backfilled_poses() {
        rec.late_pose(b.seq, &Pose::from_row_major_3x4(&b.t_world_cam));
    }
    let (stage_ms, capture_to_pose_ms) = f.stage_ms();
    rec.timing(&Timing {
        frame: h.frame,
        stamp: h.stamp,
        stage_ms,
        capture_to_pose_ms,
        dropped: f.dropped,
        lost: f.lost,
    });
    let (q, m) = (f.header.loop_query, f.header.loop_match);
    if q >= 0 && m >= 0 {
        rec.loop_closure(h.stamp, (q as u64, m as u64));
    }
}
