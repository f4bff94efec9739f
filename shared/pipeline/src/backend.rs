//! Back end: records every frame's outcome as it arrives (`frames.csv`, see
//! [`crate::frame_log`]), closes loops over the keyframes tracking sends and answers each
//! keyframe with its verdict (see [`crate::loop_closing`]), publishes what it has recorded
//! for a restarted tracker, and writes the trajectory (loop-corrected) at the end of the
//! stream or on SIGTERM.
//!
//! A restarted back end reads `frames.csv` and `keyframes.bin` back, rebuilds the loop
//! closer from them and continues after the last line. Local mapping (triangulation and
//! bundle adjustment over the covisible keyframes) still runs in the tracking process.

use crate::common::{send_value, StageArgs, StageContext};
use crate::frame_log::{read_lines, record, Recorder};
use crate::inbox::Inbox;
use crate::loop_closing::{LoopClosing, PosedFrame};
use crate::remote_mapping::MappingServer;
use anyhow::{Context, Result};
use std::path::Path;
use std::time::Duration;
use supermvo_dataset::{hold_last_pose, write_trajectory, Sequence, Trajectory, TrajectoryFormat};
use supermvo_geometry::Pose;
use supermvo_inference::Features;
use supermvo_messages::iceoryx2::port::update_connections::UpdateConnections;
use supermvo_messages::iceoryx2::prelude::*;
use supermvo_messages::{
    now_ns, BackendState, CorrectionMsg, FeatureLayout, FrameHeader, MessageError, PoseMsg,
    StageKind, Status, Topic,
};

pub use crate::frame_log::{read_records, status_name, Record, BACKFILLED, LOOP_CORRECTED};

/// Writes the trajectory of the records (`read_records`: loop-corrected where loops were
/// closed): see [`write_trajectories`].
pub fn write_outputs(out: &Path, records: &[Record]) -> Result<Vec<usize>> {
    let frames: Vec<(f64, Option<Pose>)> = records
        .iter()
        .filter(|r| r.status != "end")
        .map(|r| (r.stamp, r.t_world_cam))
        .collect();
    write_trajectories(out, &frames)
}

/// Writes a run's trajectory for every frame `(stamp, pose if posed)` in order:
/// `trajectory.tum.txt` with the posed frames and their stamps, and `trajectory.kitti.txt`
/// with one row per frame, unposed frames holding the last pose
/// ([`supermvo_dataset::hold_last_pose`]); returns the unposed frames' positions. With no
/// pose at all neither file is left behind (an older run's files in the same folder are
/// removed).
pub fn write_trajectories(out: &Path, frames: &[(f64, Option<Pose>)]) -> Result<Vec<usize>> {
    let (tum, kitti) = (
        out.join("trajectory.tum.txt"),
        out.join("trajectory.kitti.txt"),
    );
    let poses: Vec<Option<Pose>> = frames.iter().map(|f| f.1).collect();
    let Some((rows, unposed)) = hold_last_pose(&poses) else {
        for f in [&tum, &kitti] {
            match std::fs::remove_file(f) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                    return Err(e).with_context(|| format!("removing {}", f.display()))
                }
                _ => {}
            }
        }
        return Ok((0..frames.len()).collect());
    };
    let posed: Vec<(f64, Pose)> = frames
        .iter()
        .filter_map(|(t, p)| p.map(|p| (*t, p)))
        .collect();
    let traj = Trajectory {
        stamps: Some(posed.iter().map(|e| e.0).collect()),
        poses: posed.iter().map(|e| e.1).collect(),
        quaternions: None,
    };
    write_trajectory(&tum, TrajectoryFormat::Tum, &traj)?;
    let all = Trajectory {
        stamps: None,
        poses: rows,
        quaternions: None,
    };
    write_trajectory(&kitti, TrajectoryFormat::Kitti, &all)?;
    Ok(unposed)
}

/// The end of the run: the loop-corrected poses into `frames.csv` and `loops.json` (when
/// loops were closed), then the trajectory files.
fn finish(out: &Path, rec: &mut Recorder, loops: Option<&LoopClosing>) -> Result<()> {
    if let Some(l) = loops.filter(|l| !l.loops().is_empty()) {
        for (seq, p) in l.corrected(&read_lines(&rec.path)?) {
            rec.correct(seq, p)?;
        }
        let path = out.join("loops.json");
        std::fs::write(&path, serde_json::to_string_pretty(&l.loops())?)
            .with_context(|| format!("writing {}", path.display()))?;
        tracing::info!(loops = l.loops().len(), "loop-corrected trajectory written");
    }
    write_outputs(out, &read_records(&rec.path)?)?;
    Ok(())
}

