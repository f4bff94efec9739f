//! Tracking: the VO tracker over the features and matches of each frame, publishing its
//! result (pose, state and the reference keyframe for the next frame) on `poses`, each new
//! keyframe to the back end, and applying the back end's loop corrections
//! ([`crate::loop_feedback`]).
//!
//! A restarted tracker continues from the back end's last recorded pose and map scale.

use crate::common::{receive_features, send_value, stamp, StageArgs, StageContext};
use crate::inbox::Inbox;
use crate::loop_feedback::LoopFeedback;
use crate::remote_mapping::RemoteMapping;
use anyhow::{Context, Result};
use std::time::Duration;
use supermvo_config::{IngestMode, PipelineConfig};
use supermvo_dataset::Sequence;
use supermvo_geometry::Pose;
use supermvo_inference::{Features, FrameView, Matches};
use supermvo_messages::iceoryx2::port::subscriber::Subscriber;
use supermvo_messages::iceoryx2::port::update_connections::UpdateConnections;
use supermvo_messages::iceoryx2::prelude::*;
use supermvo_messages::{
    now_ns, BackendState, BackfilledPose, FrameHeader, Ipc, MatchEntry, MatchRequest, MessageError,
    PoseMsg, StageKind, Status, Topic, ViewHeader, MAX_BACKFILLED,
};
use supermvo_vo::tracker::{FrameMeta, FrameOutput, Tracker, TrackerConfig, TrackingState};

/// The tracker configuration the daemon and `supermvo run --mode inprocess` both use.
pub fn tracker_config(cfg: &PipelineConfig) -> TrackerConfig {
    let base = TrackerConfig {
        local_ba_window: cfg.ba_window,
        local_ba_min_shared: cfg.ba_min_shared,
        keyframe_ratio: cfg.keyframe_ratio,
        relocalisation_frames: cfg.relocalisation_frames,
        weak_gate_factor: cfg.pnp_gate_widening,
        backfill_frames: cfg.backfill_frames,
        reinitialise_on_reference: cfg.reinitialise_on_reference,
        reinitialise_at_map_scale: cfg.reinitialise_at_map_scale,
        covisible_triangulation_keyframes: cfg.covisible_triangulation,
        robust_cutoff_factor: cfg.robust_cutoff,
        match_every_frame: cfg.match_every_frame,
        lens_check: cfg.lens_check,
        lens_self_calibration: cfg.lens_self_calibration,
        lens_min_k1: cfg.lens_min_k1,
        ..TrackerConfig::default()
    }
    .with_seed(cfg.seed);
    match cfg.frontend {
        // the learned pairs share the default thresholds
        supermvo_config::Frontend::XfeatLighterglue
        | supermvo_config::Frontend::SuperpointSuperglue
        | supermvo_config::Frontend::AlikedLightglue => base,
        // ORB's ratio-tested matches cluster near the focus of expansion (their median
        // displacement stays under 10 px while the car drives 20 m on the synthetic
        // streets) and thin out as the baseline grows, so ORB starts the two-view
        // initialisation at 5 px and initialises and tracks with fewer matches; without this
        // it never initialises.
        supermvo_config::Frontend::Orb => TrackerConfig {
            min_parallax_px: 5.0,
            min_init_landmarks: 50,
            min_tracked: 30,
            keyframe_min_tracked: 80,
            ..base
        },
    }
}

// the configuration's bound on the backfilled frames is what a pose message carries
const _: () = assert!(supermvo_config::MAX_BACKFILL_FRAMES == MAX_BACKFILLED);

/// A tracker result as a message payload (the tracker's frame indices are sequence numbers
/// in the daemon, see `frame_meta`).
/// `corrections`: the loop corrections the tracker had applied.
pub fn pose_msg(o: &FrameOutput, corrections: u32) -> PoseMsg {
    PoseMsg {
        state: match o.state {
            TrackingState::Initializing => 0,
            TrackingState::Tracking => 1,
            TrackingState::Lost => PoseMsg::LOST,
        },
        has_pose: o.t_world_cam.is_some() as u32,
        t_world_cam: o
            .t_world_cam
            .map(|p| p.to_row_major_3x4())
            .unwrap_or_default(),
        keyframe: o.keyframe as u32,
        keypoints: o.keypoints as u32,
        matches: o.matches as u32,
        inliers: o.inliers as u32,
        landmarks: o.landmarks as u64,
        reference: o.reference.map_or(-1, |r| r as i64),
        match_next: o.match_next as u32,
        scale: o.scale.unwrap_or(0.0),
        backfilled_count: o.backfilled.len().min(MAX_BACKFILLED) as u32,
        corrections,
        backfilled: std::array::from_fn(|i| {
            o.backfilled
                .get(i)
                .map_or_else(Default::default, |l| BackfilledPose {
                    seq: l.index as u64,
                    t_world_cam: l.t_world_cam.to_row_major_3x4(),
                })
        }),
    }
}

