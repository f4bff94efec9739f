//! Loop closing in the back-end process: the loop closer over the poses tracking reports
//! (`poses`) and the features of its keyframes (`keyframes`), with its verdict on every
//! keyframe sent back (`corrections`), and what a restarted back end rebuilds it from: the
//! keyframes' features in `keyframes.bin` beside `frames.csv`, replayed in the recorded order
//! (the loop closer is a deterministic function of what it was fed).
//!
//! A pose says how many corrections the tracker had applied when it was estimated
//! (`PoseMsg::corrections`): in lossless mode always all of them (tracking waits for each
//! keyframe's verdict), in real-time mode possibly fewer, which the loop closer accounts for.

use crate::frame_log::{is_late_pose, Record, BACKFILLED};
use anyhow::{Context, Result};
use std::collections::HashMap;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use supermvo_config::PipelineConfig;
use supermvo_dataset::Calibration;
use supermvo_geometry::Pose;
use supermvo_inference::Features;
use supermvo_messages::{BackendState, CorrectionMsg, FeatureLayout, FrameHeader, PoseMsg, Status};
use supermvo_vo::loops::{Correction, LoopCloser, LoopConfig, LoopEdge, ReportedPose};

/// Name of the keyframe log in the output folder.
pub const KEYFRAMES_FILE: &str = "keyframes.bin";

/// One frame as the loop closer takes it: its own pose and the earlier frames it posed.
#[derive(Debug, Clone, Copy)]
pub struct PosedFrame<'a> {
    /// Sequence number.
    pub seq: u64,
    /// The camera's pose in the world, when estimated.
    pub t_world_cam: Option<Pose>,
    /// Whether it became a keyframe.
    pub keyframe: bool,
    /// Whether tracking failed on it (state `Lost`).
    pub lost: bool,
    /// Corrections the tracker had applied when it estimated the poses.
    pub corrections: u32,
    /// Earlier frames it posed: `(seq, T_world_cam)`.
    pub backfilled: &'a [(u64, Pose)],
}

/// The back end's loop closing (see module docs).
pub struct LoopClosing {
    closer: LoopCloser,
    log: KeyframeLog,
    /// The verdict on the last keyframe, sent again after a restart (the tracker may be
    /// waiting for it).
    last_verdict: Option<(u64, CorrectionMsg)>,
    /// Keyframes rebuilt from the log when this back end started.
    restored_keyframes: usize,
}

/// The loop-closing configuration the daemon and `supermvo run --mode inprocess` both use:
/// keyframes' strongest `pipeline.matcher_top_k` keypoints when that is set.
pub fn loop_config(cfg: &PipelineConfig) -> LoopConfig {
    LoopConfig {
        keypoints: cfg.matcher_keypoints(),
        ..LoopConfig::default()
    }
}

impl std::fmt::Debug for LoopClosing {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "LoopClosing({:?})", self.closer)
    }
}

impl LoopClosing {
    /// Loop closing with `cfg` for a camera with calibration `calib`, rebuilt from what an
    /// earlier back end recorded in `out` (`lines`: `frames.csv` in the order written).
    pub fn open(out: &Path, calib: Calibration, cfg: LoopConfig, lines: &[Record]) -> Result<Self> {
        let path = out.join(KEYFRAMES_FILE);
        let mut features = if lines.is_empty() {
            HashMap::new()
        } else {
            KeyframeLog::read(&path)?
        };
        let mut me = Self {
            closer: LoopCloser::new(calib, cfg),
            log: KeyframeLog::open(&path, lines.is_empty())?,
            last_verdict: None,
            restored_keyframes: 0,
        };
        for (r, backfilled) in frames_with_backfills(lines) {
            let frame = PosedFrame {
                seq: r.seq,
                t_world_cam: r.t_world_cam,
                keyframe: r.keyframe,
                lost: r.state == PoseMsg::LOST,
                corrections: r.corrections,
                backfilled: &backfilled,
            };
            let f = features.remove(&r.seq);
            me.restored_keyframes += f.is_some() as usize;
            me.add(frame, f.as_ref());
        }
        if me.restored_keyframes > 0 {
            tracing::info!(
                keyframes = me.restored_keyframes,
                loops = me.closer.loops().len(),
                "loop closing restored from {}",
                path.display()
            );
        }
        Ok(me)
    }

