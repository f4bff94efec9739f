//! `frames.csv`, the back end's record of every frame: one line per frame as it arrives,
//! flushed at once, so a crash loses nothing. Two kinds of later lines give an earlier
//! frame's final pose: [`BACKFILLED`] (posed by the initialisation after it) and
//! [`LOOP_CORRECTED`] (moved by the loops closed, written at the end of the stream);
//! [`read_records`] folds them into the frames' records, [`read_lines`] keeps them apart.

use anyhow::{Context, Result};
use std::io::Write;
use std::path::{Path, PathBuf};
use supermvo_geometry::Pose;
use supermvo_messages::{BackendState, FrameHeader, PoseMsg, StageKind, Status};

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
    /// The camera's pose in the world when estimated (`pose` in `report.json`, 3x4
    /// row-major).
    #[serde(rename = "pose", serialize_with = "row_major_3x4")]
    pub t_world_cam: Option<Pose>,
    /// Map scale.
    pub scale: f64,
    /// Whether it became a keyframe.
    pub keyframe: bool,
    /// Capture → tracking result, ms.
    pub latency_ms: f64,
    /// Loop corrections the tracker had applied when it posed the frame
    /// ([`PoseMsg::corrections`]).
    pub corrections: u32,
}

/// A pose as KITTI's 3x4 row-major matrix, as the files and messages hold it.
fn row_major_3x4<S: serde::Serializer>(p: &Option<Pose>, s: S) -> Result<S::Ok, S::Error> {
    serde::Serialize::serialize(&p.map(|p| p.to_row_major_3x4()), s)
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
    "seq,frame,stamp,status,state,keyframe,scale,latency_ms,r00,r01,r02,tx,r10,r11,r12,ty,r20,r21,r22,tz,corrections";

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
        let matrix = self.t_world_cam.map(|p| p.to_row_major_3x4());
        for i in 0..12 {
            s.push(',');
            if let Some(m) = &matrix {
                s.push_str(&m[i].to_string());
            }
        }
        s.push_str(&format!(",{}", self.corrections));
        s
    }

    fn parse(line: &str) -> Option<Self> {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 21 {
            return None;
        }
        let t_world_cam = if f[8].is_empty() {
            None
        } else {
            let mut m = [0.0; 12];
            for (i, v) in m.iter_mut().enumerate() {
                *v = f[8 + i].parse().ok()?;
            }
            Some(Pose::from_row_major_3x4(&m))
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
            t_world_cam,
            corrections: f[20].parse().ok()?,
        })
    }
}

/// Status of a `frames.csv` line that gives an earlier frame's pose (`seq`), known only once
/// a later frame's initialisation built the map it is posed on.
pub const BACKFILLED: &str = "backfilled";

/// Status of a `frames.csv` line that gives an earlier frame's pose moved by the loops the
/// back end closed (written for every posed frame at the end of the stream, when loops were
/// closed).
pub const LOOP_CORRECTED: &str = "loop_corrected";

/// Whether a line gives an earlier frame's pose rather than a frame's own record.
pub fn is_late_pose(r: &Record) -> bool {
    r.status == BACKFILLED || r.status == LOOP_CORRECTED
}

/// Whether `out/frames.csv` holds at least one frame: a stage starting then
/// joins a run in progress (the supervisor removes the file when a run starts).
pub fn has_records(out: &Path) -> bool {
    std::fs::metadata(out.join("frames.csv")).is_ok_and(|m| m.len() > CSV_HEADER.len() as u64 + 1)
}

/// Every line of `frames.csv` in the order written, late poses included, skipping a torn
/// last line; empty when the file does not exist.
pub fn read_lines(path: &Path) -> Result<Vec<Record>> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
    };
    Ok(text.lines().skip(1).filter_map(Record::parse).collect())
}

/// Reads `frames.csv` (the back end's record), skipping a torn last line: one record per
/// frame, with the poses that [`BACKFILLED`] lines gave later in their frames' records, and
/// the [`LOOP_CORRECTED`] poses in place of the recorded ones.
pub fn read_records(path: &Path) -> Result<Vec<Record>> {
    let (late, mut records): (Vec<Record>, Vec<Record>) =
        read_lines(path)?.into_iter().partition(is_late_pose);
    let pose_of = |status: &str| -> std::collections::HashMap<u64, Pose> {
        late.iter()
            .filter(|r| r.status == status)
            .filter_map(|r| r.t_world_cam.map(|p| (r.seq, p)))
            .collect()
    };
    let (backfilled, corrected) = (pose_of(BACKFILLED), pose_of(LOOP_CORRECTED));
    for r in records.iter_mut() {
        if r.t_world_cam.is_none() {
            r.t_world_cam = backfilled.get(&r.seq).copied();
        }
        if r.t_world_cam.is_some() {
            r.t_world_cam = corrected.get(&r.seq).copied().or(r.t_world_cam);
        }
    }
    Ok(records)
}

/// The record on disk; in memory only what a restarted tracker needs (memory stays flat
/// however long the run).
#[derive(Debug)]
pub struct Recorder {
    /// `frames.csv`.
    pub path: PathBuf,
    file: std::fs::File,
    /// Frames recorded.
    pub count: usize,
    /// The last frame recorded.
    pub last: Option<Record>,
    /// The last pose recorded: `T_world_cam`, map scale, corrections applied.
    last_pose: Option<(Pose, f64, u32)>,
}

impl Recorder {
    /// Opens (or starts) `out/frames.csv`, continuing after its last complete line.
    pub fn open(out: &Path) -> Result<Self> {
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
            .find_map(|r| r.t_world_cam.map(|p| (p, r.scale, r.corrections)));
        Ok(Self {
            path,
            file,
            count: records.len(),
            last: records.last().cloned(),
            last_pose,
        })
    }

