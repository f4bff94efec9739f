//! The tracker's local bundle adjustment: the last keyframes of the current map and their
//! landmarks, older keyframes that see them held fixed as anchors (they carry the scale).

use super::Tracker;
use crate::ba::BaOutcome;
use supermvo_geometry::{Pose, Vec3};

/// One local bundle adjustment: its size, cost (sum of squared normalised reprojection
/// errors under the robust loss) and wall time including building the problem.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct BaStats {
    /// Keyframes in the window (including the fixed ones).
    pub keyframes: usize,
    /// Landmarks.
    pub points: usize,
    /// Observations.
    pub observations: usize,
    /// Cost before.
    pub cost_before: f64,
    /// Cost after.
    pub cost_after: f64,
    /// Milliseconds.
    pub ms: f64,
}

/// Levenberg-Marquardt iterations of one local BA.
const LOCAL_BA_ITERATIONS: usize = 10;

/// A solved window: the keyframes' `T_cam_world` and the points.
type SolvedWindow<'a> = (&'a [Pose], &'a [Vec3]);

/// A window handed off to a solver elsewhere, until its solution arrives.
#[derive(Debug, Clone)]
pub(crate) struct PendingBa {
    id: u64,
    /// The keyframes optimised (map ids, in the problem's order).
    window: Vec<usize>,
    /// The landmarks, in the problem's order.
    point_ids: Vec<usize>,
    /// The map segment it was built in.
    segment_start: usize,
}

impl Tracker {
    /// Runs the local mapping's triangulations and BA with `solver` instead of in this
    /// thread (the daemon hands them to the back-end process); the results must not depend
    /// on where they ran.
    pub fn set_mapping_solver(&mut self, solver: Box<dyn crate::mapping_solver::MappingSolver>) {
        self.mapping_solver = Some(solver);
    }

    /// The keyframes a local bundle adjustment optimises, in id order (`None`: too few
    /// for one). With `local_ba_min_shared` 0, the last `local_ba_window` keyframes of the
    /// current map; otherwise the newest keyframe and those sharing at least that many
    /// landmarks with it, the most covisible first, at most `local_ba_window` in all (as
    /// ORB-SLAM and stella_vslam choose them): in a weak stretch, where a keyframe comes
    /// every frame, the window then reaches as far back as its landmarks do.
    fn ba_keyframes(&self) -> Option<Vec<usize>> {
        let window = self.cfg.local_ba_window;
        let n = self.map.keyframe_poses.len();
        if window < 3 || n < 3 {
            return None;
        }
        let newest = n - 1;
        let mut ids: Vec<usize> = if self.cfg.local_ba_min_shared == 0 {
            (n.saturating_sub(window).max(self.map.segment_start)..n).collect()
        } else {
            let covisible = self.map.covisible(newest);
            std::iter::once(newest)
                .chain(
                    covisible
                        .iter()
                        .filter(|&&(_, shared)| shared >= self.cfg.local_ba_min_shared)
                        .map(|&(k, _)| k)
                        .take(window - 1),
                )
                .collect()
        };
        ids.sort_unstable();
        (ids.len() >= 3).then_some(ids)
    }

