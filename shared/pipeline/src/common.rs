//! What every stage process shares: its command line, its node, and progress reports.

use anyhow::{Context, Result};
use std::path::{Path, PathBuf};
use std::time::Duration;
use supermvo_config::{Config, PipelineConfig};
use supermvo_messages::iceoryx2::port::publisher::Publisher;
use supermvo_messages::iceoryx2::port::subscriber::Subscriber;
use supermvo_messages::iceoryx2::prelude::ZeroCopySend;
use supermvo_messages::{
    create_node, now_ns, FrameHeader, Ipc, IpcNode, MessageError, Progress, ProgressEvent,
    Services, StageKind, Status, Topic,
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

/// Environment variable through which the supervisor gives its pid to the stages it starts.
pub const SUPERVISOR_PID_ENV: &str = "SUPERMVO_SUPERVISOR_PID";

/// A stage's connection to the pipeline: its node, the service names and its progress
/// publisher.
pub struct StageContext {
    /// The supervisor that started this process (from [`SUPERVISOR_PID_ENV`]), if any.
    supervisor: Option<u32>,
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
        let supervisor = std::env::var(SUPERVISOR_PID_ENV)
            .ok()
            .and_then(|v| v.parse().ok());
        Ok(Self {
            supervisor,
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
            cpu_ns: process_cpu_ns(),
            ..Default::default()
        }
    }

    /// A subscriber to a slice topic that first receives the topic's history (a restarted
    /// stage picks up what was in flight).
    pub fn slice_subscriber<P>(&self, topic: Topic) -> Result<Subscriber<Ipc, [P], FrameHeader>>
    where
        P: std::fmt::Debug + ZeroCopySend + 'static,
    {
        Ok(self
            .services
            .slice_topic::<P>(&self.node, topic, false)?
            .subscriber_builder()
            .history_request(Services::history(topic))
            .create()
            .map_err(|e| MessageError::ipc(format!("{} subscriber", topic.name()), e))?)
    }

    /// A subscriber to a fixed-size topic with headers, receiving its history first.
    pub fn header_subscriber<P>(&self, topic: Topic) -> Result<Subscriber<Ipc, P, FrameHeader>>
    where
        P: std::fmt::Debug + ZeroCopySend + 'static,
    {
        Ok(self
            .services
            .header_topic::<P>(&self.node, topic, false)?
            .subscriber_builder()
            .history_request(Services::history(topic))
            .create()
            .map_err(|e| MessageError::ipc(format!("{} subscriber", topic.name()), e))?)
    }

    /// A subscriber to a header-less topic (its history is the last state).
    pub fn plain_subscriber<P>(&self, topic: Topic) -> Result<Subscriber<Ipc, P, ()>>
    where
        P: std::fmt::Debug + ZeroCopySend + 'static,
    {
        Ok(self
            .services
            .plain_topic::<P>(&self.node, topic, false)?
            .subscriber_builder()
            .create()
            .map_err(|e| MessageError::ipc(format!("{} subscriber", topic.name()), e))?)
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

    /// Sleeps one poll period; false once SIGINT or SIGTERM asked the process to stop, or
    /// once the supervisor that started it is gone (it was killed or crashed: nobody would
    /// restart, stop or account for this stage any more, so it exits instead of lingering).
    pub fn wait(&self) -> bool {
        if self.node.wait(POLL).is_err() {
            return false;
        }
        match self.supervisor {
            Some(pid) if std::os::unix::process::parent_id() != pid => {
                tracing::error!(
                    "supervisor (pid {pid}) is gone; {} worker {} stops",
                    self.stage.name(),
                    self.worker
                );
                false
            }
            _ => true,
        }
    }
}

/// Stamps the time this stage sends a header on.
pub fn stamp(h: &mut FrameHeader, stage: StageKind) {
    h.t_ns[stage as usize] = now_ns();
}

/// Sends `data` (copied into a loaned sample; empty for a status-only message) with header
/// `h` on a slice topic.
pub fn send_slice<P>(p: &Publisher<Ipc, [P], FrameHeader>, h: FrameHeader, data: &[P]) -> Result<()>
where
    P: std::fmt::Debug + ZeroCopySend + Copy + 'static,
{
    let s = p
        .loan_slice_uninit(data.len())
        .map_err(|e| MessageError::ipc("loaning a sample", e))?;
    let mut s = s.write_from_slice(data);
    *s.user_header_mut() = h;
    s.send()
        .map_err(|e| MessageError::ipc("sending a sample", e))?;
    Ok(())
}

/// Sends the fixed-size `value` with header `h`; `what` names it in errors.
pub fn send_value<P>(
    p: &Publisher<Ipc, P, FrameHeader>,
    h: FrameHeader,
    value: P,
    what: &str,
) -> Result<()>
where
    P: std::fmt::Debug + ZeroCopySend + 'static,
{
    let s = p
        .loan_uninit()
        .map_err(|e| MessageError::ipc(format!("loaning {what}"), e))?;
    let mut s = s.write_payload(value);
    *s.user_header_mut() = h;
    s.send()
        .map_err(|e| MessageError::ipc(format!("sending {what}"), e))?;
    Ok(())
}

/// Sends features `f` ([`supermvo_messages::FeatureLayout`]) with header `h`, whose `count`
/// and `dim` it sets; returns the header sent.
pub fn send_features(
    p: &Publisher<Ipc, [f32], FrameHeader>,
    mut h: FrameHeader,
    f: &supermvo_inference::Features,
) -> Result<FrameHeader> {
    let layout = supermvo_messages::FeatureLayout {
        n: f.len(),
        dim: f.dim,
    };
    let mut s = p
        .loan_slice(layout.len())
        .map_err(|e| MessageError::ipc("loaning a features sample", e))?;
    supermvo_messages::FeatureLayout::write(f, s.payload_mut());
    (h.count, h.dim) = (f.len() as u32, f.dim as u32);
    *s.user_header_mut() = h;
    s.send()
        .map_err(|e| MessageError::ipc("sending features", e))?;
    Ok(h)
}

/// CPU time (user + system, every thread) this process has used, ns, from its own
/// accounting (`getrusage`); 0 where that is unavailable.
pub fn process_cpu_ns() -> u64 {
    use nix::sys::resource::{getrusage, UsageWho};
    let Ok(u) = getrusage(UsageWho::RUSAGE_SELF) else {
        return 0;
    };
    let ns =
        |t: nix::sys::time::TimeVal| t.tv_sec() as u64 * 1_000_000_000 + t.tv_usec() as u64 * 1_000;
    ns(u.user_time()) + ns(u.system_time())
}

/// Peak resident memory of this process so far, KiB (`getrusage`); 0 where unavailable.
pub fn peak_rss_kb() -> u64 {
    use nix::sys::resource::{getrusage, UsageWho};
    getrusage(UsageWho::RUSAGE_SELF).map_or(0, |u| u.max_rss().max(0) as u64)
}

/// Whether log lines on stderr get ANSI colours: only on a terminal (a stage's stderr is
/// its log file; a redirected run's is a file too), and never with `NO_COLOR` set
/// (no-color.org).
pub fn colour_on_stderr() -> bool {
    use std::io::IsTerminal;
    std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none_or(|v| v.is_empty())
}

/// An error and its causes on one line, each cause once: a cause whose text the line
/// already holds (an OS error that its context quoted) is not repeated.
pub fn error_line(e: &anyhow::Error) -> String {
    let mut line = e.to_string();
    for cause in e.chain().skip(1) {
        let text = cause.to_string();
        if !line.contains(&text) {
            line.push_str(": ");
            line.push_str(&text);
        }
    }
    line
}

/// Logging to stderr for a stage process (`RUST_LOG` overrides the level).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(colour_on_stderr())
        .with_writer(std::io::stderr)
        .try_init();
}

/// Entry point shared by the stage binaries: logging, then `run`, then a one-line error.
pub fn main_with<F: FnOnce() -> Result<()>>(stage: &str, run: F) -> std::process::ExitCode {
    init_logging();
    match run().with_context(|| format!("supermvo-{stage}")) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_line(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The `main` of a stage binary: parse the stage arguments, run `$stage::run`, report an
/// error in one line. Each stage binary is this one line.
#[macro_export]
macro_rules! stage_main {
    ($stage:ident) => {
        #[doc = concat!("SuPerMVO ", stringify!($stage), " stage process.")]
        #[derive(Debug, clap::Parser)]
        #[command(
            version,
            about = concat!("SuPerMVO ", stringify!($stage), " stage process; started by the supervisor.")
        )]
        struct Cli {
            #[command(flatten)]
            args: $crate::common::StageArgs,
        }

        fn main() -> std::process::ExitCode {
            let cli = <Cli as clap::Parser>::parse();
            $crate::common::main_with(stringify!($stage), || $crate::$stage::run(&cli.args))
        }
    };
}

/// Moves every features message waiting on `sub` into `inbox` (payload copied out of shared
/// memory: the stage keeps them beyond the sample's life).
pub fn receive_features(
    sub: &Subscriber<Ipc, [f32], FrameHeader>,
    inbox: &mut crate::inbox::Inbox<Option<supermvo_inference::Features>>,
) -> Result<()> {
    while let Some(s) = sub
        .receive()
        .map_err(|e| MessageError::ipc("features", e))?
    {
        let h = *s.user_header();
        h.check()?;
        let f = match h.status() {
            Status::Ok => Some(supermvo_messages::FeatureLayout::read(&h, s.payload())?),
            _ => None,
        };
        inbox.insert(h, f, now_ns());
    }
    Ok(())
}

/// The inference crate's device for the configuration's.
pub fn device(d: supermvo_config::Device) -> supermvo_inference::runtime::Device {
    match d {
        supermvo_config::Device::Cpu => supermvo_inference::runtime::Device::Cpu,
        supermvo_config::Device::Cuda => supermvo_inference::runtime::Device::Cuda,
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
    use super::*;

    #[test]
    fn a_cause_that_the_message_quotes_is_printed_once() {
        let os = std::io::Error::new(std::io::ErrorKind::NotFound, "No such file or directory");
        let quoted = anyhow::Error::new(os).context("gt.txt: No such file or directory");
        let line = error_line(&quoted.context("reading ground truth"));
        assert_eq!(
            line,
            "reading ground truth: gt.txt: No such file or directory"
        );
        // causes the message does not hold are all kept, in order
        let e = anyhow::anyhow!("disk full").context("writing out/report.json");
        assert_eq!(error_line(&e), "writing out/report.json: disk full");
    }
}
