//! Ingest: replays a KITTI-layout sequence into the `frames` service, at the dataset's frame
//! rate (real-time mode: frames the pipeline cannot take are dropped here and reported) or as
//! fast as the pipeline accepts (lossless mode: at most [`MAX_IN_FLIGHT`] frames between
//! ingest and tracking, so back-pressure replaces loss; in real-time mode at most
//! [`REALTIME_IN_FLIGHT`], so latency stays bounded).

use crate::common::{send_slice, stamp, StageArgs, StageContext};
use anyhow::{bail, Result};
use std::time::{Duration, Instant};
use supermvo_config::IngestMode;
use supermvo_dataset::Sequence;
use supermvo_messages::iceoryx2::port::update_connections::UpdateConnections;
use supermvo_messages::iceoryx2::prelude::*;
use supermvo_messages::{
    now_ns, BackendState, FrameHeader, MessageError, PoseMsg, StageKind, Status, Topic,
    MAX_IN_FLIGHT,
};

/// Frames in flight at most in real-time mode: a frame that would wait behind more than this
/// is stale by the time it is processed. It waits for a free slot only until the next frame
/// is captured, and is then dropped (and reported) in favour of the newer one.
pub const REALTIME_IN_FLIGHT: usize = 2;

/// The frames the replay emits: `seq` maps to a frame of the sequence and a timestamp that
/// keeps growing across loops.
#[derive(Debug, Clone)]
pub struct Replay {
    /// Frames per loop.
    pub frames: usize,
    /// Loops.
    pub loops: usize,
    times: Vec<f64>,
}

impl Replay {
    /// The replay of `seq` (`max_frames` 0: all) `loops` times.
    pub fn new(seq: &Sequence, max_frames: usize, loops: usize) -> Self {
        let n = if max_frames == 0 {
            seq.len()
        } else {
            max_frames.min(seq.len())
        };
        Self {
            frames: n,
            loops: loops.max(1),
            times: seq.times[..n].to_vec(),
        }
    }

    /// Sequence numbers in all.
    pub fn total(&self) -> u64 {
        (self.frames * self.loops) as u64
    }

    /// Frame index and timestamp of `seq`.
    pub fn frame(&self, seq: u64) -> (usize, f64) {
        let n = self.frames.max(1);
        let (l, i) = (seq as usize / n, seq as usize % n);
        let period = match self.times.len() {
            0 | 1 => 0.1,
            k => (self.times[k - 1] - self.times[0]) * k as f64 / (k - 1) as f64,
        };
        (
            i,
            self.times.get(i).copied().unwrap_or(0.0) + l as f64 * period,
        )
    }
}

