//! The supervisor: creates the pipeline's services, starts every stage process, watches them
//! (exit, silence past the deadline), removes a dead stage's stale shared-memory resources and
//! restarts it with back-off up to a limit, measures per-stage and end-to-end latency from the
//! stages' progress reports, and shuts everything down cleanly at the end of the stream or on
//! SIGINT/SIGTERM. It writes `metrics.json` and `processes.json` to the output directory.

use crate::backend::read_records;
use anyhow::{bail, Context, Result};
use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use supermvo_config::Config;
use supermvo_messages::iceoryx2::node::NodeView;
use supermvo_messages::iceoryx2::prelude::*;
use supermvo_messages::{
    create_node, BackendState, CorrectionMsg, FrameHeader, Ipc, MatchEntry, MatchRequest,
    MessageError, PoseMsg, Progress, ProgressEvent, Services, StageKind, Status, Topic,
};

/// What the supervisor runs.
#[derive(Debug, Clone)]
pub struct SupervisorOptions {
    /// Effective configuration (written to `out/config.toml` for the stages).
    pub config: Config,
    /// Sequence directory.
    pub seq: PathBuf,
    /// Output directory.
    pub out: PathBuf,
    /// Where the stage binaries (`supermvo-ingest`, ...) are.
    pub bin_dir: PathBuf,
    /// No live summary.
    pub quiet: bool,
}

/// The directory of the stage binaries: `SUPERMVO_BIN_DIR`, else beside the running program.
pub fn default_bin_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("SUPERMVO_BIN_DIR") {
        return PathBuf::from(d);
    }
    std::env::current_exe()
        .ok()
        .and_then(|p| p.parent().map(Path::to_path_buf))
        .unwrap_or_else(|| PathBuf::from("."))
}

/// Binary name of a stage.
pub fn binary_name(stage: StageKind) -> String {
    format!("supermvo-{}", stage.name())
}

/// Latency percentiles in milliseconds.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct Percentiles {
    /// Samples.
    pub count: usize,
    /// Median.
    pub p50: f64,
    /// 95th percentile.
    pub p95: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Maximum.
    pub max: f64,
    /// Mean.
    pub mean: f64,
}

impl Percentiles {
    /// Percentiles of `v` (nearest rank).
    pub fn of(v: &[f64]) -> Self {
        if v.is_empty() {
            return Self::default();
        }
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        let q = |p: f64| s[((p * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1];
        Self {
            count: s.len(),
            p50: q(0.50),
            p95: q(0.95),
            p99: q(0.99),
            max: s[s.len() - 1],
            mean: s.iter().sum::<f64>() / s.len() as f64,
        }
    }
}

/// One restart of a stage.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RestartRecord {
    /// Stage name.
    pub stage: String,
    /// Worker.
    pub worker: u32,
    /// Why: exit status or "deadline".
    pub reason: String,
    /// From noticing the death to the new process running, ms.
    pub respawn_ms: f64,
    /// From noticing the death to the new process reporting itself up, ms (models loaded,
    /// subscribed); `None` if it never did.
    pub ready_ms: Option<f64>,
}

/// What a supervised run produced.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RunMetrics {
    /// Pipeline name.
    pub pipeline: String,
    /// "lossless" or "realtime".
    pub mode: String,
    /// Wall time of the run, s.
    pub duration_s: f64,
    /// Frames the back end recorded, by status.
    pub frames: BTreeMap<String, usize>,
    /// Frames recorded with a pose.
    pub estimated: usize,
    /// Throughput: recorded frames per second of wall time (start-up included).
    pub fps: f64,
    /// Time between successive tracking results, ms: the steady-state time per frame, the
    /// peer of an in-process run's time per frame (start-up and warm-up excluded).
    pub frame_interval_ms: Percentiles,
    /// Processing time per frame of each stage (receive to send), ms.
    pub stage_latency_ms: BTreeMap<String, Percentiles>,
    /// CPU time per frame of each stage, core-ms (from each process's own accounting,
    /// between its successive frames: waiting and polling included; 200 core-ms is what two
    /// cores give a frame at 10 Hz).
    pub stage_cpu_ms: BTreeMap<String, Percentiles>,
    /// Capture (ingest) to tracking result, ms, over processed frames.
    pub end_to_end_ms: Percentiles,
    /// Most frames waiting in a stage's input, per stage.
    pub max_queue: BTreeMap<String, u32>,
    /// Restarts.
    pub restarts: Vec<RestartRecord>,
    /// Peak resident memory (kB) of each stage process, sampled while it ran.
    pub peak_rss_kb: BTreeMap<String, u64>,
    /// Resident memory samples (kB) per process over time: `(seconds since start, kB)`.
    pub rss_samples: BTreeMap<String, Vec<(f64, u64)>>,
    /// Whether the run was interrupted (SIGINT/SIGTERM) before the end of the stream.
    pub interrupted: bool,
}

