//! A read-only viewer attached to a running pipeline: it joins the tracking stage's frame
//! views (`view`) with ingest's images (`view_images`) by sequence number, and counts the
//! frames dropped and lost from `progress`. It subscribes only to lossy services, so it can
//! never slow a stage down; what it misses while it falls behind is gone (its records then
//! skip frames), which is what a live view wants. `supermvo record` and `supermvo view` feed
//! its frames to a Foxglove recorder.

use anyhow::{bail, Result};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};
use supermvo_features::FrameView;
use supermvo_messages::iceoryx2::port::subscriber::Subscriber;
use supermvo_messages::{
    create_node, BackendState, FrameHeader, Ipc, IpcNode, MessageError, Progress, ProgressEvent,
    Services, StageKind, Status, Topic, ViewHeader, ViewLayout,
};

/// One frame as a viewer received it.
#[derive(Debug, Clone)]
pub struct ViewedFrame {
    /// The frame and the tracker's result.
    pub header: ViewHeader,
    /// Keypoints, match flow and (keyframes) map points.
    pub view: FrameView,
    /// The grey image `(width, height, pixels)`, when it arrived.
    pub image: Option<(u32, u32, Vec<u8>)>,
    /// Frames dropped at ingest (real-time mode) so far.
    pub dropped: u64,
    /// Frames lost in the pipeline so far.
    pub lost: u64,
}

impl ViewedFrame {
    /// Milliseconds from each stage's predecessor sending the frame on to the stage sending it
    /// (queueing included), by stage name, and capture (ingest) to pose (tracking).
    pub fn stage_ms(&self) -> (Vec<(String, f64)>, Option<f64>) {
        let t = self.header.frame.t_ns;
        let ms = |a: u64, b: u64| (a > 0 && b >= a).then(|| (b - a) as f64 * 1e-6);
        let mut stages = Vec::new();
        let mut prev = t[StageKind::Ingest as usize];
        for stage in [
            StageKind::Features,
            StageKind::Matching,
            StageKind::Tracking,
        ] {
            let at = t[stage as usize];
            if let Some(v) = ms(prev, at) {
                stages.push((stage.name().to_string(), v));
                prev = at;
            }
        }
        let total = ms(
            t[StageKind::Ingest as usize],
            t[StageKind::Tracking as usize],
        );
        (stages, total)
    }
}

/// What a poll found.
#[derive(Debug, Clone)]
pub enum ViewEvent {
    /// A frame the tracker handled.
    Frame(Box<ViewedFrame>),
    /// The pipeline reached the end of its stream.
    End,
}

/// A viewer of pipeline `name` (see the module docs).
pub struct Viewer {
    _node: IpcNode,
    views: Subscriber<Ipc, [f32], ViewHeader>,
    images: Subscriber<Ipc, [u8], FrameHeader>,
    progress: Subscriber<Ipc, Progress, ()>,
    backend: Subscriber<Ipc, BackendState, ()>,
    pending_images: BTreeMap<u64, (u32, u32, Vec<u8>)>,
    dropped: u64,
    lost: u64,
    ended: bool,
}

impl std::fmt::Debug for Viewer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Viewer(dropped {}, lost {})", self.dropped, self.lost)
    }
}

/// Images kept while their frame's view has not arrived.
const PENDING_IMAGES: usize = 32;

