//! Matching: LighterGlue matches of each frame against the tracker's reference keyframe.
//!
//! Which frame is the reference is the tracker's decision for the previous frame, read from
//! the `poses` service; so matching of frame `s` waits for the tracker's result of `s - 1`.
//! That decision also says whether frame `s` is matched at once: otherwise the tracker
//! first tries it by projection, and either decides it without matches (nothing is sent
//! for it) or asks for them on `match_requests`.
//! Features are kept by sequence number until they can no longer become or be the reference.

use crate::common::{receive_features, send_slice, stamp, StageArgs, StageContext};
use crate::inbox::Inbox;
use anyhow::Result;
use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;
use supermvo_config::{Frontend, NetworkPlacement, PipelineConfig};
use supermvo_inference::lighterglue::{LightGlue, LightGlueConfig};
use supermvo_inference::orb::OrbMatcher;
use supermvo_inference::strongest::StrongestOnly;
use supermvo_inference::superglue::{SuperGlue, SuperGlueConfig};
use supermvo_inference::{models, Features, Matcher};
use supermvo_messages::iceoryx2::port::update_connections::UpdateConnections;
use supermvo_messages::iceoryx2::prelude::*;
use supermvo_messages::{
    now_ns, FrameHeader, MatchEntry, MatchRequest, MessageError, PoseMsg, StageKind, Status, Topic,
};

/// The matcher the daemon and `supermvo run --mode inprocess` both use, given only the
/// strongest `pipeline.matcher_top_k` keypoints of each frame when that is set.
pub fn matcher(
    cfg: &PipelineConfig,
    placement: NetworkPlacement,
) -> Result<Box<dyn Matcher + Send>> {
    let full = frontend_matcher(cfg, placement)?;
    Ok(match cfg.matcher_keypoints() {
        Some(k) => Box::new(StrongestOnly::new(full, k)),
        None => full,
    })
}

/// The front end's matcher, given every keypoint.
fn frontend_matcher(
    cfg: &PipelineConfig,
    placement: NetworkPlacement,
) -> Result<Box<dyn Matcher + Send>> {
    Ok(match cfg.frontend {
        Frontend::XfeatLighterglue => Box::new(LightGlue::new(
            &models::model_path("lighterglue"),
            "lighterglue",
            LightGlueConfig {
                threads: cfg.matcher_threads(placement),
                spin: cfg.thread_spinning,
                device: crate::common::device(cfg.device),
                width_confidence: cfg.width_confidence as f32,
                depth_confidence: cfg.depth_confidence as f32,
                ..Default::default()
            },
        )?),
        Frontend::AlikedLightglue => Box::new(LightGlue::new(
            &models::model_path("lightglue"),
            "lightglue",
            LightGlueConfig {
                threads: cfg.matcher_threads(placement),
                spin: cfg.thread_spinning,
                device: crate::common::device(cfg.device),
                // LightGlue's own defaults for its adaptive width and depth
                width_confidence: 0.99,
                depth_confidence: 0.95,
                ..Default::default()
            },
        )?),
        Frontend::SuperpointSuperglue => Box::new(SuperGlue::new(
            &models::model_path("superglue"),
            SuperGlueConfig {
                threads: cfg.matcher_threads(placement),
                spin: cfg.thread_spinning,
                device: crate::common::device(cfg.device),
                ..Default::default()
            },
        )?),
        Frontend::Orb => Box::new(OrbMatcher::default()),
    })
}

type MatchPublisher = supermvo_messages::iceoryx2::port::publisher::Publisher<
    supermvo_messages::Ipc,
    [MatchEntry],
    FrameHeader,
>;

fn send(p: &MatchPublisher, mut h: FrameHeader, entries: &[MatchEntry]) -> Result<FrameHeader> {
    stamp(&mut h, StageKind::Matching);
    h.count = entries.len() as u32;
    send_slice(p, h, entries)?;
    Ok(h)
}

