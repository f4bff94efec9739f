//! New landmarks between a new keyframe and the keyframes before its reference: the
//! matcher pairs the new keyframe with the reference only, and a point that the chain of
//! keyframe matches lost, or that needs a wider baseline than two keyframes give, would
//! otherwise never become a landmark. Here each free keypoint of the new keyframe (no
//! landmark, no pending track) is paired with the free keypoint of an earlier keyframe that
//! lies within a few pixels of its epipolar line and has the nearest descriptor (mutual,
//! ratio-tested), and the pair becomes a landmark when it triangulates in front of both
//! views, within 2 px in each, with enough parallax (as ORB-SLAM's local mapping does with
//! its covisible keyframes; the poses are known, so no network is needed).
//!
//! Frames: keyframe poses are `T_cam_world`; bearings are normalised image coordinates.

use super::lens::bearing;
use super::Tracker;
use supermvo_geometry::essential::triangulate_checked;
use supermvo_geometry::Vec3;
use supermvo_inference::Features;

/// Bit pattern of a bearing, to recognise a keypoint by the bearing stored for it.
fn bits(b: &Vec3) -> [u64; 3] {
    [b.x.to_bits(), b.y.to_bits(), b.z.to_bits()]
}

impl Tracker {
    /// Triangulates new landmarks between the reference keyframe (just inserted) and the
    /// `covisible_triangulation_keyframes` keyframes before it, newest first; the landmarks
    /// go into the reference's keypoints (so the next frames track them) and the map. Then
    /// the map keeps the reference's keypoints for the keyframes to come.
    pub(super) fn triangulate_with_earlier_keyframes(&mut self) {
        let n = self.cfg.covisible_triangulation_keyframes;
        let Some(kf_id) = self.keyframe.as_ref().map(|k| k.id).filter(|_| n > 0) else {
            return;
        };
        // the keyframe just before the reference was matched by the network already
        let first = kf_id.saturating_sub(n + 1).max(self.map.segment_start);
        let earlier: Vec<usize> = (first..kf_id.saturating_sub(1)).rev().collect();
        let mut created = 0;
        for j in earlier {
            created += self.triangulate_pair(j);
        }
        tracing::debug!(keyframe = kf_id, created, "covisible triangulation");
        if let Some(k) = self.keyframe.as_ref() {
            self.map.keep_keypoints(k.id, &k.features, n + 1);
        }
    }

    /// New landmarks between the reference keyframe and earlier keyframe `j` (see the module
    /// docs); returns how many.
    fn triangulate_pair(&mut self, j: usize) -> usize {
        let (Some(kf), Some(older)) = (self.keyframe.as_ref(), self.map.keyframe_keypoints.get(&j))
        else {
            return 0;
        };
        let (view_k, view_j) = (self.map.keyframe_poses[kf.id], self.map.keyframe_poses[j]);
        let pairs = self.epipolar_matches(kf, older, j);
        let gate = 2.0 / self.focal();
        let mut created = Vec::new();
        for (ik, ij) in pairs {
            let bk = bearing(&self.calib, &kf.features.keypoints[ik]);
            let bj = bearing(&self.calib, &older.keypoints[ij]);
            let views = [(view_j.r, view_j.t, bj), (view_k.r, view_k.t, bk)];
            let Some(tri) = triangulate_checked(&views, gate) else {
                continue;
            };
            if tri.parallax_deg > self.cfg.min_triangulation_parallax_deg {
                created.push((ik, tri.point, vec![(j, bj), (kf.id, bk)]));
            }
        }
        let count = created.len();
        for (ik, p, obs) in created {
            let Some(kf) = self.keyframe.as_mut() else {
                break;
            };
            let id = self.map.add_landmark(
                p,
                obs,
                kf.features.descriptor(ik),
                crate::map::LandmarkSource::Covisible,
            );
            kf.landmark[ik] = Some(id);
        }
        count
    }

    /// `(keypoint of the reference, keypoint of keyframe j)` pairs of free keypoints: each
    /// within `epipolar_max_px` of the other's epipolar line, nearest to each other by
    /// descriptor among those (mutually), within the local-map search's distance and ratio.
    fn epipolar_matches(
        &self,
        kf: &super::Keyframe,
        older: &Features,
        j: usize,
    ) -> Vec<(usize, usize)> {
        let (view_k, view_j) = (self.map.keyframe_poses[kf.id], self.map.keyframe_poses[j]);
        let (r_k, t_k, r_j, t_j) = (view_k.r, view_k.t, view_j.r, view_j.t);
        // X_k = r X_j + t; the epipolar constraint b_k' E b_j = 0 with E = [t]x r
        let r = r_k * r_j.transpose();
        let t = t_k - r * t_j;
        if t.norm() < 1e-9 {
            return Vec::new();
        }
        let e = t.cross_matrix() * r;
        let free_k: Vec<usize> = (0..kf.features.len())
            .filter(|&i| kf.landmark[i].is_none() && kf.track[i].is_none())
            .collect();
        let free_j = self.free_keypoints(j, older);
        let gate = self.cfg.epipolar_max_px / self.focal();
        let lines: Vec<Vec3> = free_j
            .iter()
            .map(|&i| {
                let l = e * bearing(&self.calib, &older.keypoints[i]);
                l / l.x.hypot(l.y).max(1e-12)
            })
            .collect();
        let (max_d, ratio) = (self.cfg.map_search_max_distance, self.cfg.map_search_ratio);
        // best candidate in j for each free keypoint of the reference, and the reverse
        let mut best_k: Vec<Option<usize>> = vec![None; free_k.len()];
        let mut best_j: Vec<(f32, usize)> = vec![(f32::INFINITY, usize::MAX); free_j.len()];
        for (a, &ik) in free_k.iter().enumerate() {
            let bk = bearing(&self.calib, &kf.features.keypoints[ik]);
            let dk = kf.features.descriptor(ik);
            let (mut best, mut second) = ((f32::INFINITY, usize::MAX), f32::INFINITY);
            for (c, &ij) in free_j.iter().enumerate() {
                if bk.dot(&lines[c]).abs() > gate {
                    continue;
                }
                let d = supermvo_inference::descriptor_distance(dk, older.descriptor(ij));
                if d < best.0 {
                    (second, best) = (best.0, (d, c));
                } else if d < second {
                    second = d;
                }
                if d < best_j[c].0 {
                    best_j[c] = (d, a);
                }
            }
            if best.1 != usize::MAX && best.0 <= max_d && best.0 < ratio * second {
                best_k[a] = Some(best.1);
            }
        }
        best_k
            .iter()
            .enumerate()
            .filter_map(|(a, c)| {
                c.filter(|&c| best_j[c].1 == a)
                    .map(|c| (free_k[a], free_j[c]))
            })
            .collect()
    }

    /// Keypoints of keyframe `j` that carry no landmark and no pending track: those whose
    /// bearing no landmark or track of the map records as `j`'s observation.
    fn free_keypoints(&self, j: usize, older: &Features) -> Vec<usize> {
        let observed: std::collections::HashSet<[u64; 3]> = self
            .map
            .landmarks
            .values()
            .flat_map(|lm| lm.obs.iter())
            .chain(self.map.tracks.values().flatten())
            .filter(|(k, _)| *k == j)
            .map(|(_, b)| bits(b))
            .collect();
        (0..older.len())
            .filter(|&i| !observed.contains(&bits(&bearing(&self.calib, &older.keypoints[i]))))
            .collect()
    }
}
