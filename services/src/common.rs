//! What every stage process shares: its command line, its node, and progress reports.

use anyhow::{Context, Result};
use std::path::{Path, PathBuf};
use std::time::Duration;
use supermvo_config::{Config, PipelineConfig};
use supermvo_messages::iceoryx2::port::publisher::Publisher;
use supermvo_messages::{
    create_node, now_ns, FrameHeader, Ipc, IpcNode, Progress, ProgressEvent, Services, StageKind,
    Status, Topic,
};

/// How long a stage sleeps between polls of its inputs.
pub const POLL: Duration = Duration::from_micros(500);

/// How often an idle stage says it is alive.
pub const HEARTBEAT: Duration = Duration::from_millis(500);

/// Command line of every stage binary (the supervisor passes these).
#[derive(Debug, Clone, clap::Args)]
pub struct StageArgs {
    /// Configuration file (TOML, see config/default.toml); defaults apply without one.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Sequence directory (KITTI layout).
    #[arg(long)]
    pub seq: PathBuf,
    /// Output directory (the back end writes the trajectory there).
    #[arg(long)]
    pub out: PathBuf,
    /// Worker index of this process within its stage.
    #[arg(long, default_value_t = 0)]
    pub worker: u32,
}

impl StageArgs {
    /// The configuration, validated.
    pub fn load_config(&self) -> Result<Config> {
        load_config(self.config.as_deref())
    }
}

/// Reads and validates a config file, or the defaults.
pub fn load_config(path: Option<&Path>) -> Result<Config> {
    match path {
        Some(p) => Ok(Config::load(p)?),
        None => Ok(Config::default()),
    }
}

/// A stage's connection to the pipeline: its node, the service names and its progress
/// publisher.
pub struct StageContext {
    /// The iceoryx2 node of this process.
    pub node: IpcNode,
    /// Service names of the pipeline.
    pub services: Services,
    /// This stage.
    pub stage: StageKind,
    /// Worker index.
    pub worker: u32,
    /// Pipeline settings.
    pub cfg: PipelineConfig,
    progress: Publisher<Ipc, Progress, ()>,
    last_report: std::time::Instant,
}

impl std::fmt::Debug for StageContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "StageContext({}/{})", self.stage.name(), self.worker)
    }
}

impl StageContext {
    /// Creates the node and the progress publisher. The supervisor has created the services;
    /// a stage started without one fails here with a clear message.
    pub fn new(stage: StageKind, worker: u32, cfg: &PipelineConfig) -> Result<Self> {
        let services = Services::new(&cfg.name);
        let node = create_node(&services.node_name(stage.name(), worker)?)?;
        let progress = services
            .plain_topic::<Progress>(&node, Topic::Progress, false)?
            .publisher_builder()
            .create()
            .map_err(|e| supermvo_messages::MessageError::ipc("progress publisher", e))?;
        Ok(Self {
            node,
            services,
            stage,
            worker,
            cfg: cfg.clone(),
            progress,
            last_report: std::time::Instant::now(),
        })
    }

    fn send(&mut self, p: Progress) {
        self.last_report = std::time::Instant::now();
        if let Err(e) = self.progress.send_copy(p) {
            tracing::debug!("progress not sent: {e:?}");
        }
    }

    fn base(&self, event: ProgressEvent) -> Progress {
        Progress {
            stage: self.stage as u32,
            worker: self.worker,
            pid: std::process::id(),
            event: event as u32,
            t_out_ns: now_ns(),
            ..Default::default()
        }
    }

    /// Says the stage is up.
    pub fn started(&mut self) {
        let p = self.base(ProgressEvent::Started);
        self.send(p);
    }

    /// Says the stage has passed the end of the stream on.
    pub fn finished(&mut self) {
        let p = self.base(ProgressEvent::Finished);
        self.send(p);
    }

    /// Sends a heartbeat when nothing was reported for a while.
    pub fn heartbeat_if_idle(&mut self) {
        if self.last_report.elapsed() >= HEARTBEAT {
            let p = self.base(ProgressEvent::Heartbeat);
            self.send(p);
        }
    }

    /// Reports what this stage did with a frame (`h` is the header it sent on).
    pub fn frame_done(&mut self, h: &FrameHeader, t_in_ns: u64, queue: usize) {
        let mut p = self.base(ProgressEvent::Frame);
        p.seq = h.seq;
        p.frame = h.frame;
        p.status = h.status;
        p.queue = queue as u32;
        p.t_in_ns = t_in_ns;
        p.t_capture_ns = h.t_ns[0];
        self.send(p);
    }

    /// Sleeps one poll period; false once SIGINT or SIGTERM asked the process to stop.
    pub fn wait(&self) -> bool {
        self.node.wait(POLL).is_ok()
    }
}

/// Stamps the time this stage sends a header on.
pub fn stamp(h: &mut FrameHeader, stage: StageKind) {
    h.t_ns[stage as usize] = now_ns();
}

/// Whether a status carries a payload.
pub fn has_payload(h: &FrameHeader) -> bool {
    h.status() == Status::Ok
}

/// Logging to stderr for a stage process (`RUST_LOG` overrides the level).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}

/// Entry point shared by the stage binaries: logging, then `run`, then a one-line error.
pub fn main_with<F: FnOnce() -> Result<()>>(stage: &str, run: F) -> std::process::ExitCode {
    init_logging();
    match run().with_context(|| format!("supermvo-{stage}")) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