    /// Records one frame.
    pub fn add(&mut self, r: Record) -> Result<()> {
        self.write_line(&r)?;
        if let Some(p) = r.t_world_cam {
            self.last_pose = Some((p, r.scale, r.corrections));
        }
        self.count += 1;
        self.last = Some(r);
        Ok(())
    }

    /// Records the pose of earlier frame `seq` (a [`BACKFILLED`] line): the frame keeps its
    /// own record, so neither the count nor the last record changes.
    pub fn backfill(&mut self, seq: u64, t_world_cam: Pose, scale: f64) -> Result<()> {
        self.write_line(&Self::late_pose(seq, BACKFILLED, t_world_cam, scale))
    }

    /// Records the loop-corrected pose of earlier frame `seq` (a [`LOOP_CORRECTED`] line).
    pub fn correct(&mut self, seq: u64, t_world_cam: Pose) -> Result<()> {
        self.write_line(&Self::late_pose(seq, LOOP_CORRECTED, t_world_cam, 0.0))
    }

    fn late_pose(seq: u64, status: &str, t_world_cam: Pose, scale: f64) -> Record {
        Record {
            seq,
            frame: 0,
            stamp: 0.0,
            status: status.to_string(),
            state: 1,
            t_world_cam: Some(t_world_cam),
            scale,
            keyframe: false,
            latency_ms: 0.0,
            corrections: 0,
        }
    }

    fn write_line(&mut self, r: &Record) -> Result<()> {
        writeln!(self.file, "{}", r.csv())
            .and_then(|_| self.file.flush())
            .with_context(|| format!("writing {}", self.path.display()))
    }

    /// The loop corrections the tracker had applied when it posed the last pose recorded.
    pub fn last_pose_corrections(&self) -> u32 {
        self.last_pose.map_or(0, |p| p.2)
    }

    /// What a restarted tracker continues from (the last pose as recorded).
    pub fn state(&self, finished: bool) -> BackendState {
        let last = self.last.as_ref();
        BackendState {
            seq: last.map_or(0, |r| r.seq),
            frame: last.map_or(0, |r| r.frame),
            has_pose: self.last_pose.is_some() as u32,
            corrections: 0,
            t_world_cam: self.last_pose.map_or([0.0; 12], |p| p.0.to_row_major_3x4()),
            scale: self.last_pose.map_or(0.0, |p| p.1),
            recorded: self.count as u64,
            state: last.map_or(0, |r| r.state),
            finished: finished as u32,
        }
    }
}

/// The record of a frame's pose message.
pub fn record(h: &FrameHeader, p: &PoseMsg) -> Record {
    let t_track = h.t_ns[StageKind::Tracking as usize];
    Record {
        seq: h.seq,
        frame: h.frame,
        stamp: h.stamp,
        status: status_name(h.status()).to_string(),
        state: p.state,
        t_world_cam: (p.has_pose == 1).then(|| Pose::from_row_major_3x4(&p.t_world_cam)),
        scale: p.scale,
        keyframe: p.keyframe == 1,
        latency_ms: if h.t_ns[0] > 0 && t_track >= h.t_ns[0] {
            (t_track - h.t_ns[0]) as f64 * 1e-6
        } else {
            0.0
        },
        corrections: p.corrections,
    }
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
            t_world_cam: Some(Pose::from_row_major_3x4(&[
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
            ])),
            scale: 12.345_678_9,
            keyframe: true,
            latency_ms: 150.25,
            corrections: 2,
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
        let frame = |seq: u64, t_world_cam: Option<Pose>| Record {
            seq,
            frame: seq,
            stamp: seq as f64 * 0.1,
            status: "ok".into(),
            state: if t_world_cam.is_some() { 1 } else { 0 },
            t_world_cam,
            scale: 0.0,
            keyframe: t_world_cam.is_some(),
            latency_ms: 1.0,
            corrections: 0,
        };
        let pose = |x: f64| Pose::new(supermvo_geometry::Mat3::identity(), [x, 0.0, 0.0].into());
        rec.add(frame(0, Some(pose(0.0)))).unwrap();
        rec.add(frame(1, None)).unwrap();
        rec.add(frame(2, None)).unwrap();
        rec.add(frame(3, Some(pose(3.0)))).unwrap();
        rec.backfill(1, pose(1.0), 5.0).unwrap();
        rec.backfill(2, pose(2.0), 5.0).unwrap();
        let records = read_records(&rec.path).unwrap();
        let poses: Vec<Option<f64>> = records
            .iter()
            .map(|r| r.t_world_cam.map(|p| p.t.x))
            .collect();
        assert_eq!(poses, [Some(0.0), Some(1.0), Some(2.0), Some(3.0)]);
        assert_eq!(
            records[1],
            Record {
                t_world_cam: Some(pose(1.0)),
                ..frame(1, None)
            }
        );
        // loop-corrected poses replace the recorded ones, leaving the count alone
        rec.correct(3, pose(30.0)).unwrap();
        rec.correct(1, pose(10.0)).unwrap();
        let records = read_records(&rec.path).unwrap();
        let poses: Vec<Option<f64>> = records
            .iter()
            .map(|r| r.t_world_cam.map(|p| p.t.x))
            .collect();
        assert_eq!(poses, [Some(0.0), Some(10.0), Some(2.0), Some(30.0)]);
        assert_eq!(read_lines(&rec.path).unwrap().len(), 8);
        drop(rec);
        let reopened = Recorder::open(dir.path()).unwrap();
        assert_eq!(reopened.count, 4);
        assert_eq!(reopened.last.as_ref().map(|r| r.seq), Some(3));
    }
}