/// Runs the back end until the end of the stream has been recorded and SIGTERM arrives.
pub fn run(args: &StageArgs) -> Result<()> {
    let cfg = args.load_config()?.pipeline;
    let mut rec = Recorder::open(&args.out)?;
    let mut loops = match cfg.loop_closure {
        true => {
            let calib = Sequence::open_with_camera(&args.seq, cfg.camera.as_deref())?.calib;
            Some(LoopClosing::open(
                &args.out,
                calib,
                crate::loop_closing::loop_config(&cfg),
                &read_lines(&rec.path)?,
            )?)
        }
        false => None,
    };
    let mut ctx = StageContext::new(StageKind::Backend, args.worker, &cfg)?;
    let poses = ctx.header_subscriber::<PoseMsg>(Topic::Poses)?;
    let keyframes = ctx.slice_subscriber::<f32>(Topic::Keyframes)?;
    let state = ctx
        .services
        .plain_topic::<BackendState>(&ctx.node, Topic::Backend, false)?
        .publisher_builder()
        .create()
        .map_err(|e| MessageError::ipc("backend publisher", e))?;
    let verdicts = ctx
        .services
        .header_topic::<CorrectionMsg>(&ctx.node, Topic::Corrections, false)?
        .publisher_builder()
        .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
        .create()
        .map_err(|e| MessageError::ipc("corrections publisher", e))?;
    let mut local_mapping = MappingServer::open(&ctx, &args.out)?;
    let mut finished = rec.last.as_ref().is_some_and(|r| r.status == "end");
    let start = rec.last.as_ref().map_or(0, |r| r.seq + 1);
    let mut inbox: Inbox<PoseMsg> = Inbox::new(start, 1);
    // keyframe features by seq, until their pose arrives
    let mut keyframe_features: std::collections::HashMap<u64, Features> = Default::default();
    let gap = Duration::from_millis(cfg.gap_timeout_ms);
    let state_now = |rec: &Recorder, loops: Option<&LoopClosing>, finished: bool| {
        let mut s = rec.state(finished);
        if let Some(l) = loops {
            l.restore_state(&mut s, rec.last_pose_corrections());
        }
        s
    };
    let _ = verdicts.update_connections();
    if rec.count > 0 {
        state
            .send_copy(state_now(&rec, loops.as_ref(), finished))
            .map_err(|e| MessageError::ipc("backend state", e))?;
        // a tracker may be waiting for the verdict this back end's predecessor owed it
        if let Some((h, v)) = loops.as_ref().and_then(LoopClosing::last_verdict) {
            send_value(&verdicts, h, v, "a correction")?;
        }
    }
    ctx.started();
    let mut waited_since: Option<std::time::Instant> = None;
    while ctx.wait() {
        // first what the tracker waits for
        local_mapping.serve()?;
        while let Some(s) = poses.receive().map_err(|e| MessageError::ipc("poses", e))? {
            let h = *s.user_header();
            h.check()?;
            inbox.insert(h, *s.payload(), now_ns());
        }
        while let Some(s) = keyframes
            .receive()
            .map_err(|e| MessageError::ipc("keyframes", e))?
        {
            let h = *s.user_header();
            h.check()?;
            if h.seq >= inbox.next() {
                keyframe_features.insert(h.seq, FeatureLayout::read(&h, s.payload())?);
            }
        }
        // a restarted tracker's subscribers get the state and the verdicts in the history
        let _ = state.update_connections();
        let _ = verdicts.update_connections();
        let mut changed = false;
        loop {
            if !inbox.ready() {
                if !finished && inbox.gap_expired(gap) {
                    let seq = inbox.skip();
                    tracing::warn!("pose of seq {seq} never arrived; recorded lost");
                    let h = FrameHeader::new(seq, 0, 0.0, Status::Lost);
                    rec.add(record(&h, &PoseMsg::default()))?;
                    ctx.frame_done(&h, now_ns(), inbox.len());
                    changed = true;
                    continue;
                }
                break;
            }
            // a keyframe waits for its features (sent before its pose) for up to the gap
            if let Some((h, p, _)) = inbox.peek() {
                let needs = loops.is_some() && p.keyframe == 1 && p.has_pose == 1;
                if needs && !finished && !keyframe_features.contains_key(&h.seq) {
                    let since = *waited_since.get_or_insert_with(std::time::Instant::now);
                    if since.elapsed() < gap {
                        break;
                    }
                }
            }
            waited_since = None;
            let Some((h, p, _received)) = inbox.pop() else {
                break;
            };
            let t_in = now_ns();
            if finished {
                continue;
            }
            let features = keyframe_features.remove(&h.seq);
            if let (Some(l), Some(f)) = (loops.as_mut(), features.as_ref()) {
                l.log_keyframe(h.seq, f)?;
            }
            rec.add(record(&h, &p))?;
            let backfilled: Vec<(u64, Pose)> = p
                .backfilled_poses()
                .iter()
                .map(|b| (b.seq, Pose::from_row_major_3x4(&b.t_world_cam)))
                .collect();
            for &(seq, t_world_cam) in &backfilled {
                rec.backfill(seq, t_world_cam, p.scale)?;
            }
            if let Some(l) = loops.as_mut() {
                let frame = PosedFrame {
                    seq: h.seq,
                    t_world_cam: (p.has_pose == 1)
                        .then(|| Pose::from_row_major_3x4(&p.t_world_cam)),
                    keyframe: p.keyframe == 1,
                    lost: p.state == PoseMsg::LOST,
                    corrections: p.corrections,
                    backfilled: &backfilled,
                };
                if let Some(v) = l.add(frame, features.as_ref()) {
                    send_value(&verdicts, h.forward(Status::Ok), v, "a correction")?;
                }
            }
            changed = true;
            ctx.frame_done(&h, t_in, inbox.len());
            local_mapping.serve()?;
            if h.status() == Status::EndOfStream {
                finish(&args.out, &mut rec, loops.as_ref())?;
                finished = true;
                ctx.finished();
            }
        }
        keyframe_features.retain(|seq, _| *seq >= inbox.next());
        if changed {
            state
                .send_copy(state_now(&rec, loops.as_ref(), finished))
                .map_err(|e| MessageError::ipc("backend state", e))?;
        }
        ctx.heartbeat_if_idle();
    }
    // SIGINT/SIGTERM: whatever was recorded becomes the trajectory
    if finished {
        write_outputs(&args.out, &read_records(&rec.path)?)?;
    } else {
        finish(&args.out, &mut rec, loops.as_ref())?;
    }
    Ok(())
}
