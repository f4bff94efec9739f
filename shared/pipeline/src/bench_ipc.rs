//! One hop between two stages, measured: a 1241x376 image and 2048 keypoints with 64-float
//! descriptors, sent over iceoryx2 shared memory to another process, next to the same
//! payloads sent over a crossbeam channel to another thread of one process.
//!
//! The latency of a hop runs from just before the sender starts writing the payload (loan
//! and write in place for iceoryx2; allocate and copy for the channel, since an owned buffer
//! is what a channel moves) to the receiver holding it; the receiver reads the payload's last
//! byte. Sends are one at a time (ping-pong), so no queueing is measured. The receiver spins,
//! as it would with an event-driven wait; the pipeline stages poll every 0.5 ms on top.

use anyhow::{bail, Context, Result};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use supermvo_messages::iceoryx2::prelude::*;
use supermvo_messages::{create_node, now_ns, FrameHeader, Ipc, IpcNode, MessageError, Status};

/// Percentiles of one kind of hop, microseconds.
#[derive(Debug, Clone, serde::Serialize)]
pub struct HopStats {
    /// Transport.
    pub transport: String,
    /// Payload.
    pub payload: String,
    /// Bytes per message.
    pub bytes: usize,
    /// Hops measured.
    pub count: usize,
    /// Median, µs.
    pub p50_us: f64,
    /// 99th percentile, µs.
    pub p99_us: f64,
}

