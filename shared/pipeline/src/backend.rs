//! Back end: records every frame's outcome as it arrives (one line per frame in
//! `frames.csv`, flushed at once, so a crash loses nothing; a frame posed later, by the
//! initialisation after it, gets a second, `backfilled` line then), publishes what it has recorded
//! for a restarted tracker, and writes the trajectory at the end of the stream or on SIGTERM.
//!
//! A restarted back end reads `frames.csv` back and continues after its last line.
//! Loop closure and the pose graph run in the tracking process today, beside the tracker, so
//! that their corrections reach it before the next frame (see `tracking.rs`); moving them and
//! local mapping here is issue 21's work.

use crate::common::{StageArgs, StageContext};
use crate::inbox::Inbox;
use anyhow::{Context, Result};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;
use supermvo_dataset::{hold_last_pose, write_trajectory, Trajectory, TrajectoryFormat};
use supermvo_geometry::Pose;
use supermvo_messages::{
    now_ns, BackendState, FrameHeader, MessageError, PoseMsg, StageKind, Status, Topic,
};

/// One recorded frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Record {
    /// Sequence number.
    pub seq: u64,
    /// Frame index.
    pub frame: u64,
    /// Timestamp, s.
    pub stamp: f64,
    /// What became of the frame.
    pub status: String,
    /// Tracker state code (see [`PoseMsg::state`]).
    pub state: u32,
    /// `T_world_cam` when estimated.
    pub pose: Option<[f64; 12]>,
    /// Map scale.
    pub scale: f64,
    /// Whether it became a keyframe.
    pub keyframe: bool,
    /// Capture → tracking result, ms.
    pub latency_ms: f64,
}

/// Name of a status in `frames.csv`.
pub fn status_name(s: Status) -> &'static str {
    match s {
        Status::Ok => "ok",
        Status::Dropped => "dropped",
        Status::Unreadable => "unreadable",
        Status::Lost => "lost",
        Status::EndOfStream => "end",
        Status::NoReference => "no_reference",
    }
}

const CSV_HEADER: &str =
    "seq,frame,stamp,status,state,keyframe,scale,latency_ms,r00,r01,r02,tx,r10,r11,r12,ty,r20,r21,r22,tz";

impl Record {
    fn csv(&self) -> String {
        let mut s = format!(
            "{},{},{},{},{},{},{},{}",
            self.seq,
            self.frame,
            self.stamp,
            self.status,
            self.state,
            self.keyframe as u8,
            self.scale,
            self.latency_ms
        );
        for i in 0..12 {
            s.push(',');
            if let Some(p) = &self.pose {
                s.push_str(&p[i].to_string());
            }
        }
        s
    }

    fn parse(line: &str) -> Option<Self> {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 20 {
            return None;
        }
        let pose = if f[8].is_empty() {
            None
        } else {
            let mut p = [0.0; 12];
            for (i, v) in p.iter_mut().enumerate() {
                *v = f[8 + i].parse().ok()?;
            }
            Some(p)
        };
        Some(Self {
            seq: f[0].parse().ok()?,
            frame: f[1].parse().ok()?,
            stamp: f[2].parse().ok()?,
            status: f[3].to_string(),
            state: f[4].parse().ok()?,
            keyframe: f[5] == "1",
            scale: f[6].parse().ok()?,
            latency_ms: f[7].parse().ok()?,
            pose,
        })
    }
}

/// Status of a `frames.csv` line that gives an earlier frame's pose (`seq`), known only once
/// a later frame's initialisation built the map it is posed on.
pub const BACKFILLED: &str = "backfilled";

/// Reads `frames.csv` (the back end's record), skipping a torn last line: one record per
/// frame, with the poses that [`BACKFILLED`] lines gave later in their frames' records.
pub fn read_records(path: &Path) -> Result<Vec<Record>> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
    };
    let (late, mut records): (Vec<Record>, Vec<Record>) = text
        .lines()
        .skip(1)
        .filter_map(Record::parse)
        .partition(|r| r.status == BACKFILLED);
    let late: std::collections::HashMap<u64, [f64; 12]> = late
        .into_iter()
        .filter_map(|r| r.pose.map(|p| (r.seq, p)))
        .collect();
    for r in records.iter_mut().filter(|r| r.pose.is_none()) {
        r.pose = late.get(&r.seq).copied();
    }
    Ok(records)
}