    /// Whether a frame needs its keyframe's features before [`LoopClosing::add`].
    pub fn needs_features(frame: &PosedFrame) -> bool {
        frame.keyframe && frame.t_world_cam.is_some()
    }

    /// Keeps a keyframe's features where a restarted back end finds them (before the
    /// frame's line in `frames.csv`).
    pub fn log_keyframe(&mut self, seq: u64, f: &Features) -> Result<()> {
        self.log.append(seq, f)
    }

    /// Feeds one recorded frame to the loop closer; for a posed keyframe returns the verdict
    /// to send to tracking (`features` missing: the keyframe only extends the trajectory).
    pub fn add(&mut self, frame: PosedFrame, features: Option<&Features>) -> Option<CorrectionMsg> {
        if frame.lost {
            self.closer.add_lost_frame();
        }
        let pose = frame.t_world_cam?;
        let (seq, applied) = (frame.seq as usize, frame.corrections as usize);
        let correction = match features.filter(|_| frame.keyframe) {
            Some(f) => self.closer.add_keyframe_at(seq, &pose, f, applied),
            None => {
                if !frame.keyframe {
                    return None;
                }
                tracing::warn!("keyframe seq {seq}: its features never arrived; no loop check");
                None
            }
        };
        let verdict = self.verdict(correction);
        self.last_verdict = Some((frame.seq, verdict));
        Some(verdict)
    }

    fn verdict(&self, c: Option<Correction>) -> CorrectionMsg {
        let corrections = self.closer.corrections() as u32;
        let Some(c) = c else {
            return CorrectionMsg {
                corrections,
                loop_query: -1,
                loop_match: -1,
                ..Default::default()
            };
        };
        let edge = self.closer.loops().last().cloned();
        let r = c.sim3.r;
        CorrectionMsg {
            closed: 1,
            corrections,
            scale: c.sim3.s,
            rotation: std::array::from_fn(|i| r[(i / 3, i % 3)]),
            translation: [c.sim3.t.x, c.sim3.t.y, c.sim3.t.z],
            loop_query: edge.as_ref().map_or(-1, |e| e.query_frame as i64),
            loop_match: edge.as_ref().map_or(-1, |e| e.match_frame as i64),
        }
    }

    /// The verdict on the last keyframe, with its header, to send again after a restart.
    pub fn last_verdict(&self) -> Option<(FrameHeader, CorrectionMsg)> {
        self.last_verdict
            .map(|(seq, v)| (FrameHeader::new(seq, seq, 0.0, Status::Ok), v))
    }

    /// The restored tracker's state: the last pose moved into the world after every
    /// correction, and their count.
    pub fn restore_state(&self, state: &mut BackendState, applied: u32) {
        if state.has_pose == 1 {
            let p = Pose::from_row_major_3x4(&state.t_world_cam);
            state.t_world_cam = self
                .closer
                .in_latest_world(&p, applied as usize)
                .to_row_major_3x4();
        }
        state.corrections = self.closer.corrections() as u32;
    }

    /// Loops accepted so far.
    pub fn loops(&self) -> &[LoopEdge] {
        self.closer.loops()
    }

    /// The loop-corrected pose of every posed frame of `lines` (`frames.csv` in the order
    /// written), by sequence number; empty while no loop was closed.
    pub fn corrected(&self, lines: &[Record]) -> Vec<(u64, Pose)> {
        if self.closer.loops().is_empty() {
            return Vec::new();
        }
        let reported = frames_with_backfills(lines).flat_map(|(r, backfilled)| {
            let corrections = r.corrections as usize;
            backfilled
                .into_iter()
                .chain(r.t_world_cam.map(|p| (r.seq, p)))
                .map(move |(seq, t_world_cam)| ReportedPose {
                    frame: seq as usize,
                    t_world_cam,
                    corrections,
                })
        });
        self.closer
            .trajectory(reported)
            .into_iter()
            .map(|(seq, p)| (seq as u64, p))
            .collect()
    }
}

/// Each frame's own line of `frames.csv` (in the order written) with the poses that the
/// [`BACKFILLED`] lines after it gave earlier frames: `(seq, T_world_cam)`.
fn frames_with_backfills(lines: &[Record]) -> impl Iterator<Item = (&Record, Vec<(u64, Pose)>)> {
    lines
        .iter()
        .enumerate()
        .filter(|(_, r)| !is_late_pose(r))
        .map(|(i, r)| {
            let backfilled = lines[i + 1..]
                .iter()
                .take_while(|l| is_late_pose(l))
                .filter(|l| l.status == BACKFILLED)
                .filter_map(|l| l.t_world_cam.map(|p| (l.seq, p)))
                .collect();
            (r, backfilled)
        })
}

