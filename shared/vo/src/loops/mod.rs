//! Loop closure: place recognition over keyframes, geometric verification with a Sim(3)
//! between the two places' triangulated points, and a Sim(3) pose graph of keyframes that
//! spreads the drift (scale included) along the loop.
//!
//! Place recognition aggregates each keyframe's learned descriptors into a VLAD vector over
//! a small vocabulary that is learned at the start of the run from the first keyframes'
//! descriptors (k-means, fixed seed): no training data is shipped or needed, the vocabulary
//! fits the camera and scene at hand, and VLAD's residual aggregation keeps far more of the
//! descriptor than a bag of words of the same size. A candidate is accepted only when the
//! two keyframes' 3D points agree under one similarity (RANSAC, reprojection in both images)
//! and the next keyframe finds the same place again.
//!
//! Frames: keyframe poses are `T_world_cam`; a keyframe's points are in its own camera frame
//! at the map scale of the moment, so the verified transform carries the scale drift between
//! the two visits.
//!
//! Where each part lives: the vocabulary and VLAD vectors in [`place_recognition`], the
//! points of each keyframe and the Sim(3) check of a candidate in [`verification`], the
//! Sim(3) pose graph in [`pose_graph`], which keyframes leave place recognition in
//! [`revisits`], the settings in [`config`]; this file keeps the keyframes and decides.

mod config;
mod mutual_nearest;
mod place_recognition;
mod pose_graph;
mod revisits;
#[cfg(test)]
mod tests;
mod verification;

pub use config::LoopConfig;
pub use pose_graph::pose_of;

use nalgebra::DMatrix;
use place_recognition::dot;
use pose_graph::sim3_of;
use supermvo_dataset::Calibration;
use supermvo_geometry::{Pose, Vec3};
use supermvo_inference::Features;
use supermvo_optim::lie::{LieGroup, Sim3};

/// An accepted loop.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LoopEdge {
    /// Frame index of the keyframe that recognised the place.
    pub query_frame: usize,
    /// Frame index of the earlier keyframe it recognised.
    pub match_frame: usize,
    /// Verified 3D-3D inliers.
    pub inliers: usize,
    /// Scale of the query's map relative to the match's (1 without drift).
    pub scale: f64,
    /// VLAD similarity.
    pub similarity: f32,
}

/// A correction of the world frame after a loop: the similarity that takes everything the
/// tracker estimated (its map and poses) to the corrected world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correction {
    /// Frame index of the keyframe at which the loop was closed.
    pub frame: usize,
    /// `x_corrected = s R x + t`.
    pub sim3: Sim3,
}

/// Keyframes before the newest that it is triangulated against (the one with the widest
/// baseline is taken).
const TRIANGULATION_KEYFRAMES: usize = 4;

/// The longest run of unverified keyframes between two revisits of one stretch that counts
/// as revisited too (see `LoopCloser::mark_revisit`).
const REVISIT_GAP: usize = 8;

struct KeyframeEntry {
    frame: usize,
    /// Pose in the odometry frame (the tracker's frame with all corrections undone).
    odom: Sim3,
    /// Current best estimate.
    opt: Sim3,
    keypoints: Vec<[f32; 2]>,
    /// Unit descriptors, one row per keypoint.
    desc: DMatrix<f32>,
    /// Triangulated point of each keypoint, in this keyframe's camera frame.
    points: Vec<Option<Vec3>>,
    vlad: Option<Vec<f32>>,
    /// Tracking failed on a frame between this keyframe and the one before (the tracker
    /// may have started a new map, whose placement and scale the odometry does not tie to
    /// the old one).
    after_gap: bool,
    /// The earlier keyframe whose place it revisits (see `LoopConfig::cull_revisits`).
    revisit: Option<usize>,
    /// Its place-recognition data was freed: never a candidate again.
    culled: bool,
}

