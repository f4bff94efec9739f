//! The tracker's local mapping run in the back-end process: each new keyframe's
//! triangulations and its local bundle adjustment.
//!
//! At each new keyframe the tracker gathers the triangulations the keyframe needs (its
//! landmarks re-fitted with the new view, re-observations, pending tracks extended by its
//! fresh matches) and then builds its local BA window, as it does in one process; in the
//! daemon, [`RemoteMapping`] sends each to the back end (`mapping_requests`), whose
//! [`MappingServer`] computes it with the same code and answers (`mapping_replies`). Every
//! number crosses as an `f64` ([`crate::mapping_codec`]), so the answer is the one the
//! tracker would have computed: the run stays bit-identical to `supermvo run --mode
//! inprocess`. The tracker keeps the map and its bookkeeping. When no back end listens (it
//! is restarting) or none answers within the gap timeout, the tracker does the work itself,
//! with the same result, so a dead back end costs time, never a different trajectory. In
//! real time the tracker does not wait: it triangulates the keyframe's landmarks itself
//! (the next frame tracks them), hands the window to the back end and [`LateSolutions`]
//! applies each solution when it arrives, as ORB-SLAM's local mapping thread updates the
//! map beside tracking.

use crate::common::{send_slice, StageContext};
use crate::mapping_codec::{
    apply_solution, decode_answers, decode_request, decode_solution, encode_answers, encode_batch,
    encode_problem, encode_solution, Request,
};
use anyhow::{Context, Result};
use std::io::Write;
use std::time::{Duration, Instant};
use supermvo_geometry::essential::Triangulated;
use supermvo_messages::iceoryx2::port::publisher::Publisher;
use supermvo_messages::iceoryx2::port::subscriber::Subscriber;
use supermvo_messages::iceoryx2::prelude::*;
use supermvo_messages::{FrameHeader, Ipc, MessageError, Status, Topic};
use supermvo_vo::ba::{BaOutcome, LocalBa};
use supermvo_vo::mapping_solver::{MappingSolver, TriangulationBatch};
use supermvo_vo::tracker::Tracker;

type Port = supermvo_messages::iceoryx2::service::port_factory::publish_subscribe::PortFactory<
    Ipc,
    [f64],
    FrameHeader,
>;

/// Tracking's side: hands each keyframe's triangulations and local BA to the back end and
/// waits for the answers, or (real time) hands over only the BA and goes on while
/// [`LateSolutions`] brings its solution.
pub struct RemoteMapping {
    service: Port,
    requests: Publisher<Ipc, [f64], FrameHeader>,
    /// The replies waited for; `None`: not waited for.
    replies: Option<Subscriber<Ipc, [f64], FrameHeader>>,
    next_id: u64,
    timeout: Duration,
}

impl std::fmt::Debug for RemoteMapping {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "RemoteMapping({} sent)", self.next_id)
    }
}

impl RemoteMapping {
    /// The ports of the tracking stage of `ctx`; waits for each answer up to `timeout`.
    pub fn open(ctx: &StageContext, timeout: Duration) -> Result<Self> {
        let mut mapping = Self::sender(ctx, timeout)?;
        mapping.replies = Some(ctx.slice_subscriber::<f64>(Topic::MappingReplies)?);
        Ok(mapping)
    }

    /// The ports of the tracking stage of `ctx`, not waiting: the BA solutions come through
    /// the [`LateSolutions`] returned with it.
    pub fn open_deferred(ctx: &StageContext) -> Result<(Self, LateSolutions)> {
        let late = LateSolutions {
            solutions: ctx.slice_subscriber::<f64>(Topic::MappingReplies)?,
        };
        Ok((Self::sender(ctx, Duration::ZERO)?, late))
    }