/// Matches made-up keypoint sets before the stage reports itself up: ONNX Runtime's first
/// call is several times slower than the next ones (in real time the first frames would be
/// late or dropped), and its memory arena grows to what the calls need. A matcher's tensors
/// change shape with each pair's keypoint counts and with the points it prunes and the
/// layers it runs, so the warm-up runs the largest computation at the configured size
/// ([`Matcher::warm_up`]: LighterGlue with no point pruned and every layer run), then
/// smaller pairs as configured, with every point matchable and with half of them not, for
/// the arena to reach its working size before the first frame.
fn warm_up(matcher: &mut dyn Matcher, n: usize, dim: usize) {
    if n == 0 {
        return;
    }
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32 - 0.5
    };
    let mut unit = |count: usize| -> Vec<f32> {
        let mut d: Vec<f32> = (0..count * dim).map(|_| next()).collect();
        for row in d.chunks_mut(dim.max(1)) {
            let norm = row.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-6);
            row.iter_mut().for_each(|v| *v /= norm);
        }
        d
    };
    let (shared, own) = (unit(n), [unit(n), unit(n)]);
    // `count` points, the first `matchable` with descriptors both sides share
    let features = |side: usize, count: usize, matchable: usize| -> Features {
        let k = matchable.min(count);
        let mut descriptors = shared[..k * dim].to_vec();
        descriptors.extend_from_slice(&own[side][k * dim..count * dim]);
        let shift = 3.0 * side as f32;
        Features {
            keypoints: (0..count)
                .map(|i| [(i % 40) as f32 * 25.0 + shift, (i / 40) as f32 * 12.0])
                .collect(),
            scores: vec![1.0; count],
            descriptors,
            dim,
            image_size: (1024, 512),
        }
    };
    let _ = matcher.warm_up(&features(0, n, n), &features(1, n, n));
    let sizes = [(n, n), (n, n * 3 / 4), (n * 3 / 4, n), (n / 2, n / 2)];
    for (a, b) in sizes.into_iter().filter(|&(a, b)| a > 0 && b > 0) {
        for matchable in [n, n / 2] {
            let _ = matcher.match_features(&features(0, a, matchable), &features(1, b, matchable));
        }
    }
}

