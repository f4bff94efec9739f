//! Tracking's side of the back end's loop closing: the features of each new keyframe go to
//! the back end (`keyframes`, sent before the keyframe's pose), its verdicts come back
//! (`corrections`) and their similarities are applied to the tracker in the order issued.
//!
//! In lossless mode the frame after a keyframe waits for the verdict on it, so that a
//! correction reaches the tracker exactly where it does in one process and the run stays
//! bit-identical to `supermvo run --mode inprocess`; in real-time mode tracking never waits
//! and applies a correction when it arrives (each pose says how many it had applied, see
//! `PoseMsg::corrections`, and the back end accounts for the lag).

use crate::common::{send_features, StageContext};
use anyhow::Result;
use std::time::{Duration, Instant};
use supermvo_config::{IngestMode, PipelineConfig};
use supermvo_messages::iceoryx2::port::publisher::Publisher;
use supermvo_messages::iceoryx2::port::subscriber::Subscriber;
use supermvo_messages::iceoryx2::port::update_connections::UpdateConnections;
use supermvo_messages::iceoryx2::prelude::*;
use supermvo_messages::{CorrectionMsg, FrameHeader, Ipc, MessageError, Topic};
use supermvo_optim::lie::Sim3;
use supermvo_vo::tracker::{FrameOutput, Tracker};

/// See the module docs.
pub struct LoopFeedback {
    keyframes: Publisher<Ipc, [f32], FrameHeader>,
    corrections: Subscriber<Ipc, CorrectionMsg, FrameHeader>,
    /// Corrections applied to the tracker (the world frame of its poses).
    pub applied: u32,
    /// The keyframe whose verdict the next frame waits for, and since when.
    awaiting: Option<(u64, Instant)>,
    wait: bool,
    timeout: Duration,
    /// The loop closed since the last view was published: `(query, match)` seqs.
    closed: Option<(i64, i64)>,
}

impl std::fmt::Debug for LoopFeedback {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "LoopFeedback({} applied)", self.applied)
    }
}

impl LoopFeedback {
    /// The feedback of a pipeline with loop closure on (None when it is off), continuing
    /// after `applied` corrections.
    pub fn open(ctx: &StageContext, cfg: &PipelineConfig, applied: u32) -> Result<Option<Self>> {
        if !cfg.loop_closure {
            return Ok(None);
        }
        let keyframes = ctx
            .services
            .slice_topic::<f32>(&ctx.node, Topic::Keyframes, false)?
            .publisher_builder()
            .initial_max_slice_len(cfg.top_k * (3 + cfg.frontend.descriptor_dim()))
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
            .create()
            .map_err(|e| MessageError::ipc("keyframes publisher", e))?;
        Ok(Some(Self {
            keyframes,
            corrections: ctx.header_subscriber::<CorrectionMsg>(Topic::Corrections)?,
            applied,
            awaiting: None,
            wait: cfg.mode == IngestMode::Lossless,
            timeout: Duration::from_millis(cfg.gap_timeout_ms),
            closed: None,
        }))
    }

    /// Sends the features of a frame that became a keyframe (before its pose is published)
    /// and, in lossless mode, holds the next frame until the back end's verdict on it.
    pub fn keyframe(
        &mut self,
        h: &FrameHeader,
        out: &FrameOutput,
        tracker: &Tracker,
    ) -> Result<()> {
        let Some((_, f)) = tracker.reference().filter(|_| out.keyframe) else {
            return Ok(());
        };
        if out.t_world_cam.is_none() {
            return Ok(());
        }
        let mut kh = *h;
        (kh.width, kh.height) = (f.image_size.0 as u32, f.image_size.1 as u32);
        send_features(&self.keyframes, kh, f)?;
        if self.wait {
            self.awaiting = Some((h.seq, Instant::now()));
        }
        Ok(())
    }

    /// Takes the verdicts that arrived and applies their corrections to the tracker.
    pub fn receive(&mut self, tracker: &mut Tracker) -> Result<()> {
        // a restarted back end's subscriber gets the keyframes in the history
        let _ = self.keyframes.update_connections();
        while let Some(s) = self
            .corrections
            .receive()
            .map_err(|e| MessageError::ipc("corrections", e))?
        {
            let h = *s.user_header();
            h.check()?;
            let v = *s.payload();
            if self.awaiting.is_some_and(|(seq, _)| seq == h.seq) {
                self.awaiting = None;
            }
            // a verdict the tracker has seen (the history a restarted stage receives)
            if v.closed != 1 || v.corrections <= self.applied {
                continue;
            }
            if v.corrections != self.applied + 1 {
                tracing::warn!(
                    "loop correction {} arrived after {} applied; corrections in between were lost",
                    v.corrections,
                    self.applied
                );
            }
            tracker.apply_correction(&sim3(&v));
            self.applied = v.corrections;
            self.closed = Some((v.loop_query, v.loop_match));
            tracing::info!(
                query = v.loop_query,
                matched = v.loop_match,
                scale = v.scale,
                "loop correction applied"
            );
        }
        Ok(())
    }

    /// Whether the next frame must wait for a verdict (lossless mode); gives up with a
    /// warning after the gap timeout (the run goes on, no longer bit-identical).
    pub fn holds_next_frame(&mut self) -> bool {
        let Some((seq, since)) = self.awaiting else {
            return false;
        };
        if since.elapsed() < self.timeout {
            return true;
        }
        tracing::warn!(
            "no loop-closing verdict on keyframe seq {seq} from the back end within {:?}; tracking goes on",
            self.timeout
        );
        self.awaiting = None;
        false
    }

    /// The loop closed since the last call: `(query, match)` sequence numbers.
    pub fn take_closed(&mut self) -> Option<(i64, i64)> {
        self.closed.take()
    }
}

/// The similarity of a verdict.
fn sim3(v: &CorrectionMsg) -> Sim3 {
    Sim3 {
        r: nalgebra::Matrix3::from_row_slice(&v.rotation),
        t: nalgebra::Vector3::from(v.translation),
        s: v.scale,
    }
}