    /// Local bundle adjustment over [`Tracker::ba_keyframes`] (the oldest one or two held
    /// fixed) and the landmarks they observe, with those landmarks' observations from other
    /// keyframes of the map held fixed as anchors; writes the refined poses and points back.
    pub(crate) fn local_ba(&mut self) {
        let started = std::time::Instant::now();
        let Some(window) = self.ba_keyframes() else {
            return;
        };
        // Points seen in the window; their observations from other keyframes of this map
        // enter too, with those keyframes held fixed as anchors (they carry the scale).
        let mut point_ids = Vec::new();
        let mut observations = Vec::new();
        let mut slot: std::collections::BTreeMap<usize, usize> =
            window.iter().enumerate().map(|(i, &k)| (k, i)).collect();
        let in_window: std::collections::BTreeSet<usize> = window.iter().copied().collect();
        let mut anchors = Vec::new();
        for (&id, lm) in self.map.landmarks.iter() {
            let seen_in_window = lm.obs.iter().filter(|(k, _)| in_window.contains(k)).count();
            let usable: Vec<&(usize, Vec3)> = lm
                .obs
                .iter()
                .filter(|(k, _)| {
                    *k >= self.map.segment_start && (self.cfg.ba_anchors || in_window.contains(k))
                })
                .collect();
            if seen_in_window < 1 || usable.len() < 2 {
                continue;
            }
            let pi = point_ids.len();
            point_ids.push(id);
            for (k, b) in usable {
                let next = slot.len();
                let kf = *slot.entry(*k).or_insert_with(|| {
                    anchors.push(*k);
                    next
                });
                observations.push(crate::ba::Observation {
                    kf,
                    point: pi,
                    bearing: *b,
                });
            }
        }
        if point_ids.len() < 20 {
            return;
        }
        let window_fixed = if anchors.is_empty() {
            2
        } else {
            self.cfg.ba_fixed_with_anchors
        };
        let mut poses: Vec<_> = window.iter().map(|&k| self.map.keyframe_poses[k]).collect();
        poses.extend(anchors.iter().map(|&k| self.map.keyframe_poses[k]));
        let mut ba = crate::ba::LocalBa {
            poses,
            fixed: (0..window.len())
                .map(|i| i < window_fixed)
                .chain(anchors.iter().map(|_| true))
                .collect(),
            points: point_ids
                .iter()
                .map(|id| self.map.landmarks[id].p)
                .collect(),
            observations,
            huber: 2.0 / self.focal(),
        };
        let outcome = match self.mapping_solver.as_mut() {
            Some(solver) => solver.solve(&mut ba, LOCAL_BA_ITERATIONS),
            None => {
                let (c0, c1) = ba.solve(LOCAL_BA_ITERATIONS);
                BaOutcome::Solved(c0, c1)
            }
        };
        let (c0, c1) = match outcome {
            BaOutcome::Solved(c0, c1) => {
                let ids: Vec<usize> = window.iter().chain(&anchors).copied().collect();
                self.read_lens(&ba, &ids);
                (c0, c1)
            }
            BaOutcome::Deferred(id) => {
                self.pending_ba = Some(PendingBa {
                    id,
                    window,
                    point_ids,
                    segment_start: self.map.segment_start,
                });
                return;
            }
        };
        let stats = BaStats {
            keyframes: window.len(),
            points: point_ids.len(),
            observations: ba.observations.len(),
            cost_before: c0,
            cost_after: c1,
            ms: 0.0,
        };
        tracing::debug!(
            keyframes = window.len(),
            anchors = anchors.len(),
            points = point_ids.len(),
            observations = ba.observations.len(),
            cost_before = c0,
            cost_after = c1,
            "local BA"
        );
        self.write_back(&window, &point_ids, (&ba.poses, &ba.points), false);
        self.last_ba = Some(BaStats {
            ms: started.elapsed().as_secs_f64() * 1e3,
            ..stats
        });
    }

    /// Writes a solved window's keyframe poses and points into the map. The reference
    /// keyframe takes its refined pose and the last frame's pose follows it: solved at once,
    /// the last frame is the keyframe; solved later (`later`), a later frame keeps its pose
    /// relative to the keyframe.
    fn write_back(
        &mut self,
        window: &[usize],
        point_ids: &[usize],
        (poses, points): SolvedWindow,
        later: bool,
    ) {
        for (i, &k) in window.iter().enumerate() {
            self.map.keyframe_poses[k] = poses[i];
        }
        for (i, &id) in point_ids.iter().enumerate() {
            if let Some(lm) = self.map.landmarks.get_mut(&id) {
                lm.p = points[i];
            }
        }
        if let Some(kf) = self.keyframe.as_mut() {
            let before = kf.t_cam_world;
            kf.t_cam_world = self.map.keyframe_poses[kf.id];
            self.last_t_cam_world = match later {
                false => kf.t_cam_world,
                true => self
                    .last_t_cam_world
                    .compose(&before.inverse())
                    .compose(&kf.t_cam_world),
            };
        }
    }

    /// Applies the solution of the window handed off as `id` (see
    /// [`crate::ba::BaOutcome::Deferred`]) while tracking went on: `poses` of the window's
    /// keyframes (anchors after them are ignored) and `points` in the order sent. Returns
    /// whether it was applied: not when another window replaced it, the map started over or
    /// a loop correction moved the world since, or the sizes do not fit.
    pub fn apply_local_ba(&mut self, id: u64, poses: &[Pose], points: &[Vec3]) -> bool {
        let Some(p) = self.pending_ba.take_if(|p| p.id == id) else {
            return false;
        };
        let fits = poses.len() >= p.window.len()
            && points.len() == p.point_ids.len()
            && p.segment_start == self.map.segment_start
            && p.window.iter().all(|&k| k < self.map.keyframe_poses.len());
        if fits {
            self.write_back(&p.window, &p.point_ids, (poses, points), true);
        }
        fits
    }

    /// What the last local bundle adjustment did, taken (for benchmarks and diagnostics:
    /// `None` when no window was solved since the last call).
    pub fn take_ba_stats(&mut self) -> Option<BaStats> {
        self.last_ba.take()
    }
}
