//! Read-only views of running pipelines: `supermvo inspect` (nodes and services) and
//! `supermvo monitor` (rates, latencies, tracking state, current pose).
//!
//! A monitor subscribes only to the `progress` and `backend` services, which drop their
//! oldest samples when a reader falls behind, so attaching one can never slow the pipeline.

use anyhow::Result;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};
use supermvo_messages::iceoryx2::config::Config as IpcConfig;
use supermvo_messages::iceoryx2::node::NodeView;
use supermvo_messages::iceoryx2::prelude::*;
use supermvo_messages::{
    create_node, BackendState, Ipc, IpcNode, MessageError, Progress, ProgressEvent, Services,
    StageKind, Status, Topic,
};

/// A node of some SuPerMVO pipeline.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct NodeInfo {
    /// Node name (`supermvo/<pipeline>/<stage>/<worker>`).
    pub name: String,
    /// "alive", "dead" (crashed, resources not yet removed) or "unknown".
    pub state: String,
}

/// A service of some SuPerMVO pipeline.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct ServiceInfo {
    /// Service name (`supermvo/<pipeline>/<topic>`).
    pub name: String,
    /// Nodes attached.
    pub nodes: usize,
}

/// Every SuPerMVO node and service on this machine.
pub fn inspect() -> Result<(Vec<NodeInfo>, Vec<ServiceInfo>)> {
    supermvo_messages::quiet_ipc_logs();
    let mut nodes = Vec::new();
    Node::<Ipc>::list(IpcConfig::global_config(), |state| {
        let (name, st) = match &state {
            NodeState::Alive(v) => (v.details().as_ref().map(|d| d.name().to_string()), "alive"),
            NodeState::Dead(v) => (v.details().as_ref().map(|d| d.name().to_string()), "dead"),
            _ => (None, "unknown"),
        };
        if let Some(name) = name.filter(|n| n.starts_with("supermvo/")) {
            nodes.push(NodeInfo {
                name,
                state: st.into(),
            });
        }
        CallbackProgression::Continue
    })
    .map_err(|e| MessageError::ipc("listing iceoryx2 nodes", e))?;
    let mut services = Vec::new();
    Ipc::list(IpcConfig::global_config(), |s| {
        let name = s.static_details.name().to_string();
        if name.starts_with("supermvo/") {
            services.push(ServiceInfo {
                name,
                nodes: s.dynamic_details.as_ref().map_or(0, |d| d.nodes.len()),
            });
        }
        CallbackProgression::Continue
    })
    .map_err(|e| MessageError::ipc("listing iceoryx2 services", e))?;
    nodes.sort_by(|a, b| a.name.cmp(&b.name));
    services.sort_by(|a, b| a.name.cmp(&b.name));
    Ok((nodes, services))
}

/// One summary of what a monitor saw over an interval.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct Snapshot {
    /// Frames per second handled by each stage over the interval.
    pub rates: BTreeMap<String, f64>,
    /// Median processing time per stage over the interval, ms.
    pub median_ms: BTreeMap<String, f64>,
    /// Median capture-to-pose latency over the interval, ms.
    pub end_to_end_ms: Option<f64>,
    /// Frames not processed (dropped, unreadable, lost) over the interval.
    pub not_processed: usize,
    /// Last sequence number recorded by the back end.
    pub last_seq: Option<u64>,
    /// Tracking state of that frame.
    pub state: Option<String>,
    /// Its camera position in the world (first camera) frame.
    pub position: Option<[f64; 3]>,
    /// Whether the back end reported the end of the stream.
    pub finished: bool,
}

/// A read-only attachment to a running pipeline.
pub struct Monitor {
    _node: IpcNode,
    progress: supermvo_messages::iceoryx2::port::subscriber::Subscriber<Ipc, Progress, ()>,
    backend: supermvo_messages::iceoryx2::port::subscriber::Subscriber<Ipc, BackendState, ()>,
}

impl std::fmt::Debug for Monitor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Monitor")
    }
}

impl Monitor {
    /// Attaches to pipeline `name`; a clear error when it is not running.
    pub fn attach(name: &str) -> Result<Self> {
        let services = Services::new(name);
        let node = create_node(&services.node_name("monitor", std::process::id())?)?;
        let progress = services
            .plain_topic::<Progress>(&node, Topic::Progress, false)?
            .subscriber_builder()
            .create()
            .map_err(|e| MessageError::ipc("progress subscriber", e))?;
        let backend = services
            .plain_topic::<BackendState>(&node, Topic::Backend, false)?
            .subscriber_builder()
            .create()
            .map_err(|e| MessageError::ipc("backend subscriber", e))?;
        Ok(Self {
            _node: node,
            progress,
            backend,
        })
    }

    /// Watches for `interval` and summarises.
    pub fn sample(&self, interval: Duration) -> Result<Snapshot> {
        let t0 = Instant::now();
        let mut counts: BTreeMap<String, usize> = BTreeMap::new();
        let mut times: BTreeMap<String, Vec<f64>> = BTreeMap::new();
        let mut e2e = Vec::new();
        let mut snap = Snapshot::default();
        loop {
            while let Some(s) = self
                .progress
                .receive()
                .map_err(|e| MessageError::ipc("progress", e))?
            {
                let p = *s.payload();
                let Some(stage) = StageKind::from_u32(p.stage) else {
                    continue;
                };
                if p.event != ProgressEvent::Frame as u32 {
                    continue;
                }
                let k = stage.name().to_string();
                *counts.entry(k.clone()).or_default() += 1;
                if p.status == Status::Ok as u32 {
                    times
                        .entry(k)
                        .or_default()
                        .push(p.t_out_ns.saturating_sub(p.t_in_ns) as f64 * 1e-6);
                    if stage == StageKind::Tracking && p.t_capture_ns > 0 {
                        e2e.push(p.t_out_ns.saturating_sub(p.t_capture_ns) as f64 * 1e-6);
                    }
                } else if stage == StageKind::Tracking && p.status != Status::EndOfStream as u32 {
                    snap.not_processed += 1;
                }
            }
            while let Some(s) = self
                .backend
                .receive()
                .map_err(|e| MessageError::ipc("backend", e))?
            {
                let b = *s.payload();
                snap.last_seq = (b.recorded > 0).then_some(b.seq);
                snap.state = Some(
                    ["initializing", "tracking", "lost", "no frame"]
                        .get(b.state as usize)
                        .unwrap_or(&"unknown")
                        .to_string(),
                );
                snap.position = (b.has_pose == 1).then_some([
                    b.t_world_cam[3],
                    b.t_world_cam[7],
                    b.t_world_cam[11],
                ]);
                snap.finished = b.finished == 1;
            }
            if t0.elapsed() >= interval {
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let secs = t0.elapsed().as_secs_f64();
        snap.rates = counts
            .into_iter()
            .map(|(k, c)| (k, c as f64 / secs))
            .collect();
        let median = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        snap.median_ms = times
            .into_iter()
            .filter(|(_, v)| !v.is_empty())
            .map(|(k, mut v)| (k, median(&mut v)))
            .collect();
        snap.end_to_end_ms = (!e2e.is_empty()).then(|| median(&mut e2e));
        Ok(snap)
    }
}