impl KeyframeEntry {
    /// Frees what verification needs (keypoints, descriptors, points).
    fn release_features(&mut self) {
        self.keypoints = Vec::new();
        self.desc = DMatrix::zeros(0, 0);
        self.points = Vec::new();
    }
}

/// A recognised but not yet confirmed place.
#[derive(Debug, Clone, Copy)]
struct Detection {
    keyframe: usize,
    matched: usize,
    rel: Sim3,
    inliers: usize,
    similarity: f32,
}

/// The loop closer (see module docs).
pub struct LoopCloser {
    calib: Calibration,
    cfg: LoopConfig,
    keyframes: Vec<KeyframeEntry>,
    vocabulary: Option<DMatrix<f32>>,
    /// The loops a pose-graph solve may still free a keyframe of: (matched keyframe, query
    /// keyframe, Sim(3) query -> matched). Loops wholly before the keyframes a solve frees
    /// (see [`LoopCloser::solve`]) leave it, so that it does not grow with the run.
    loops: Vec<(usize, usize, Sim3)>,
    /// Every loop accepted, for the report.
    edges: Vec<LoopEdge>,
    pending: Vec<Detection>,
    /// The tracker's world after `k` corrections is `fixes[k]` * the odometry frame
    /// (`fixes[0]` is the identity); a tracker that has not yet applied the latest one (the
    /// daemon's real-time mode) reports poses in an earlier world, and says which.
    fixes: Vec<Sim3>,
    disabled: Option<String>,
    /// Tracking failed on a frame since the last keyframe.
    gap: bool,
    /// Keyframe index of the last correction.
    last_correction: Option<usize>,
    /// Loops accepted since the pose graph was last solved.
    unsolved_loops: bool,
    /// The newest keyframe that a solved loop tied to the map: the keyframes before it are
    /// consistent with the map, and a later solve leaves them (all but a margin) held.
    tied: Option<usize>,
    /// Pose-graph solves so far, and the keyframes free in the last (read by the tests).
    solves: usize,
    free_in_last_solve: usize,
}

impl std::fmt::Debug for LoopCloser {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "LoopCloser({} keyframes, {} loops)",
            self.keyframes.len(),
            self.edges.len()
        )
    }
}

impl LoopCloser {
    /// A loop closer for a camera with calibration `calib`.
    pub fn new(calib: Calibration, cfg: LoopConfig) -> Self {
        Self {
            calib,
            cfg,
            keyframes: Vec::new(),
            vocabulary: None,
            loops: Vec::new(),
            edges: Vec::new(),
            pending: Vec::new(),
            fixes: vec![Sim3::identity()],
            disabled: None,
            gap: false,
            last_correction: None,
            unsolved_loops: false,
            tied: None,
            solves: 0,
            free_in_last_solve: 0,
        }
    }

    /// Accepted loops so far.
    pub fn loops(&self) -> &[LoopEdge] {
        &self.edges
    }

    /// Why loop closure is off for this run (features without float descriptors), if it is.
    pub fn disabled_reason(&self) -> Option<&str> {
        self.disabled.as_deref()
    }

    fn project(&self, p: &Vec3) -> Option<(f64, f64)> {
        (p.z > 1e-6).then(|| {
            (
                self.calib.fx * p.x / p.z + self.calib.cx,
                self.calib.fy * p.y / p.z + self.calib.cy,
            )
        })
    }

    fn bearing(&self, kp: &[f32; 2]) -> Vec3 {
        Vec3::new(
            (kp[0] as f64 - self.calib.cx) / self.calib.fx,
            (kp[1] as f64 - self.calib.cy) / self.calib.fy,
            1.0,
        )
    }

    /// Corrections issued so far (each returned by [`LoopCloser::add_keyframe`]).
    pub fn corrections(&self) -> usize {
        self.fixes.len() - 1
    }

    /// The tracker's world after `applied` corrections, relative to the odometry frame.
    fn fix(&self, applied: usize) -> Sim3 {
        self.fixes[applied.min(self.fixes.len() - 1)]
    }