struct Worker {
    stage: StageKind,
    index: u32,
    child: Option<Child>,
    restarts: u32,
    restart_at: Option<Instant>,
    died_at: Option<Instant>,
    last_seen: Instant,
    pending: Option<usize>,
    reason: Option<String>,
}

impl Worker {
    fn key(&self) -> String {
        format!("{}/{}", self.stage.name(), self.index)
    }
}

type Factories = (
    supermvo_messages::iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        Ipc,
        [u8],
        FrameHeader,
    >,
    supermvo_messages::iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        Ipc,
        [f32],
        FrameHeader,
    >,
    supermvo_messages::iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        Ipc,
        [MatchEntry],
        FrameHeader,
    >,
    supermvo_messages::iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        Ipc,
        PoseMsg,
        FrameHeader,
    >,
    supermvo_messages::iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        Ipc,
        MatchRequest,
        FrameHeader,
    >,
    supermvo_messages::iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        Ipc,
        BackendState,
        (),
    >,
);

/// Names of the live nodes of pipeline `name` (other than the caller's own).
pub fn live_nodes(name: &str) -> Result<Vec<String>> {
    let prefix = format!("supermvo/{name}/");
    let mut found = Vec::new();
    Node::<Ipc>::list(
        supermvo_messages::iceoryx2::config::Config::global_config(),
        |state| {
            if let NodeState::Alive(view) = &state {
                if let Some(d) = view.details() {
                    let n = d.name().to_string();
                    if n.starts_with(&prefix) {
                        found.push(n);
                    }
                }
            }
            CallbackProgression::Continue
        },
    )
    .map_err(|e| MessageError::ipc("listing iceoryx2 nodes", e))?;
    Ok(found)
}

fn rss_kb(pid: u32) -> Option<u64> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    s.lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
}