/// `keyframes.bin`: each keyframe's features as one record, appended and flushed: `seq`
/// (u64), keypoints `n`, descriptor length, image width and height (u32 each), then the
/// [`FeatureLayout`] floats; little-endian. A torn last record is ignored.
struct KeyframeLog {
    path: PathBuf,
    file: std::fs::File,
}

impl KeyframeLog {
    fn open(path: &Path, fresh: bool) -> Result<Self> {
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .with_context(|| format!("opening {}", path.display()))?;
        if fresh {
            file.set_len(0)
                .with_context(|| format!("clearing {}", path.display()))?;
        }
        Ok(Self {
            path: path.to_path_buf(),
            file,
        })
    }

    fn append(&mut self, seq: u64, f: &Features) -> Result<()> {
        let layout = FeatureLayout {
            n: f.len(),
            dim: f.dim,
        };
        let mut floats = vec![0.0f32; layout.len()];
        FeatureLayout::write(f, &mut floats);
        let mut bytes = Vec::with_capacity(24 + 4 * floats.len());
        bytes.extend_from_slice(&seq.to_le_bytes());
        for v in [layout.n, layout.dim, f.image_size.0, f.image_size.1] {
            bytes.extend_from_slice(&(v as u32).to_le_bytes());
        }
        for v in floats {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        self.file
            .write_all(&bytes)
            .and_then(|_| self.file.flush())
            .with_context(|| format!("writing {}", self.path.display()))
    }

    /// Every complete record, by sequence number (the last of duplicates).
    fn read(path: &Path) -> Result<HashMap<u64, Features>> {
        let mut bytes = Vec::new();
        match std::fs::File::open(path) {
            Ok(mut f) => f
                .read_to_end(&mut bytes)
                .with_context(|| format!("reading {}", path.display()))?,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(HashMap::new()),
            Err(e) => return Err(e).with_context(|| format!("opening {}", path.display())),
        };
        let mut out = HashMap::new();
        let mut at = 0;
        let u32_at = |b: &[u8], i: usize| u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
        while at + 24 <= bytes.len() {
            let seq = u64::from_le_bytes(std::array::from_fn(|i| bytes[at + i]));
            let (n, dim) = (u32_at(&bytes, at + 8), u32_at(&bytes, at + 12));
            let (w, h) = (u32_at(&bytes, at + 16), u32_at(&bytes, at + 20));
            let layout = FeatureLayout {
                n: n as usize,
                dim: dim as usize,
            };
            let end = at + 24 + 4 * layout.len();
            if end > bytes.len() {
                break;
            }
            let floats: Vec<f32> = bytes[at + 24..end]
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            let mut header = FrameHeader::new(seq, seq, 0.0, Status::Ok);
            (header.count, header.dim, header.width, header.height) = (n, dim, w, h);
            out.insert(seq, FeatureLayout::read(&header, &floats)?);
            at = end;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
    use super::*;

    fn features(seed: u32) -> Features {
        let n = 5;
        Features {
            keypoints: (0..n).map(|i| [i as f32 + seed as f32, 2.5]).collect(),
            scores: (0..n).map(|i| 1.0 / (i + 1) as f32).collect(),
            descriptors: (0..n * 16).map(|i| (i as f32 * 0.37).sin()).collect(),
            dim: 16,
            image_size: (640, 480),
        }
    }

    /// What a restarted back end reads back is what was logged, bit for bit; a torn last
    /// record is skipped.
    #[test]
    fn the_keyframe_log_reads_back_exactly_and_skips_a_torn_record() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(KEYFRAMES_FILE);
        let mut log = KeyframeLog::open(&path, true).unwrap();
        log.append(3, &features(3)).unwrap();
        log.append(9, &features(9)).unwrap();
        drop(log);
        let len = std::fs::metadata(&path).unwrap().len();
        let f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
        f.set_len(len - 7).unwrap();
        let back = KeyframeLog::read(&path).unwrap();
        assert_eq!(back.len(), 1);
        assert_eq!(back[&3], features(3));
    }
}