impl Viewer {
    /// Attaches to pipeline `name`, waiting up to `wait` for it to start.
    pub fn attach(name: &str, wait: Duration) -> Result<Self> {
        let services = Services::new(name);
        // outside the pipeline's node names: a viewer waiting for a pipeline to start must
        // not look like that pipeline running (the supervisor refuses a second one)
        let node_name = format!("supermvo-viewer/{name}/{}", std::process::id());
        let node_name = node_name
            .as_str()
            .try_into()
            .map_err(|e| MessageError::ipc(format!("node name '{node_name}'"), e))?;
        let node = create_node(&node_name)?;
        let deadline = Instant::now() + wait;
        let view_service = loop {
            match services.view_topic(&node, false) {
                Ok(s) => break s,
                Err(e) if Instant::now() >= deadline => return Err(e.into()),
                Err(_) => std::thread::sleep(Duration::from_millis(50)),
            }
        };
        let sub = |what: &str, e: &dyn std::fmt::Debug| {
            MessageError::ipc(format!("{what} subscriber"), e)
        };
        let views = view_service
            .subscriber_builder()
            .create()
            .map_err(|e| sub("view", &e))?;
        let images = services
            .slice_topic::<u8>(&node, Topic::ViewImages, false)?
            .subscriber_builder()
            .create()
            .map_err(|e| sub("view_images", &e))?;
        let progress = services
            .plain_topic::<Progress>(&node, Topic::Progress, false)?
            .subscriber_builder()
            .create()
            .map_err(|e| sub("progress", &e))?;
        let backend = services
            .plain_topic::<BackendState>(&node, Topic::Backend, false)?
            .subscriber_builder()
            .create()
            .map_err(|e| sub("backend", &e))?;
        Ok(Self {
            _node: node,
            views,
            images,
            progress,
            backend,
            pending_images: BTreeMap::new(),
            dropped: 0,
            lost: 0,
            ended: false,
        })
    }

    /// Everything that arrived since the last poll, in order.
    pub fn poll(&mut self) -> Result<Vec<ViewEvent>> {
        // first: once the back end has finished, every view was published before this
        let finished = self.backend_finished()?;
        self.count_drops()?;
        self.receive_images()?;
        let mut events = Vec::new();
        while let Some(s) = self
            .views
            .receive()
            .map_err(|e| MessageError::ipc("view", e))?
        {
            let h = *s.user_header();
            h.frame.check()?;
            match h.frame.status() {
                Status::EndOfStream => {
                    self.ended = true;
                    events.push(ViewEvent::End);
                }
                Status::Ok => {
                    let Some(view) = ViewLayout::read(&h, s.payload()) else {
                        bail!(
                            "view of seq {}: payload disagrees with its header",
                            h.frame.seq
                        );
                    };
                    let seq = h.frame.seq;
                    let image = self.pending_images.remove(&seq);
                    self.pending_images = self.pending_images.split_off(&seq);
                    events.push(ViewEvent::Frame(Box::new(ViewedFrame {
                        header: h,
                        view,
                        image,
                        dropped: self.dropped,
                        lost: self.lost,
                    })));
                }
                _ => {}
            }
        }
        if !self.ended && finished {
            // the end of the stream's view was overwritten before it was read
            self.ended = true;
            events.push(ViewEvent::End);
        }
        Ok(events)
    }

    fn receive_images(&mut self) -> Result<()> {
        while let Some(s) = self
            .images
            .receive()
            .map_err(|e| MessageError::ipc("view_images", e))?
        {
            let h = *s.user_header();
            h.check()?;
            let image = (h.width, h.height, s.payload().to_vec());
            self.pending_images.insert(h.seq, image);
            while self.pending_images.len() > PENDING_IMAGES {
                self.pending_images.pop_first();
            }
        }
        Ok(())
    }

    fn count_drops(&mut self) -> Result<()> {
        while let Some(s) = self
            .progress
            .receive()
            .map_err(|e| MessageError::ipc("progress", e))?
        {
            let p = *s.payload();
            if p.event != ProgressEvent::Frame as u32 {
                continue;
            }
            match Status::from_u32(p.status) {
                Status::Dropped if p.stage == StageKind::Ingest as u32 => self.dropped += 1,
                Status::Lost if p.stage == StageKind::Tracking as u32 => self.lost += 1,
                _ => {}
            }
        }
        Ok(())
    }

    fn backend_finished(&mut self) -> Result<bool> {
        let mut finished = false;
        while let Some(s) = self
            .backend
            .receive()
            .map_err(|e| MessageError::ipc("backend", e))?
        {
            finished |= s.payload().finished == 1;
        }
        Ok(finished)
    }
}