/// Runs the pipeline under supervision until the end of the stream (or a signal).
pub fn run(opts: &SupervisorOptions) -> Result<RunMetrics> {
    let cfg = &opts.config.pipeline;
    opts.config.validate()?;
    // everything that can be checked is checked before anything starts
    let mut missing = Vec::new();
    for stage in StageKind::ALL {
        let p = opts.bin_dir.join(binary_name(stage));
        if !p.is_file() {
            missing.push(p.display().to_string());
        }
    }
    if !missing.is_empty() {
        bail!(
            "stage binaries missing: {}; build them with `cargo build --release --workspace` or point SUPERMVO_BIN_DIR at them",
            missing.join(", ")
        );
    }
    supermvo_dataset::Sequence::open_with_camera(&opts.seq, cfg.camera.as_deref())?;
    std::fs::create_dir_all(opts.out.join("logs"))
        .with_context(|| format!("creating {}", opts.out.display()))?;
    let services = Services::new(&cfg.name);
    let node = create_node(&services.node_name("supervisor", 0)?)?;
    node.try_cleanup_dead_nodes();
    // our own node is one of the live ones; any other means the name is taken
    let live = live_nodes(&cfg.name)?;
    if live.len() > 1 {
        bail!(
            "pipeline '{}' is already running ({} live processes); stop it first, or give this one another name (pipeline.name / --name)",
            cfg.name,
            live.len() - 1
        );
    }
    // a fresh run starts with a fresh record
    let _ = std::fs::remove_file(opts.out.join("frames.csv"));
    for f in [
        "trajectory.tum.txt",
        "trajectory.kitti.txt",
        crate::loop_closing::KEYFRAMES_FILE,
        "loops.json",
        crate::tracking::LENS_FILE,
        crate::remote_mapping::BA_LOG_FILE,
        crate::remote_mapping::TRIANGULATION_LOG_FILE,
    ] {
        let _ = std::fs::remove_file(opts.out.join(f));
    }
    let config_path = opts.out.join("config.toml");
    std::fs::write(&config_path, toml::to_string(&opts.config)?)
        .with_context(|| format!("writing {}", config_path.display()))?;

    // the supervisor owns the services for the whole run; stages come and go
    let _factories: Factories = (
        services.slice_topic::<u8>(&node, Topic::Frames, true)?,
        services.slice_topic::<f32>(&node, Topic::Features, true)?,
        services.slice_topic::<MatchEntry>(&node, Topic::Matches, true)?,
        services.header_topic::<PoseMsg>(&node, Topic::Poses, true)?,
        services.header_topic::<MatchRequest>(&node, Topic::MatchRequests, true)?,
        services.plain_topic::<BackendState>(&node, Topic::Backend, true)?,
    );
    // tracking and the back end's loop closing and local mapping
    let _mapping = (
        services.slice_topic::<f32>(&node, Topic::Keyframes, true)?,
        services.header_topic::<CorrectionMsg>(&node, Topic::Corrections, true)?,
        services.slice_topic::<f64>(&node, Topic::MappingRequests, true)?,
        services.slice_topic::<f64>(&node, Topic::MappingReplies, true)?,
    );
    // the diagnostic views (lossy; stages publish on them only while someone listens)
    let _views = (
        services.view_topic(&node, true)?,
        services.slice_topic::<u8>(&node, Topic::ViewImages, true)?,
    );
    let progress_service = services.plain_topic::<Progress>(&node, Topic::Progress, true)?;
    let progress = progress_service
        .subscriber_builder()
        .create()
        .map_err(|e| MessageError::ipc("progress subscriber", e))?;

    let mut workers: Vec<Worker> = Vec::new();
    // downstream first, so every subscriber exists before data flows; ingest only once every
    // other stage is up (networks loaded and warmed up), so that in real time no frame is
    // dropped or late while they start
    for stage in StageKind::ALL.iter().rev() {
        let n = if *stage == StageKind::Features {
            cfg.features_workers as u32
        } else {
            1
        };
        for index in 0..n {
            workers.push(Worker {
                stage: *stage,
                index,
                child: None,
                restarts: 0,
                restart_at: (*stage != StageKind::Ingest).then(Instant::now),
                died_at: None,
                last_seen: Instant::now(),
                pending: None,
                reason: None,
            });
        }
    }
    let spawn = |w: &Worker| -> Result<Child> {
        let log = std::fs::OpenOptions::new().create(true).append(true).open(
            opts.out
                .join("logs")
                .join(format!("{}-{}.log", w.stage.name(), w.index)),
        )?;
        Command::new(opts.bin_dir.join(binary_name(w.stage)))
            .arg("--config")
            .arg(&config_path)
            .arg("--seq")
            .arg(&opts.seq)
            .arg("--out")
            .arg(&opts.out)
            .arg("--worker")
            .arg(w.index.to_string())
            .env(
                crate::common::SUPERVISOR_PID_ENV,
                std::process::id().to_string(),
            )
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .with_context(|| format!("starting {}", binary_name(w.stage)))
    };

    let t_start = Instant::now();
    let mut stage_lat: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    // per stage, CPU core-ms between successive frames of one process; by pid, its last reading
    let mut stage_cpu: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut last_cpu_ns: BTreeMap<u32, u64> = BTreeMap::new();
    let mut e2e = Vec::new();
    let (mut intervals, mut last_result_ns) = (Vec::new(), None::<u64>);
    let mut max_queue: BTreeMap<String, u32> = BTreeMap::new();
    let mut restarts: Vec<RestartRecord> = Vec::new();
    let mut peak_rss: BTreeMap<String, u64> = BTreeMap::new();
    let mut rss_samples: BTreeMap<String, Vec<(f64, u64)>> = BTreeMap::new();
    let mut last_rss = Instant::now();
    let mut last_print = Instant::now();
    let mut relay = crate::log_relay::LogRelay::default();
    for w in &workers {
        let log = format!("{}-{}.log", w.stage.name(), w.index);
        relay.follow(&opts.out.join("logs").join(log));
    }
    let mut last_relay = Instant::now();
    let mut tracked = 0usize;
    let mut finished = false;
    let mut interrupted = false;
    let mut failure: Option<String> = None;
    let deadline = Duration::from_millis(cfg.deadline_ms);
    let mut up: std::collections::BTreeSet<(u32, u32)> = Default::default();
    let mut ingest_waits = true;

    loop {
        if node.wait(Duration::from_millis(2)).is_err() {
            interrupted = true;
            break;
        }
        // start or restart what is due
        let mut spawned = false;
        for w in workers.iter_mut() {
            if w.child.is_none() && w.restart_at.is_some_and(|t| Instant::now() >= t) {
                w.restart_at = None;
                let child = spawn(w)?;
                if let Some(died) = w.died_at {
                    restarts.push(RestartRecord {
                        stage: w.stage.name().into(),
                        worker: w.index,
                        reason: w.reason.take().unwrap_or_default(),
                        respawn_ms: died.elapsed().as_secs_f64() * 1e3,
                        ready_ms: None,
                    });
                    w.pending = Some(restarts.len() - 1);
                }
                w.child = Some(child);
                w.last_seen = Instant::now();
                spawned = true;
            }
        }
        if spawned {
            write_processes(&opts.out, &workers)?;
        }
        // progress
        while let Some(s) = progress
            .receive()
            .map_err(|e| MessageError::ipc("progress", e))?
        {
            let p = *s.payload();
            let Some(stage) = StageKind::from_u32(p.stage) else {
                continue;
            };
            if let Some(w) = workers
                .iter_mut()
                .find(|w| w.stage == stage && w.index == p.worker)
            {
                w.last_seen = Instant::now();
                if p.event == ProgressEvent::Started as u32 {
                    up.insert((p.stage, p.worker));
                    if let (Some(i), Some(died)) = (w.pending.take(), w.died_at.take()) {
                        restarts[i].ready_ms = Some(died.elapsed().as_secs_f64() * 1e3);
                    }
                }
            }
            if p.event == ProgressEvent::Finished as u32 && stage == StageKind::Backend {
                finished = true;
            }
            if p.event == ProgressEvent::Frame as u32 {
                if let Some(prev) = last_cpu_ns.insert(p.pid, p.cpu_ns) {
                    stage_cpu
                        .entry(stage.name().into())
                        .or_default()
                        .push(p.cpu_ns.saturating_sub(prev) as f64 * 1e-6);
                }
                let q = max_queue.entry(stage.name().into()).or_default();
                *q = (*q).max(p.queue);
                if p.status == Status::Ok as u32 && p.t_out_ns >= p.t_in_ns {
                    stage_lat
                        .entry(stage.name().into())
                        .or_default()
                        .push((p.t_out_ns - p.t_in_ns) as f64 * 1e-6);
                    if stage == StageKind::Tracking && p.t_capture_ns > 0 {
                        e2e.push(p.t_out_ns.saturating_sub(p.t_capture_ns) as f64 * 1e-6);
                    }
                    if stage == StageKind::Tracking {
                        if let Some(prev) = last_result_ns.replace(p.t_out_ns) {
                            intervals.push(p.t_out_ns.saturating_sub(prev) as f64 * 1e-6);
                        }
                    }
                }
                if stage == StageKind::Backend {
                    tracked += 1;
                }
            }
        }
        if finished {
            break;
        }
        if ingest_waits
            && workers
                .iter()
                .filter(|w| w.stage != StageKind::Ingest)
                .all(|w| up.contains(&(w.stage as u32, w.index)))
        {
            ingest_waits = false;
            for w in workers.iter_mut().filter(|w| w.stage == StageKind::Ingest) {
                w.restart_at = Some(Instant::now());
            }
        }
        // deaths and hangs
        for w in workers.iter_mut() {
            let Some(child) = w.child.as_mut() else {
                continue;
            };
            let exited = child.try_wait()?;
            let hung = exited.is_none() && w.last_seen.elapsed() > deadline;
            if exited.is_none() && !hung {
                continue;
            }
            let reason = match exited {
                Some(st) => format!("exited: {st}"),
                None => {
                    let _ = child.kill();
                    let _ = child.wait();
                    format!("silent for more than {} ms", cfg.deadline_ms)
                }
            };
            tracing::warn!("{} {reason}; restarting", w.key());
            w.child = None;
            w.died_at = Some(Instant::now());
            // the dead process's ports and segments go before its successor connects
            node.try_cleanup_dead_nodes();
            if w.restarts >= cfg.max_restarts {
                failure = Some(format!(
                    "{} failed {} times (last: {reason}); see {}",
                    w.key(),
                    w.restarts + 1,
                    opts.out
                        .join("logs")
                        .join(format!("{}-{}.log", w.stage.name(), w.index))
                        .display()
                ));
                break;
            }
            let backoff = cfg
                .restart_backoff_ms
                .saturating_mul(1 << w.restarts.min(10));
            w.restarts += 1;
            w.restart_at = Some(Instant::now() + Duration::from_millis(backoff));
            w.reason = Some(reason);
        }
        if failure.is_some() {
            break;
        }
        if last_rss.elapsed() >= Duration::from_millis(500) {
            last_rss = Instant::now();
            let t = t_start.elapsed().as_secs_f64();
            for w in &workers {
                if let Some(kb) = w.child.as_ref().and_then(|c| rss_kb(c.id())) {
                    let k = w.key();
                    let e = peak_rss.entry(k.clone()).or_default();
                    *e = (*e).max(kb);
                    rss_samples.entry(k).or_default().push((t, kb));
                }
            }
        }
        if last_relay.elapsed() >= Duration::from_millis(200) {
            last_relay = Instant::now();
            for line in relay.new_lines() {
                eprintln!("{line}");
            }
        }
        if !opts.quiet && last_print.elapsed() >= Duration::from_secs(1) {
            last_print = Instant::now();
            let p = Percentiles::of(&e2e);
            eprintln!(
                "[supervisor] {tracked} frames recorded, {:.1} fps, capture->pose p50 {:.0} ms p99 {:.0} ms, {} restarts",
                tracked as f64 / t_start.elapsed().as_secs_f64(),
                p.p50,
                p.p99,
                workers.iter().map(|w| w.restarts).sum::<u32>()
            );
        }
    }

    // shut down: SIGTERM, a grace period, then SIGKILL
    for w in workers.iter() {
        if let Some(c) = &w.child {
            let _ = kill(Pid::from_raw(c.id() as i32), Signal::SIGTERM);
        }
    }
    let grace = Instant::now();
    for w in workers.iter_mut() {
        if let Some(mut c) = w.child.take() {
            loop {
                if c.try_wait()?.is_some() {
                    break;
                }
                if grace.elapsed() > Duration::from_secs(5) {
                    let _ = c.kill();
                    let _ = c.wait();
                    break;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
        }
    }
    node.try_cleanup_dead_nodes();
    for line in relay.new_lines() {
        eprintln!("{line}");
    }

    let records = read_records(&opts.out.join("frames.csv"))?;
    let mut frames: BTreeMap<String, usize> = BTreeMap::new();
    for r in records.iter().filter(|r| r.status != "end") {
        *frames.entry(r.status.clone()).or_default() += 1;
    }
    let duration_s = t_start.elapsed().as_secs_f64();
    let metrics = RunMetrics {
        pipeline: cfg.name.clone(),
        mode: format!("{:?}", cfg.mode).to_lowercase(),
        duration_s,
        estimated: records.iter().filter(|r| r.t_world_cam.is_some()).count(),
        fps: frames.values().sum::<usize>() as f64 / duration_s,
        frames,
        stage_latency_ms: stage_lat
            .iter()
            .map(|(k, v)| (k.clone(), Percentiles::of(v)))
            .collect(),
        stage_cpu_ms: stage_cpu
            .iter()
            .map(|(k, v)| (k.clone(), Percentiles::of(v)))
            .collect(),
        end_to_end_ms: Percentiles::of(&e2e),
        frame_interval_ms: Percentiles::of(&intervals),
        max_queue,
        restarts,
        peak_rss_kb: peak_rss,
        rss_samples,
        interrupted,
    };
    std::fs::write(
        opts.out.join("metrics.json"),
        serde_json::to_string_pretty(&metrics)?,
    )?;
    if let Some(f) = failure {
        bail!("{f}");
    }
    Ok(metrics)
}

/// Writes who runs where (`processes.json`), for operators and the fault tests.
fn write_processes(out: &Path, workers: &[Worker]) -> Result<()> {
    let v: Vec<serde_json::Value> = workers
        .iter()
        .filter_map(|w| {
            w.child.as_ref().map(|c| {
                serde_json::json!({"stage": w.stage.name(), "worker": w.index, "pid": c.id(), "restarts": w.restarts})
            })
        })
        .collect();
    let tmp = out.join("processes.json.tmp");
    std::fs::write(&tmp, serde_json::to_string_pretty(&v)?)?;
    std::fs::rename(&tmp, out.join("processes.json"))?;
    Ok(())
}