/// Runs the ingest stage until SIGTERM.
pub fn run(args: &StageArgs) -> Result<()> {
    let cfg = args.load_config()?.pipeline;
    let mut seq = Sequence::open_with_camera(&args.seq, cfg.camera.as_deref())?;
    // the features stage undistorts keypoints instead when so configured
    crate::features::keypoint_lens(&cfg, &mut seq);
    let replay = Replay::new(&seq, cfg.max_frames, cfg.loops);
    if replay.frames == 0 {
        bail!("{}: no frames", seq.dir.display());
    }
    let first = seq.load_frame(0)?;
    let mut ctx = StageContext::new(StageKind::Ingest, args.worker, &cfg)?;
    let frames = ctx
        .services
        .slice_topic::<u8>(&ctx.node, Topic::Frames, false)?
        .publisher_builder()
        .initial_max_slice_len(first.width * first.height)
        .allocation_strategy(AllocationStrategy::PowerOfTwo)
        .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
        .max_loaned_samples(2)
        .create()
        .map_err(|e| MessageError::ipc("frames publisher", e))?;
    let views = crate::views::ImageViews::open(&ctx, first.width * first.height)?;
    let poses = ctx.header_subscriber::<PoseMsg>(Topic::Poses)?;
    let backend = ctx.plain_subscriber::<BackendState>(Topic::Backend)?;

    // where to start: after the last frame the pipeline finished (restart), else at 0
    let mut done: Option<u64> = None;
    let drain_done = |done: &mut Option<u64>| -> Result<()> {
        while let Some(s) = poses.receive().map_err(|e| MessageError::ipc("poses", e))? {
            let seq = s.user_header().seq;
            *done = Some(done.map_or(seq, |d| d.max(seq)));
        }
        Ok(())
    };
    drain_done(&mut done)?;
    while let Some(s) = backend
        .receive()
        .map_err(|e| MessageError::ipc("backend", e))?
    {
        if s.payload().recorded > 0 {
            let seq = s.payload().seq;
            done = Some(done.map_or(seq, |d| d.max(seq)));
        }
    }
    let start = done.map_or(0, |d| d + 1);
    ctx.started();

    let (_, stamp_start) = replay.frame(start);
    let t0 = Instant::now();
    let mut next = start;
    let mut eos_sent = false;
    while ctx.wait() {
        drain_done(&mut done)?;
        if next > replay.total() {
            if !eos_sent {
                eos_sent = true;
                ctx.finished();
            }
            ctx.heartbeat_if_idle();
            publisher_keepalive(&frames);
            continue;
        }
        let in_flight = next - done.map_or(0, |d| d + 1).min(next);
        if next == replay.total() {
            // end of stream once every frame is through (so it stays in order)
            let mut h = FrameHeader::new(next, 0, 0.0, Status::EndOfStream);
            stamp(&mut h, StageKind::Ingest);
            send_slice(&frames, h, &[])?;
            ctx.frame_done(&h, h.t_ns[0], 0);
            next += 1;
            continue;
        }
        let (index, t) = replay.frame(next);
        let mut captured_ns = None;
        match cfg.mode {
            IngestMode::Lossless => {
                if in_flight as usize >= MAX_IN_FLIGHT {
                    publisher_keepalive(&frames);
                    ctx.heartbeat_if_idle();
                    continue;
                }
            }
            IngestMode::Realtime => {
                let due_at =
                    |t: f64| Duration::from_secs_f64(((t - stamp_start) / cfg.speed).max(0.0));
                let (due, now) = (due_at(t), t0.elapsed());
                if now < due {
                    publisher_keepalive(&frames);
                    ctx.heartbeat_if_idle();
                    continue;
                }
                // a full pipeline: the frame waits for a free slot until the next one is
                // captured, which then replaces it (a camera driver keeping the newest
                // frame); its capture time stays when it was due
                let next_due =
                    (next + 1 < replay.total()).then(|| due_at(replay.frame(next + 1).1));
                if in_flight as usize >= REALTIME_IN_FLIGHT && next_due.is_some_and(|d| now < d) {
                    publisher_keepalive(&frames);
                    ctx.heartbeat_if_idle();
                    continue;
                }
                captured_ns = Some(now_ns().saturating_sub((now - due).as_nanos() as u64));
                if in_flight as usize >= REALTIME_IN_FLIGHT {
                    let mut h = FrameHeader::new(next, index as u64, t, Status::Dropped);
                    stamp(&mut h, StageKind::Ingest);
                    send_slice(&frames, h, &[])?;
                    ctx.frame_done(&h, h.t_ns[0], in_flight as usize);
                    next += 1;
                    continue;
                }
            }
        }
        let t_in = now_ns();
        let size = (first.width, first.height);
        let h = publish_frame((&frames, &views), &seq, (next, index, t, captured_ns), size)?;
        ctx.frame_done(&h, t_in, in_flight as usize);
        next += 1;
    }
    Ok(())
}

type FramePublisher = supermvo_messages::iceoryx2::port::publisher::Publisher<
    supermvo_messages::Ipc,
    [u8],
    FrameHeader,
>;

/// Lets a waiting publisher deliver its history to subscribers that (re)connected.
fn publisher_keepalive(p: &FramePublisher) {
    let _ = p.update_connections();
}

/// Loads frame `index` and publishes it as `seq` (or reports it unreadable), and its image to
/// viewers.
fn publish_frame(
    (p, views): (&FramePublisher, &crate::views::ImageViews),
    seq: &Sequence,
    (next, index, t, captured_ns): (u64, usize, f64, Option<u64>),
    size: (usize, usize),
) -> Result<FrameHeader> {
    let image = match seq.load_frame(index) {
        Ok(img) if (img.width, img.height) == size => Some(img),
        Ok(img) => {
            tracing::warn!(
                "frame {index}: {}x{} differs from {}x{}; reported unreadable",
                img.width,
                img.height,
                size.0,
                size.1
            );
            None
        }
        Err(e) => {
            tracing::warn!("frame {index}: {e}; reported unreadable");
            None
        }
    };
    let Some(image) = image else {
        let mut h = FrameHeader::new(next, index as u64, t, Status::Unreadable);
        stamp(&mut h, StageKind::Ingest);
        send_slice(p, h, &[])?;
        return Ok(h);
    };
    let mut h = FrameHeader::new(next, index as u64, t, Status::Ok);
    h.width = image.width as u32;
    h.height = image.height as u32;
    stamp(&mut h, StageKind::Ingest);
    if let Some(captured) = captured_ns {
        // capture-to-pose latency counts from when the frame was due, waiting included
        h.t_ns[StageKind::Ingest as usize] = captured;
    }
    send_slice(p, h, &image.data)?;
    if views.listening() {
        // viewers draw the undistorted keypoints: show them the pinhole image
        let shown = seq.pinhole_view(&image);
        views.publish(h, &shown.as_ref().unwrap_or(&image).data);
    }
    Ok(h)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loops_keep_time_increasing() {
        let r = Replay {
            frames: 3,
            loops: 2,
            times: vec![0.0, 0.1, 0.2],
        };
        assert_eq!(r.total(), 6);
        let stamps: Vec<f64> = (0..6).map(|s| r.frame(s).1).collect();
        assert!(stamps.windows(2).all(|w| w[1] > w[0]), "{stamps:?}");
        assert_eq!(r.frame(4).0, 1);
        assert!((r.frame(3).1 - 0.3).abs() < 1e-12);
    }
}