    fn sender(ctx: &StageContext, timeout: Duration) -> Result<Self> {
        let service = ctx
            .services
            .slice_topic::<f64>(&ctx.node, Topic::MappingRequests, false)?;
        let requests = service
            .publisher_builder()
            .initial_max_slice_len(1 << 14)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| MessageError::ipc("local mapping publisher", e))?;
        Ok(Self {
            service,
            requests,
            replies: None,
            next_id: 0,
            timeout,
        })
    }

    fn back_end_listens(&self) -> bool {
        self.service.dynamic_config().number_of_subscribers() > 0
    }

    /// Sends a request (`what` names it in warnings): its id, or `None` when no back end
    /// listens or the send fails.
    fn send(&mut self, what: &str, request: &[f64]) -> Option<u64> {
        if !self.back_end_listens() {
            return None;
        }
        let id = self.next_id;
        self.next_id += 1;
        let h = FrameHeader::new(id, 0, 0.0, Status::Ok);
        match send_slice(&self.requests, h, request) {
            Ok(()) => Some(id),
            Err(e) => {
                tracing::warn!("{what} {id} not sent ({e:#}); done here");
                None
            }
        }
    }

    /// Waits for the reply to request `id` and reads it with `read`: `None` when none comes
    /// in time, the back end goes away or the reply does not fit.
    fn wait_for<T>(
        &self,
        what: &str,
        id: u64,
        read: impl FnOnce(&[f64]) -> Result<T>,
    ) -> Option<T> {
        let replies = self.replies.as_ref()?;
        let deadline = Instant::now() + self.timeout;
        while Instant::now() < deadline {
            match replies.receive() {
                Ok(Some(s)) if s.user_header().seq == id => {
                    return match read(s.payload()) {
                        Ok(answer) => Some(answer),
                        Err(e) => {
                            tracing::warn!("{what} {id}: {e:#}; done here");
                            None
                        }
                    };
                }
                Ok(Some(_)) => {} // the answer to a request already done here
                Ok(None) if !self.back_end_listens() => {
                    tracing::warn!("{what} {id}: the back end went away; done here");
                    return None;
                }
                Ok(None) => std::thread::sleep(Duration::from_micros(100)),
                Err(e) => {
                    tracing::warn!("{what} {id}: receiving the reply failed ({e}); done here");
                    return None;
                }
            }
        }
        tracing::warn!(
            "{what} {id}: no reply from the back end within {} ms; done here",
            self.timeout.as_millis()
        );
        None
    }
}

impl MappingSolver for RemoteMapping {
    fn solve(&mut self, ba: &mut LocalBa, iterations: usize) -> BaOutcome {
        let sent = self.send("local BA", &encode_problem(ba, iterations));
        let solved = match (sent, &self.replies) {
            (Some(id), None) => return BaOutcome::Deferred(id),
            (Some(id), Some(_)) => self.wait_for("local BA", id, |v| apply_solution(v, ba)),
            (None, _) => None,
        };
        let (before, after) = solved.unwrap_or_else(|| ba.solve(iterations));
        BaOutcome::Solved(before, after)
    }

    /// Lossless only: in real time the tracker triangulates at once, so that the next frame
    /// can track the new landmarks.
    fn triangulates(&self) -> bool {
        self.replies.is_some()
    }

    /// The back end's answers, waited for.
    fn triangulate(&mut self, batch: &TriangulationBatch) -> Option<Vec<Option<Triangulated>>> {
        let id = self.send("triangulation", &encode_batch(batch))?;
        self.wait_for("triangulation", id, |v| {
            decode_answers(v, batch.queries.len())
        })
    }
}

/// Real time: the solutions of the windows handed off, applied to the tracker as they come.
pub struct LateSolutions {
    solutions: Subscriber<Ipc, [f64], FrameHeader>,
}

impl std::fmt::Debug for LateSolutions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("LateSolutions")
    }
}

impl LateSolutions {
    /// Applies every solution received (the tracker drops one a newer window replaced or a
    /// loop correction outdated); how many were applied.
    pub fn apply(&self, tracker: &mut Tracker) -> Result<usize> {
        let mut applied = 0;
        while let Some(s) = self
            .solutions
            .receive()
            .map_err(|e| MessageError::ipc("local BA solutions", e))?
        {
            let id = s.user_header().seq;
            match decode_solution(s.payload()) {
                Ok((poses, points, _)) => {
                    applied += tracker.apply_local_ba(id, &poses, &points) as usize;
                }
                Err(e) => tracing::warn!("local BA {id}: {e:#}; not applied"),
            }
        }
        Ok(applied)
    }
}

