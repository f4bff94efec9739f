//! The tracker's local bundle adjustment: the last keyframes of the current map and their
//! landmarks, older keyframes that see them held fixed as anchors (they carry the scale).

use super::Tracker;
use supermvo_geometry::Vec3;

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

impl Tracker {
    /// Solves the local BA with `solver` instead of in this thread (the daemon hands it to
    /// the back-end process); the results must not depend on where it ran.
    pub fn set_ba_solver(&mut self, solver: Box<dyn crate::ba::BaSolver>) {
        self.ba_solver = Some(solver);
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
        let (c0, c1) = match self.ba_solver.as_mut() {
            Some(solver) => solver.solve(&mut ba, LOCAL_BA_ITERATIONS),
            None => ba.solve(LOCAL_BA_ITERATIONS),
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
        for (i, &k) in window.iter().enumerate() {
            self.map.keyframe_poses[k] = ba.poses[i];
        }
        for (i, &id) in point_ids.iter().enumerate() {
            if let Some(lm) = self.map.landmarks.get_mut(&id) {
                lm.p = ba.points[i];
            }
        }
        if let Some(kf) = self.keyframe.as_mut() {
            kf.t_cam_world = self.map.keyframe_poses[kf.id];
            self.last_t_cam_world = kf.t_cam_world;
        }
        self.last_ba = Some(BaStats {
            ms: started.elapsed().as_secs_f64() * 1e3,
            ..stats
        });
    }

    /// What the last local bundle adjustment did, taken (for benchmarks and diagnostics:
    /// `None` when no window was solved since the last call).
    pub fn take_ba_stats(&mut self) -> Option<BaStats> {
        self.last_ba.take()
    }
}