/// The records with the loop-corrected poses the tracking stage wrote to `out` (when it
/// closed loops) in place of the recorded ones.
pub fn with_corrections(out: &Path, records: &[Record]) -> Vec<Record> {
    let corrected = crate::tracking::read_corrected(&out.join(crate::tracking::CORRECTED_FILE));
    records
        .iter()
        .map(|r| match (r.pose, corrected.get(&r.seq)) {
            (Some(_), Some(p)) => Record {
                pose: Some(*p),
                ..r.clone()
            },
            _ => r.clone(),
        })
        .collect()
}

/// Writes the trajectory of the records (loop-corrected where the tracking stage closed
/// loops): see [`write_trajectories`].
pub fn write_outputs(out: &Path, records: &[Record]) -> Result<Vec<usize>> {
    let frames: Vec<(f64, Option<Pose>)> = with_corrections(out, records)
        .iter()
        .filter(|r| r.status != "end")
        .map(|r| (r.stamp, r.pose.as_ref().map(Pose::from_row_major_3x4)))
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

/// The record on disk; in memory only what a restarted tracker needs (memory stays flat
/// however long the run).
struct Recorder {
    path: PathBuf,
    file: std::fs::File,
    count: usize,
    last: Option<Record>,
    last_pose: Option<([f64; 12], f64)>,
}

impl Recorder {
    fn open(out: &Path) -> Result<Self> {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let path = out.join("frames.csv");
        let records = read_records(&path)?;
        let mut file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .with_context(|| format!("opening {}", path.display()))?;
        if records.is_empty() {
            // a fresh file (or one torn before its first record): start it over
            file.set_len(0)?;
            writeln!(file, "{CSV_HEADER}")?;
        }
        let last_pose = records
            .iter()
            .rev()
            .find_map(|r| r.pose.map(|p| (p, r.scale)));
        Ok(Self {
            path,
            file,
            count: records.len(),
            last: records.last().cloned(),
            last_pose,
        })
    }

    fn add(&mut self, r: Record) -> Result<()> {
        writeln!(self.file, "{}", r.csv())
            .and_then(|_| self.file.flush())
            .with_context(|| format!("writing {}", self.path.display()))?;
        if let Some(p) = r.pose {
            self.last_pose = Some((p, r.scale));
        }
        self.count += 1;
        self.last = Some(r);
        Ok(())
    }

    /// Records the pose of earlier frame `seq` (a [`BACKFILLED`] line): the frame keeps its
    /// own record, so neither the count nor the last record changes.
    fn backfill(&mut self, seq: u64, pose: [f64; 12], scale: f64) -> Result<()> {
        let line = Record {
            seq,
            frame: 0,
            stamp: 0.0,
            status: BACKFILLED.to_string(),
            state: 1,
            pose: Some(pose),
            scale,
            keyframe: false,
            latency_ms: 0.0,
        };
        writeln!(self.file, "{}", line.csv())
            .and_then(|_| self.file.flush())
            .with_context(|| format!("writing {}", self.path.display()))
    }

    fn state(&self, finished: bool) -> BackendState {
        let last = self.last.as_ref();
        BackendState {
            seq: last.map_or(0, |r| r.seq),
            frame: last.map_or(0, |r| r.frame),
            has_pose: self.last_pose.is_some() as u32,
            t_world_cam: self.last_pose.map(|p| p.0).unwrap_or_default(),
            scale: self.last_pose.map_or(0.0, |p| p.1),
            recorded: self.count as u64,
            state: last.map_or(0, |r| r.state),
            finished: finished as u32,
        }
    }
}

fn record(h: &FrameHeader, p: &PoseMsg) -> Record {
    let t_track = h.t_ns[StageKind::Tracking as usize];
    Record {
        seq: h.seq,
        frame: h.frame,
        stamp: h.stamp,
        status: status_name(h.status()).to_string(),
        state: p.state,
        pose: (p.has_pose == 1).then_some(p.t_world_cam),
        scale: p.scale,
        keyframe: p.keyframe == 1,
        latency_ms: if h.t_ns[0] > 0 && t_track >= h.t_ns[0] {
            (t_track - h.t_ns[0]) as f64 * 1e-6
        } else {
            0.0
        },
    }
}

/// Runs the back end until the end of the stream has been recorded and SIGTERM arrives.
pub fn run(args: &StageArgs) -> Result<()> {
    let cfg = args.load_config()?.pipeline;
    let mut rec = Recorder::open(&args.out)?;
    let mut ctx = StageContext::new(StageKind::Backend, args.worker, &cfg)?;
    let poses = ctx.header_subscriber::<PoseMsg>(Topic::Poses)?;
    let state = ctx
        .services
        .plain_topic::<BackendState>(&ctx.node, Topic::Backend, false)?
        .publisher_builder()
        .create()
        .map_err(|e| MessageError::ipc("backend publisher", e))?;
    let mut finished = rec.last.as_ref().is_some_and(|r| r.status == "end");
    let start = rec.last.as_ref().map_or(0, |r| r.seq + 1);
    let mut inbox: Inbox<PoseMsg> = Inbox::new(start, 1);
    let gap = Duration::from_millis(cfg.gap_timeout_ms);
    if rec.count > 0 {
        state
            .send_copy(rec.state(finished))
            .map_err(|e| MessageError::ipc("backend state", e))?;
    }
    ctx.started();
    while ctx.wait() {
        while let Some(s) = poses.receive().map_err(|e| MessageError::ipc("poses", e))? {
            let h = *s.user_header();
            h.check()?;
            inbox.insert(h, *s.payload(), now_ns());
        }
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
            let Some((h, p, _received)) = inbox.pop() else {
                break;
            };
            let t_in = now_ns();
            if finished {
                continue;
            }
            rec.add(record(&h, &p))?;
            for b in p.backfilled_poses() {
                rec.backfill(b.seq, b.t_world_cam, p.scale)?;
            }
            changed = true;
            ctx.frame_done(&h, t_in, inbox.len());
            if h.status() == Status::EndOfStream {
                write_outputs(&args.out, &read_records(&rec.path)?)?;
                finished = true;
                ctx.finished();
            }
        }
        if changed {
            state
                .send_copy(rec.state(finished))
                .map_err(|e| MessageError::ipc("backend state", e))?;
        }
        ctx.heartbeat_if_idle();
    }
    // SIGINT/SIGTERM: whatever was recorded becomes the trajectory
    write_outputs(&args.out, &read_records(&rec.path)?)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_exactly_and_torn_lines_are_skipped() {
        let dir = tempfile::tempdir().unwrap();
        let r = Record {
            seq: 3,
            frame: 3,
            stamp: 0.310_344_1,
            status: "ok".into(),
            state: 1,
            pose: Some([
                0.1 + 0.2,
                -1e-17,
                3.0,
                1.0 / 3.0,
                0.0,
                1.0,
                0.0,
                2.5,
                0.0,
                0.0,
                1.0,
                -7.25,
            ]),
            scale: 12.345_678_9,
            keyframe: true,
            latency_ms: 150.25,
        };
        let path = dir.path().join("frames.csv");
        std::fs::write(&path, format!("{CSV_HEADER}\n{}\n3,3,0.", r.csv())).unwrap();
        assert_eq!(read_records(&path).unwrap(), vec![r]);
    }

    /// A frame posed later (a `backfilled` line after its own) reads back as one record with
    /// that pose; the count and the last record are the frames', as a restarted back end
    /// needs them.
    #[test]
    fn backfilled_poses_join_their_frames_records() {
        let dir = tempfile::tempdir().unwrap();
        let mut rec = Recorder::open(dir.path()).unwrap();
        let frame = |seq: u64, pose: Option<[f64; 12]>| Record {
            seq,
            frame: seq,
            stamp: seq as f64 * 0.1,
            status: "ok".into(),
            state: if pose.is_some() { 1 } else { 0 },
            pose,
            scale: 0.0,
            keyframe: pose.is_some(),
            latency_ms: 1.0,
        };
        let pose = |x: f64| [1.0, 0.0, 0.0, x, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        rec.add(frame(0, Some(pose(0.0)))).unwrap();
        rec.add(frame(1, None)).unwrap();
        rec.add(frame(2, None)).unwrap();
        rec.add(frame(3, Some(pose(3.0)))).unwrap();
        rec.backfill(1, pose(1.0), 5.0).unwrap();
        rec.backfill(2, pose(2.0), 5.0).unwrap();
        let records = read_records(&rec.path).unwrap();
        let poses: Vec<Option<f64>> = records.iter().map(|r| r.pose.map(|p| p[3])).collect();
        assert_eq!(poses, [Some(0.0), Some(1.0), Some(2.0), Some(3.0)]);
        assert_eq!(
            records[1],
            Record {
                pose: Some(pose(1.0)),
                ..frame(1, None)
            }
        );
        drop(rec);
        let reopened = Recorder::open(dir.path()).unwrap();
        assert_eq!(reopened.count, 4);
        assert_eq!(reopened.last.as_ref().map(|r| r.seq), Some(3));
    }
}