fn stats(transport: &str, payload: &str, bytes: usize, mut v: Vec<f64>) -> HopStats {
    v.sort_by(f64::total_cmp);
    let q = |p: f64| v[((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
    HopStats {
        transport: transport.into(),
        payload: payload.into(),
        bytes,
        count: v.len(),
        p50_us: q(0.5),
        p99_us: q(0.99),
    }
}

fn service_name(name: &str, topic: &str) -> Result<ServiceName> {
    let s = format!("supermvo-bench/{name}/{topic}");
    Ok(s.as_str()
        .try_into()
        .map_err(|e| MessageError::ipc(format!("service name {s}"), e))?)
}

fn open_data(
    node: &IpcNode,
    name: &str,
    topic: &str,
) -> Result<
    supermvo_messages::iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        Ipc,
        [u8],
        FrameHeader,
    >,
> {
    node.service_builder(&service_name(name, topic)?)
        .publish_subscribe::<[u8]>()
        .user_header::<FrameHeader>()
        .open_or_create()
        .map_err(|e| MessageError::ipc(format!("bench service {topic}"), e).into())
}

fn open_ack(
    node: &IpcNode,
    name: &str,
) -> Result<
    supermvo_messages::iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        Ipc,
        u64,
        (),
    >,
> {
    node.service_builder(&service_name(name, "ack")?)
        .publish_subscribe::<u64>()
        .open_or_create()
        .map_err(|e| MessageError::ipc("bench ack service", e).into())
}

/// The receiving side (`supermvo bench ipc-echo`): answers every message with its latency
/// in nanoseconds until the sender says stop (an empty message).
pub fn echo(name: &str) -> Result<()> {
    let node = create_node(
        &format!("supermvo-bench/{name}/echo")
            .as_str()
            .try_into()
            .map_err(|e| MessageError::ipc("node name", e))?,
    )?;
    let data = open_data(&node, name, "data")?
        .subscriber_builder()
        .create()
        .map_err(|e| MessageError::ipc("bench subscriber", e))?;
    let ack = open_ack(&node, name)?
        .publisher_builder()
        .create()
        .map_err(|e| MessageError::ipc("bench ack publisher", e))?;
    let t0 = Instant::now();
    loop {
        if let Some(s) = data
            .receive()
            .map_err(|e| MessageError::ipc("bench receive", e))?
        {
            let t = now_ns();
            let p = s.payload();
            if p.is_empty() {
                return Ok(());
            }
            std::hint::black_box(p[p.len() - 1]);
            let lat = t.saturating_sub(s.user_header().t_ns[0]);
            ack.send_copy(lat)
                .map_err(|e| MessageError::ipc("bench ack", e))?;
        } else {
            std::hint::spin_loop();
            if t0.elapsed() > Duration::from_secs(300) {
                bail!("bench echo: no stop message after 300 s");
            }
        }
    }
}

/// Runs the benchmark: `samples` hops of each payload over each transport. `exe` is the
/// program that runs [`echo`] when called as `exe bench ipc-echo --name NAME`.
pub fn run(exe: &Path, samples: usize) -> Result<Vec<HopStats>> {
    let name = format!("b{}", std::process::id());
    let image: Vec<u8> = (0..1241 * 376).map(|i| (i % 251) as u8).collect();
    let kp: Vec<u8> = (0..2048 * (3 + 64) * 4).map(|i| (i % 253) as u8).collect();
    let payloads = [
        ("image 1241x376 u8", &image),
        ("2048 keypoints + 64-float descriptors", &kp),
    ];
    let mut out = Vec::new();

    // iceoryx2: another process
    let node = create_node(
        &format!("supermvo-bench/{name}/send")
            .as_str()
            .try_into()
            .map_err(|e| MessageError::ipc("node name", e))?,
    )?;
    let data_service = open_data(&node, &name, "data")?;
    let ack_service = open_ack(&node, &name)?;
    let publisher = data_service
        .publisher_builder()
        .initial_max_slice_len(kp.len().max(image.len()))
        .create()
        .map_err(|e| MessageError::ipc("bench publisher", e))?;
    let acks = ack_service
        .subscriber_builder()
        .create()
        .map_err(|e| MessageError::ipc("bench ack subscriber", e))?;
    let mut child = Command::new(exe)
        .args(["bench", "ipc-echo", "--name", &name])
        .stdin(Stdio::null())
        .spawn()
        .with_context(|| format!("starting {} bench ipc-echo", exe.display()))?;
    let send = |bytes: &[u8]| -> Result<()> {
        let mut h = FrameHeader::new(0, 0, 0.0, Status::Ok);
        h.t_ns[0] = now_ns();
        let s = publisher
            .loan_slice_uninit(bytes.len())
            .map_err(|e| MessageError::ipc("bench loan", e))?;
        let mut s = s.write_from_slice(bytes);
        *s.user_header_mut() = h;
        s.send().map_err(|e| MessageError::ipc("bench send", e))?;
        Ok(())
    };
    // wait for the echo to connect
    let t0 = Instant::now();
    while data_service.dynamic_config().number_of_subscribers() == 0 {
        if t0.elapsed() > Duration::from_secs(20) {
            let _ = child.kill();
            bail!("bench echo process did not connect within 20 s");
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    for (label, bytes) in payloads {
        let mut lat = Vec::with_capacity(samples);
        for i in 0..samples + 20 {
            send(bytes)?;
            let t = Instant::now();
            let ns = loop {
                if let Some(a) = acks
                    .receive()
                    .map_err(|e| MessageError::ipc("bench ack", e))?
                {
                    break *a.payload();
                }
                if t.elapsed() > Duration::from_secs(10) {
                    let _ = child.kill();
                    bail!("bench echo process stopped answering");
                }
                std::hint::spin_loop();
            };
            if i >= 20 {
                lat.push(ns as f64 * 1e-3);
            }
        }
        out.push(stats(
            "iceoryx2 (process to process)",
            label,
            bytes.len(),
            lat,
        ));
    }
    send(&[])?;
    let _ = child.wait();

    // crossbeam: another thread
    for (label, bytes) in payloads {
        let (tx, rx) = crossbeam_channel::bounded::<(u64, Vec<u8>)>(1);
        let (atx, arx) = crossbeam_channel::bounded::<u64>(1);
        let receiver = std::thread::spawn(move || {
            while let Ok((t, v)) = rx.recv() {
                let now = now_ns();
                if v.is_empty() {
                    break;
                }
                std::hint::black_box(v[v.len() - 1]);
                if atx.send(now.saturating_sub(t)).is_err() {
                    break;
                }
            }
        });
        let mut lat = Vec::with_capacity(samples);
        for i in 0..samples + 20 {
            let t = now_ns();
            tx.send((t, bytes.clone()))
                .map_err(|_| anyhow::anyhow!("channel closed"))?;
            let ns = arx.recv().map_err(|_| anyhow::anyhow!("channel closed"))?;
            if i >= 20 {
                lat.push(ns as f64 * 1e-3);
            }
        }
        let _ = tx.send((0, Vec::new()));
        let _ = receiver.join();
        out.push(stats(
            "crossbeam channel (thread to thread)",
            label,
            bytes.len(),
            lat,
        ));
    }
    Ok(out)
}