    /// A pose reported after `applied` corrections, moved into the world after all of them.
    pub fn in_latest_world(&self, t_world_cam: &Pose, applied: usize) -> Pose {
        if applied >= self.corrections() {
            return *t_world_cam;
        }
        let to_latest = self.fix(usize::MAX).compose(&self.fix(applied).inverse());
        pose_of(&to_latest.compose(&sim3_of(t_world_cam)))
    }

    /// Notes a frame tracking failed on: the next keyframe's odometry link to the one
    /// before is weak in the pose graph (see `after_gap`).
    pub fn add_lost_frame(&mut self) {
        self.gap = true;
    }

    /// Adds a keyframe (its pose as the tracker reported it, and its features). When a loop
    /// is closed, returns the correction the caller must apply to the tracker before the
    /// next frame (see [`Correction`]); the loop closer assumes it is applied.
    pub fn add_keyframe(
        &mut self,
        frame: usize,
        t_world_cam: &Pose,
        features: &Features,
    ) -> Option<Correction> {
        self.add_keyframe_at(frame, t_world_cam, features, self.corrections())
    }

    /// [`LoopCloser::add_keyframe`] for a pose the tracker reported after `applied`
    /// corrections; a correction returned is relative to the world after all earlier ones
    /// (the tracker applies them in order).
    pub fn add_keyframe_at(
        &mut self,
        frame: usize,
        t_world_cam: &Pose,
        features: &Features,
        applied: usize,
    ) -> Option<Correction> {
        let features = match self.cfg.keypoints {
            Some(k) => features.strongest(k),
            None => std::borrow::Cow::Borrowed(features),
        };
        let odom = self.fix(applied).inverse().compose(&sim3_of(t_world_cam));
        let opt = match self.keyframes.last() {
            // Chain the odometry onto the previous keyframe's best estimate.
            Some(prev) => prev.opt.compose(&prev.odom.inverse().compose(&odom)),
            None => odom,
        };
        let d = features.dim;
        if d < 16 || features.descriptors.len() != features.len() * d {
            self.disabled.get_or_insert_with(|| {
                format!("loop closure needs float descriptors; these features have {d}-value descriptors (ORB)")
            });
        }
        let desc = if self.disabled.is_some() {
            DMatrix::zeros(0, 0)
        } else {
            let mut m = DMatrix::from_row_slice(features.len(), d, &features.descriptors);
            for mut row in m.row_iter_mut() {
                let n = row.norm();
                if n > 0.0 {
                    row /= n;
                }
            }
            m
        };
        let index = self.keyframes.len();
        self.keyframes.push(KeyframeEntry {
            frame,
            odom,
            opt,
            keypoints: features.keypoints.clone(),
            desc,
            points: Vec::new(),
            vlad: None,
            after_gap: std::mem::take(&mut self.gap) && index > 0,
            revisit: None,
            culled: false,
        });
        if self.disabled.is_some() {
            return None;
        }
        self.triangulate(index);
        self.update_vocabulary();
        let correction = self.detect(index);
        self.cull_revisits(index);
        correction
    }

