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

impl Tracker {
    /// Local bundle adjustment over the last `local_ba_window` keyframes (the two oldest fixed) and
    /// the landmarks they observe at least twice; writes the refined poses and points back.
    pub(crate) fn local_ba(&mut self) {
        let started = std::time::Instant::now();
        let window = self.cfg.local_ba_window;
        let n = self.map.keyframe_poses.len();
        if window < 3 || n < 3 {
            return;
        }
        let first = n.saturating_sub(window).max(self.map.segment_start);
        if n - first < 3 {
            return;
        }
        // Points seen in the window; their observations from older keyframes of this map
        // enter too, with those keyframes held fixed as anchors (they carry the scale).
        let mut point_ids = Vec::new();
        let mut observations = Vec::new();
        let mut slot: std::collections::BTreeMap<usize, usize> =
            (first..n).enumerate().map(|(i, k)| (k, i)).collect();
        let mut anchors = Vec::new();
        for (&id, lm) in self.map.landmarks.iter() {
            let in_window = lm.obs.iter().filter(|(k, _)| *k >= first).count();
            let usable: Vec<&(usize, Vec3)> = lm
                .obs
                .iter()
                .filter(|(k, _)| {
                    *k >= self.map.segment_start && (self.cfg.ba_anchors || *k >= first)
                })
                .collect();
            if in_window < 1 || usable.len() < 2 {
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
        let mut poses = self.map.keyframe_poses[first..].to_vec();
        poses.extend(anchors.iter().map(|&k| self.map.keyframe_poses[k]));
        let mut ba = crate::ba::LocalBa {
            poses,
            fixed: (first..n)
                .map(|k| k < first + window_fixed)
                .chain(anchors.iter().map(|_| true))
                .collect(),
            points: point_ids
                .iter()
                .map(|id| self.map.landmarks[id].p)
                .collect(),
            observations,
            huber: 2.0 / self.focal(),
        };
        let (c0, c1) = ba.solve(10);
        let stats = BaStats {
            keyframes: n - first,
            points: point_ids.len(),
            observations: ba.observations.len(),
            cost_before: c0,
            cost_after: c1,
            ms: 0.0,
        };
        tracing::debug!(
            keyframes = n - first,
            points = point_ids.len(),
            observations = ba.observations.len(),
            cost_before = c0,
            cost_after = c1,
            "local BA"
        );
        self.map.keyframe_poses[first..].copy_from_slice(&ba.poses[..n - first]);
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