/// Continues after what the back end has recorded: the next seq, the loop corrections
/// already applied, and the tracker placed at the last recorded pose. When the back end
/// has recorded frames (this tracker replaces one that died), waits up to the gap timeout
/// for its state, which reaches a new subscriber only once the back end updates its
/// connections.
fn restore(
    backend: &Subscriber<Ipc, BackendState, ()>,
    tracker: &mut Tracker,
    out: &std::path::Path,
    cfg: &PipelineConfig,
) -> Result<(u64, u32)> {
    let joining = crate::frame_log::has_records(out);
    let deadline = std::time::Instant::now() + Duration::from_millis(cfg.gap_timeout_ms);
    let mut latest = None;
    loop {
        while let Some(s) = backend
            .receive()
            .map_err(|e| MessageError::ipc("backend", e))?
        {
            latest = Some(*s.payload());
        }
        let waiting = joining && latest.is_none_or(|b| b.recorded == 0);
        if !waiting || std::time::Instant::now() >= deadline {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let Some(b) = latest.filter(|b| b.recorded > 0) else {
        if joining {
            tracing::warn!("the back end's state did not arrive; starting at seq 0");
        }
        return Ok((0, 0));
    };
    if b.has_pose == 1 {
        let scale = (b.scale > 0.0).then_some(b.scale);
        tracker.restore(&Pose::from_row_major_3x4(&b.t_world_cam), scale);
    }
    tracing::info!("restored: continuing at seq {}", b.seq + 1);
    Ok((b.seq + 1, b.corrections))
}

/// Runs the tracking stage until SIGTERM.
pub fn run(args: &StageArgs) -> Result<()> {
    let cfg = args.load_config()?.pipeline;
    let seq = Sequence::open_with_camera(&args.seq, cfg.camera.as_deref())?;
    let mut tracker = Tracker::new(seq.calib, tracker_config(&cfg));
    let mut ctx = StageContext::new(StageKind::Tracking, args.worker, &cfg)?;
    let gap = Duration::from_millis(cfg.gap_timeout_ms);
    // the local mapping in the back end: lossless, the tracker waits for each keyframe's
    // triangulations and BA as it would for its own; in real time it triangulates itself,
    // goes on and applies each BA solution when it arrives
    let late_ba = match (cfg.local_ba_in_backend, cfg.mode) {
        (false, _) => None,
        (true, IngestMode::Lossless) => {
            tracker.set_mapping_solver(Box::new(RemoteMapping::open(&ctx, gap)?));
            None
        }
        (true, IngestMode::Realtime) => {
            let (sender, late) = RemoteMapping::open_deferred(&ctx)?;
            tracker.set_mapping_solver(Box::new(sender));
            Some(late)
        }
    };
    let features = ctx.slice_subscriber::<f32>(Topic::Features)?;
    let matches = ctx.slice_subscriber::<MatchEntry>(Topic::Matches)?;
    let backend = ctx.plain_subscriber::<BackendState>(Topic::Backend)?;
    let publisher = ctx
        .services
        .header_topic::<PoseMsg>(&ctx.node, Topic::Poses, false)?
        .publisher_builder()
        .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
        .create()
        .map_err(|e| MessageError::ipc("poses publisher", e))?;
    let views = crate::views::FrameViews::open(&ctx, cfg.top_k)?;
    let requests = ctx
        .services
        .header_topic::<MatchRequest>(&ctx.node, Topic::MatchRequests, false)?
        .publisher_builder()
        .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
        .create()
        .map_err(|e| MessageError::ipc("match requests publisher", e))?;

    let (start, applied) = restore(&backend, &mut tracker, &args.out, &cfg)?;
    let mut loops = LoopFeedback::open(&ctx, &cfg, applied)?;
    let mut feats: Inbox<Option<Features>> = Inbox::new(start, 1);
    let mut pairs: Inbox<Vec<MatchEntry>> = Inbox::new(start, 1);
    // the last frame tried without matches (and, when declined, asked for)
    let mut requested = None;
    ctx.started();
    while ctx.wait() {
        receive_features(&features, &mut feats)?;
        while let Some(s) = matches
            .receive()
            .map_err(|e| MessageError::ipc("matches", e))?
        {
            let h = *s.user_header();
            h.check()?;
            pairs.insert(h, s.payload().to_vec(), now_ns());
        }
        if let Some(l) = loops.as_mut() {
            l.receive(&mut tracker)?;
        }
        if let Some(late) = late_ba.as_ref() {
            late.apply(&mut tracker)?;
        }
        let _ = publisher.update_connections();
        let _ = requests.update_connections();
        loop {
            if loops.as_mut().is_some_and(LoopFeedback::holds_next_frame) {
                break;
            }
            let untried = |(fh, _, _): &&(FrameHeader, Option<Features>, u64)| {
                fh.status() == Status::Ok && requested != Some(fh.seq)
            };
            if let Some((fh, f, _)) = feats.peek().filter(untried) {
                let (fh, t_in) = (*fh, now_ns());
                if let Some(out) = f
                    .as_ref()
                    .and_then(|f| tracker.track_without_matches(frame_meta(&fh), f))
                {
                    // tracked by projection: the matching stage sends nothing for it
                    let view = f
                        .as_ref()
                        .filter(|_| views.listening())
                        .map(|f| FrameView::new(f, None));
                    feats.pop();
                    pairs.reset_to(fh.seq + 1);
                    let h = fh.forward(Status::Ok);
                    let (msg, closed) = report_frame(&mut loops, &h, &out, &tracker)?;
                    let h = publish(&publisher, h, msg)?;
                    publish_view(&views, &tracker, (h, msg), view, closed);
                    ctx.frame_done(&h, t_in, feats.len());
                    continue;
                }
                // matched after all: ask. When the tracker wants matches at once, this
                // process's decision on the previous frame told the matching stage so; only
                // the first frame after a (re)start, whose previous decision an earlier
                // process made, is asked for too (requests for frames the matching stage
                // matches anyway are ignored).
                if !tracker.wants_matches() || fh.seq == start {
                    let reference = tracker.reference().map_or(-1, |(r, _)| r as i64);
                    request(&requests, fh, reference)?;
                }
                requested = Some(fh.seq);
            }
            if !(feats.ready() && pairs.ready()) {
                let expired = feats.gap_expired(gap) || pairs.gap_expired(gap);
                if expired {
                    let seq = feats.next();
                    tracing::warn!("input of seq {seq} never arrived; reported lost");
                    feats.reset_to(seq + 1);
                    pairs.reset_to(seq + 1);
                    let msg = no_frame(&tracker);
                    let h = publish(&publisher, FrameHeader::new(seq, 0, 0.0, Status::Lost), msg)?;
                    ctx.frame_done(&h, now_ns(), feats.len());
                    continue;
                }
                break;
            }
            let (Some((fh, f, t_f)), Some((mh, m, t_m))) = (feats.pop(), pairs.pop()) else {
                break;
            };
            let _received = t_f.max(t_m);
            let t_in = now_ns();
            let h = match (fh.status(), mh.status(), f) {
                (Status::Ok, Status::Ok | Status::NoReference, Some(f)) => {
                    // matches count only against the reference the tracker actually holds
                    let current = tracker.reference().map(|(r, _)| r as i64);
                    let m =
                        (mh.status() == Status::Ok && current == Some(mh.reference)).then(|| {
                            Matches {
                                pairs: m.iter().map(|e| (e.a as usize, e.b as usize)).collect(),
                                scores: m.iter().map(|e| e.score).collect(),
                            }
                        });
                    let view = views.listening().then(|| {
                        FrameView::new(&f, tracker.reference().map(|r| r.1).zip(m.as_ref()))
                    });
                    let out = tracker.step(frame_meta(&fh), f, m.as_ref());
                    let mut h = fh.forward(Status::Ok);
                    h.t_ns[StageKind::Matching as usize] = mh.t_ns[StageKind::Matching as usize];
                    let (msg, closed) = report_frame(&mut loops, &h, &out, &tracker)?;
                    let h = publish(&publisher, h, msg)?;
                    publish_view(&views, &tracker, (h, msg), view, closed);
                    h
                }
                (st_f, st_m, _) => {
                    let st = if st_f != Status::Ok { st_f } else { st_m };
                    let mut h = fh.forward(st);
                    h.t_ns[StageKind::Matching as usize] = mh.t_ns[StageKind::Matching as usize];
                    let msg = no_frame(&tracker);
                    let h = publish(&publisher, h, msg)?;
                    let view = views.listening().then(FrameView::default);
                    publish_view(&views, &tracker, (h, msg), view, None);
                    h
                }
            };
            ctx.frame_done(&h, t_in, feats.len());
            if h.status() == Status::EndOfStream {
                write_lens(&args.out, &tracker)?;
                ctx.finished();
            }
        }
        ctx.heartbeat_if_idle();
    }
    Ok(())
}

/// The run's folder file with what the tracker read and learnt about the lens
/// ([`Tracker::lens_residual`]), for the run's report; none when it read nothing.
pub const LENS_FILE: &str = "lens.json";

/// Writes [`LENS_FILE`] at the end of the run.
fn write_lens(out: &std::path::Path, tracker: &Tracker) -> Result<()> {
    let Some(lens) = tracker.lens_residual() else {
        return Ok(());
    };
    let path = out.join(LENS_FILE);
    std::fs::write(&path, serde_json::to_string_pretty(&lens)?)
        .with_context(|| format!("writing {}", path.display()))
}

/// A tracked frame's pose message, after its features went to the back end when it became a
/// keyframe; with the loop the last correction closed, for the frame's view.
fn report_frame(
    loops: &mut Option<LoopFeedback>,
    h: &FrameHeader,
    out: &FrameOutput,
    tracker: &Tracker,
) -> Result<(PoseMsg, Option<(i64, i64)>)> {
    let Some(l) = loops.as_mut() else {
        return Ok((pose_msg(out, 0), None));
    };
    l.keyframe(h, out, tracker)?;
    Ok((pose_msg(out, l.applied), l.take_closed()))
}

/// Publishes a tracked frame's view (built when a viewer listened), with the map's points on
/// keyframes and the loop it closed.
fn publish_view(
    views: &crate::views::FrameViews,
    tracker: &Tracker,
    (h, pose): (FrameHeader, PoseMsg),
    view: Option<FrameView>,
    closed: Option<(i64, i64)>,
) {
    let Some(mut view) = view else {
        return;
    };
    if pose.keyframe == 1 {
        view.map_points = Some(tracker.map_points());
    }
    let (loop_query, loop_match) = closed.unwrap_or((-1, -1));
    let header = ViewHeader {
        frame: h,
        pose,
        loop_query,
        loop_match,
        ..Default::default()
    };
    views.publish(header, &view);
}

/// The message for a frame the tracker did not see (dropped, unreadable, lost, end).
fn no_frame(tracker: &Tracker) -> PoseMsg {
    PoseMsg {
        state: 3,
        reference: tracker.reference().map_or(-1, |(r, _)| r as i64),
        match_next: tracker.wants_matches() as u32,
        ..Default::default()
    }
}

fn frame_meta(h: &FrameHeader) -> FrameMeta {
    FrameMeta {
        index: h.seq as usize,
        stamp: h.stamp,
    }
}

type RequestPublisher = supermvo_messages::iceoryx2::port::publisher::Publisher<
    supermvo_messages::Ipc,
    MatchRequest,
    FrameHeader,
>;

/// Asks the matching stage for the matches of the frame of `h` to keyframe `reference`.
fn request(p: &RequestPublisher, h: FrameHeader, reference: i64) -> Result<()> {
    send_value(p, h, MatchRequest { reference }, "a match request")
}

type PosePublisher = supermvo_messages::iceoryx2::port::publisher::Publisher<
    supermvo_messages::Ipc,
    PoseMsg,
    FrameHeader,
>;

fn publish(p: &PosePublisher, mut h: FrameHeader, msg: PoseMsg) -> Result<FrameHeader> {
    stamp(&mut h, StageKind::Tracking);
    send_value(p, h, msg, "a pose")?;
    Ok(h)
}