    /// Verifies the best places for keyframe `j`; closes a loop once confirmed.
    fn detect(&mut self, j: usize) -> Option<Correction> {
        let q = self.keyframes[j].vlad.as_ref()?;
        let last = j.checked_sub(self.cfg.min_separation)?;
        let mut scored: Vec<(usize, f32)> = (0..=last)
            .filter_map(|i| self.keyframes[i].vlad.as_ref().map(|v| (i, dot(q, v))))
            .collect();
        scored.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        let found = scored
            .iter()
            .take(self.cfg.candidates)
            .filter_map(|&(i, sim)| {
                self.verify(i, j).map(|(rel, inliers)| Detection {
                    keyframe: j,
                    matched: i,
                    rel,
                    inliers,
                    similarity: sim,
                })
            })
            .max_by_key(|d| d.inliers);
        let Some(det) = found else {
            self.pending.clear();
            return None;
        };
        self.mark_revisit(j, det.matched);
        tracing::debug!(
            query = self.keyframes[j].frame,
            matched = self.keyframes[det.matched].frame,
            inliers = det.inliers,
            "place recognised"
        );
        // Consistent with the previous keyframe's detection: the same stretch of the past.
        let consistent = self
            .pending
            .last()
            .is_some_and(|p| p.keyframe + 1 == j && p.matched.abs_diff(det.matched) <= 6);
        if !consistent {
            self.pending.clear();
        }
        self.pending.push(det);
        if self.pending.len() < self.cfg.consistency {
            return None;
        }
        let confirmed = std::mem::take(&mut self.pending);
        for d in &confirmed {
            let edge = LoopEdge {
                query_frame: self.keyframes[d.keyframe].frame,
                match_frame: self.keyframes[d.matched].frame,
                inliers: d.inliers,
                scale: d.rel.s,
                similarity: d.similarity,
            };
            tracing::info!(
                query = edge.query_frame,
                matched = edge.match_frame,
                inliers = edge.inliers,
                scale = edge.scale,
                keyframes = self.keyframes.len(),
                places = self.places(),
                "loop closed"
            );
            self.loops.push((d.matched, d.keyframe, d.rel));
            self.edges.push(edge);
        }
        if self
            .last_correction
            .is_some_and(|l| j <= l + self.cfg.cooldown)
        {
            self.unsolved_loops = true;
            return None;
        }
        self.optimise();
        self.last_correction = Some(j);
        let cur = &self.keyframes[j];
        let to_corrected = cur.opt.compose(&cur.odom.inverse()).with_nearest_rotation();
        // Relative to what the tracker already applied.
        let correction = to_corrected
            .compose(&self.fix(usize::MAX).inverse())
            .with_nearest_rotation();
        self.fixes.push(to_corrected);
        Some(Correction {
            frame: cur.frame,
            sim3: correction,
        })
    }

    /// The corrected pose `T_world_cam` of each reported pose that has a keyframe at or
    /// before its frame, in the order given: each frame moves with the latest such keyframe,
    /// by the pose graph over every loop accepted (solved again when loops came after the
    /// last correction). Until a loop is closed these are the poses as reported. The loop
    /// closer keeps no record per frame (the caller has them: the daemon in `frames.csv`),
    /// so its memory grows only with the keyframes.
    pub fn trajectory(
        &self,
        reported: impl IntoIterator<Item = ReportedPose>,
    ) -> Vec<(usize, Pose)> {
        let opt: Option<Vec<Sim3>> = match (self.edges.is_empty(), self.unsolved_loops) {
            (true, _) => None,
            (false, true) => Some(self.solve()),
            (false, false) => Some(self.keyframes.iter().map(|k| k.opt).collect()),
        };
        reported
            .into_iter()
            .filter_map(|r| {
                let k = self
                    .keyframes
                    .partition_point(|kf| kf.frame <= r.frame)
                    .checked_sub(1)?;
                let Some(opt) = &opt else {
                    return Some((r.frame, r.t_world_cam));
                };
                let odom = self
                    .fix(r.corrections)
                    .inverse()
                    .compose(&sim3_of(&r.t_world_cam));
                let corrected = opt[k]
                    .compose(&self.keyframes[k].odom.inverse())
                    .compose(&odom);
                Some((r.frame, pose_of(&corrected)))
            })
            .collect()
    }
}

/// A pose as the tracker reported it, for [`LoopCloser::trajectory`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReportedPose {
    /// Frame index.
    pub frame: usize,
    /// `T_world_cam` as reported.
    pub t_world_cam: Pose,
    /// Loop corrections the tracker had applied when it reported it.
    pub corrections: usize,
}