/// The back end's record of the local BAs it solved, in the output folder: one line each
/// (`id,keyframes,fixed,points,observations,cost_before,cost_after,ms`).
pub const BA_LOG_FILE: &str = "local_ba.csv";
/// The back end's record of the keyframes' triangulations it computed: one line per
/// keyframe (`id,points,triangulated,ms`).
pub const TRIANGULATION_LOG_FILE: &str = "triangulation.csv";

/// The back end's side: computes every request received and answers it.
pub struct MappingServer {
    requests: Subscriber<Ipc, [f64], FrameHeader>,
    replies: Publisher<Ipc, [f64], FrameHeader>,
    ba_log: std::fs::File,
    triangulation_log: std::fs::File,
}

impl std::fmt::Debug for MappingServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("MappingServer")
    }
}

/// Opens the log `name` in `out` for appending, with `header` when it is new.
fn open_log(out: &std::path::Path, name: &str, header: &str) -> Result<std::fs::File> {
    let path = out.join(name);
    let fresh = !path.exists();
    let mut log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .with_context(|| format!("opening {}", path.display()))?;
    if fresh {
        writeln!(log, "{header}").with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(log)
}

impl MappingServer {
    /// The ports of the back-end stage of `ctx`, logging to [`BA_LOG_FILE`] and
    /// [`TRIANGULATION_LOG_FILE`] in `out`.
    pub fn open(ctx: &StageContext, out: &std::path::Path) -> Result<Self> {
        let ba_log = open_log(
            out,
            BA_LOG_FILE,
            "id,keyframes,fixed,points,observations,cost_before,cost_after,ms",
        )?;
        let triangulation_log = open_log(out, TRIANGULATION_LOG_FILE, "id,points,triangulated,ms")?;
        let replies = ctx
            .services
            .slice_topic::<f64>(&ctx.node, Topic::MappingReplies, false)?
            .publisher_builder()
            .initial_max_slice_len(1 << 13)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| MessageError::ipc("local mapping replies publisher", e))?;
        Ok(Self {
            requests: ctx.slice_subscriber::<f64>(Topic::MappingRequests)?,
            replies,
            ba_log,
            triangulation_log,
        })
    }

    /// Computes and answers every request waiting; how many. A malformed request is logged
    /// and left unanswered (the tracker then does the work itself).
    pub fn serve(&mut self) -> Result<usize> {
        let mut served = 0;
        while let Some(s) = self
            .requests
            .receive()
            .map_err(|e| MessageError::ipc("local mapping requests", e))?
        {
            let h = *s.user_header();
            let request = decode_request(s.payload());
            drop(s);
            let started = Instant::now();
            let ms = |started: Instant| started.elapsed().as_secs_f64() * 1e3;
            match request {
                Ok(Request::Ba(mut ba, iterations)) => {
                    let costs = ba.solve(iterations);
                    send_slice(&self.replies, h, &encode_solution(&ba, costs))?;
                    let fixed = ba.fixed.iter().filter(|&&f| f).count();
                    writeln!(
                        self.ba_log,
                        "{},{},{fixed},{},{},{:e},{:e},{:.3}",
                        h.seq,
                        ba.poses.len(),
                        ba.points.len(),
                        ba.observations.len(),
                        costs.0,
                        costs.1,
                        ms(started)
                    )?;
                }
                Ok(Request::Triangulation(batch)) => {
                    let answers = batch.solve();
                    send_slice(&self.replies, h, &encode_answers(&answers))?;
                    writeln!(
                        self.triangulation_log,
                        "{},{},{},{:.3}",
                        h.seq,
                        answers.len(),
                        answers.iter().flatten().count(),
                        ms(started)
                    )?;
                }
                Err(e) => {
                    tracing::warn!("local mapping request {}: {e:#}; not done", h.seq);
                    continue;
                }
            }
            served += 1;
        }
        Ok(served)
    }
}
