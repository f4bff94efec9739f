//! Matching by projection: landmarks are projected into the frame at a predicted pose and
//! paired with the nearest free keypoint by descriptor. It serves the local-map search
//! (landmarks the keyframe matches did not reach) and tracking between keyframes (the last
//! frame's landmarks, with that frame's descriptors).

use super::Tracker;
use supermvo_geometry::{Pose, Vec3};
use supermvo_inference::Features;

impl Tracker {
    /// The local-map search: projects every landmark of the local map not in `skip` into
    /// the frame at `t_cam_world` and pairs it with the free keypoint (`taken` false)
    /// within the search radius whose descriptor is nearest, when that distance passes the
    /// threshold and the ratio test. Each keypoint keeps its nearest landmark. Returns
    /// `(keypoint, landmark id)` pairs in keypoint order.
    pub(crate) fn search_local_map(
        &self,
        cur: &Features,
        t_cam_world: &Pose,
        taken: &[bool],
        skip: &std::collections::BTreeSet<usize>,
        radius: f64,
    ) -> Vec<(usize, usize)> {
        let candidates = self
            .map
            .landmarks
            .iter()
            .filter(|(id, _)| !skip.contains(id))
            .map(|(&id, lm)| (id, &lm.p, &lm.desc[..]));
        let limits = (radius, self.cfg.map_search_ratio);
        self.match_by_projection(cur, t_cam_world, taken, candidates, limits)
    }

    /// Pairs each candidate `(landmark id, world point, descriptor)` projected at
    /// `t_cam_world` with the free keypoint (`taken` false) within `radius` pixels
    /// whose descriptor is nearest, when that distance passes the threshold and is below
    /// `ratio` times the second nearest. Each keypoint keeps its nearest landmark. Returns
    /// `(keypoint, landmark id)` pairs in keypoint order.
    pub(crate) fn match_by_projection<'a>(
        &self,
        cur: &Features,
        t_cam_world: &Pose,
        taken: &[bool],
        candidates: impl Iterator<Item = (usize, &'a Vec3, &'a [f32])>,
        (radius, ratio): (f64, f32),
    ) -> Vec<(usize, usize)> {
        let (w, h) = cur.image_size;
        if radius <= 0.0 || cur.is_empty() || w == 0 || h == 0 {
            return Vec::new();
        }
        // keypoints bucketed in cells of the search radius
        let cell = radius.max(1.0);
        let (gw, gh) = (
            (w as f64 / cell).ceil() as usize + 1,
            (h as f64 / cell).ceil() as usize + 1,
        );
        let mut grid: Vec<Vec<usize>> = vec![Vec::new(); gw * gh];
        let cell_of = |x: f64, y: f64| -> Option<(usize, usize)> {
            let (cx, cy) = ((x / cell).floor(), (y / cell).floor());
            (cx >= 0.0 && cy >= 0.0 && (cx as usize) < gw && (cy as usize) < gh)
                .then_some((cx as usize, cy as usize))
        };
        for (i, kp) in cur.keypoints.iter().enumerate() {
            if taken[i] {
                continue;
            }
            if let Some((cx, cy)) = cell_of(kp[0] as f64, kp[1] as f64) {
                grid[cy * gw + cx].push(i);
            }
        }
        let c = &self.calib;
        let mut best_for: Vec<Option<(f32, usize)>> = vec![None; cur.len()];
        for (id, p, desc) in candidates {
            if desc.len() != cur.dim {
                continue;
            }
            let q = t_cam_world.transform(p);
            if q.z <= 1e-6 {
                continue;
            }
            let (u, v) = c.project(&q);
            if u < 0.0 || v < 0.0 || u >= w as f64 || v >= h as f64 {
                continue;
            }
            let Some((gx, gy)) = cell_of(u, v) else {
                continue;
            };
            let (mut best, mut second) = ((f32::INFINITY, usize::MAX), f32::INFINITY);
            for y in gy.saturating_sub(1)..(gy + 2).min(gh) {
                for x in gx.saturating_sub(1)..(gx + 2).min(gw) {
                    for &i in &grid[y * gw + x] {
                        let kp = cur.keypoints[i];
                        if (kp[0] as f64 - u).hypot(kp[1] as f64 - v) > radius {
                            continue;
                        }
                        let d = supermvo_inference::descriptor_distance(desc, cur.descriptor(i));
                        if d < best.0 {
                            second = best.0;
                            best = (d, i);
                        } else if d < second {
                            second = d;
                        }
                    }
                }
            }
            let (d, i) = best;
            if i == usize::MAX || d > self.cfg.map_search_max_distance || d >= ratio * second {
                continue;
            }
            if best_for[i].is_none_or(|(d0, _)| d < d0) {
                best_for[i] = Some((d, id));
            }
        }
        best_for
            .iter()
            .enumerate()
            .filter_map(|(i, b)| b.map(|(_, id)| (i, id)))
            .collect()
    }
}