/// Runs the matching stage until SIGTERM.
pub fn run(args: &StageArgs) -> Result<()> {
    let cfg = args.load_config()?.pipeline;
    let mut matcher = matcher(&cfg, NetworkPlacement::SideBySide)?;
    let mut ctx = StageContext::new(StageKind::Matching, args.worker, &cfg)?;
    let features = ctx.slice_subscriber::<f32>(Topic::Features)?;
    let poses = ctx.header_subscriber::<PoseMsg>(Topic::Poses)?;
    let requests = ctx.header_subscriber::<MatchRequest>(Topic::MatchRequests)?;
    let publisher = ctx
        .services
        .slice_topic::<MatchEntry>(&ctx.node, Topic::Matches, false)?
        .publisher_builder()
        .initial_max_slice_len(cfg.top_k)
        .allocation_strategy(AllocationStrategy::PowerOfTwo)
        .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
        .max_loaned_samples(2)
        .create()
        .map_err(|e| MessageError::ipc("matches publisher", e))?;

    // after each tracked seq: the reference, and whether the next frame is matched to it
    let mut refs: BTreeMap<u64, (Option<u64>, bool)> = BTreeMap::new();
    // frames the tracker made its reference (keyframes), which it may return to
    let mut keyframes: BTreeSet<u64> = BTreeSet::new();
    let drain_poses = |refs: &mut BTreeMap<u64, (Option<u64>, bool)>,
                       keyframes: &mut BTreeSet<u64>|
     -> Result<()> {
        while let Some(s) = poses.receive().map_err(|e| MessageError::ipc("poses", e))? {
            let (seq, r) = (s.user_header().seq, s.payload().reference);
            let r = (r >= 0).then_some(r as u64);
            if r == Some(seq) {
                keyframes.insert(seq);
            }
            refs.insert(seq, (r, s.payload().match_next != 0));
        }
        Ok(())
    };
    // frames the tracker asked to have matched after all, with their reference
    let mut asked: BTreeMap<u64, i64> = BTreeMap::new();
    let mut inbox: Inbox<Option<Features>> = Inbox::new(0, 1);
    let mut cache: BTreeMap<u64, Features> = BTreeMap::new();
    let gap = Duration::from_millis(cfg.gap_timeout_ms);
    warm_up(matcher.as_mut(), cfg.top_k, cfg.frontend.descriptor_dim());
    ctx.started();
    while ctx.wait() {
        drain_poses(&mut refs, &mut keyframes)?;
        while let Some(s) = requests
            .receive()
            .map_err(|e| MessageError::ipc("match requests", e))?
        {
            asked.insert(s.user_header().seq, s.payload().reference);
        }
        // Whenever the tracker has decided on a frame this process still expects (a restart:
        // the tracker's history may reach it only after it came up), continue after the
        // tracker's last decision instead of waiting for one that was already made.
        if let Some(&last) = refs.keys().next_back() {
            if last >= inbox.next() {
                tracing::info!("the tracker has decided up to seq {last}; continuing after it");
                inbox.reset_to(last + 1);
            }
        }
        receive_features(&features, &mut inbox)?;
        let _ = publisher.update_connections();
        loop {
            let next = inbox.next();
            let decision = if next == 0 {
                Some((None, true))
            } else {
                refs.get(&(next - 1)).copied()
            };
            let Some((reference, wanted)) = decision else {
                break; // waiting for the tracker's decision on the previous frame
            };
            if !inbox.ready() {
                if inbox.gap_expired(gap) {
                    let seq = inbox.skip();
                    tracing::warn!("features of seq {seq} never arrived; reported lost");
                    let h = send(&publisher, FrameHeader::new(seq, 0, 0.0, Status::Lost), &[])?;
                    ctx.frame_done(&h, now_ns(), inbox.len());
                    continue;
                }
                break;
            }
            let has_features = inbox.peek().is_some_and(|(_, f, _)| f.is_some());
            let target = match (wanted, asked.get(&next)) {
                (true, _) => reference,
                // the tracker tried this frame by projection and asks for its matches
                (false, Some(&r)) => (r >= 0).then_some(r as u64),
                // tracked without matches: nothing to send, only its features to keep
                (false, None) if refs.contains_key(&next) || !has_features => None,
                (false, None) => break, // the tracker has not decided yet
            };
            let skipped = !wanted && has_features && !asked.contains_key(&next);
            let Some((h_in, f, _received)) = inbox.pop() else {
                break;
            };
            // processing time, not the wait for the tracker's decision
            let t_in = now_ns();
            let h = match (f, target) {
                (Some(f), _) if skipped => {
                    cache.insert(h_in.seq, f);
                    h_in.forward(Status::Ok)
                }
                (Some(f), None) => {
                    let mut h = h_in.forward(Status::Ok);
                    h.reference = -1;
                    let h = send(&publisher, h, &[])?;
                    cache.insert(h_in.seq, f);
                    h
                }
                (Some(f), Some(r)) => {
                    let h = match cache.get(&r) {
                        Some(rf) => {
                            let m = matcher.match_features(rf, &f)?;
                            let entries: Vec<MatchEntry> = m
                                .pairs
                                .iter()
                                .zip(&m.scores)
                                .map(|(&(a, b), &score)| MatchEntry {
                                    a: a as u32,
                                    b: b as u32,
                                    score,
                                })
                                .collect();
                            let mut h = h_in.forward(Status::Ok);
                            h.reference = r as i64;
                            send(&publisher, h, &entries)?
                        }
                        None => {
                            tracing::warn!(
                                "seq {}: features of reference {r} are gone (restart); the tracker starts again",
                                h_in.seq
                            );
                            send(&publisher, h_in.forward(Status::NoReference), &[])?
                        }
                    };
                    cache.insert(h_in.seq, f);
                    h
                }
                (None, _) => send(&publisher, h_in.forward(h_in.status()), &[])?,
            };
            ctx.frame_done(&h, t_in, inbox.len());
            if h.status() == Status::EndOfStream {
                ctx.finished();
            }
            // keep only what can still be a reference: the current one, the keyframes since,
            // and the frame just matched (the tracker has not decided on it yet). A frame
            // the tracker decided on without making it its reference never becomes one, so
            // a reference held for many frames (a camera standing still while the tracker
            // initialises) keeps one frame's features here, not all of them.
            let keep_from = refs
                .get(&h.seq)
                .and_then(|(r, _)| *r)
                .or(reference)
                .unwrap_or(h.seq)
                .min(h.seq);
            cache = cache.split_off(&keep_from);
            cache.retain(|&seq, _| seq == keep_from || seq >= h.seq || keyframes.contains(&seq));
            keyframes = keyframes.split_off(&keep_from);
            refs = refs.split_off(&h.seq.saturating_sub(1));
            asked = asked.split_off(&(h.seq + 1));
        }
        ctx.heartbeat_if_idle();
    }
    Ok(())
}
