//! Two-view initialisation: once the matches to the reference move far enough, the 5-point
//! essential matrix gives the relative pose and the inliers triangulate the first landmarks;
//! the scale is a unit baseline at the first map; a map started after tracking failed
//! continues the old map's scale where its first view saw the old landmarks, and otherwise
//! gets the first map's median depth.

use super::lens::bearing;
use super::{FrameMeta, FrameOutput, Keyframe, Tracker, TrackingState};
use supermvo_geometry::essential::{find_essential, recover_pose, triangulate_checked};
use supermvo_geometry::{Mat3, Pose, Vec3};
use supermvo_inference::{Features, Matches};

/// Keypoints of a new map's first view with both an old landmark's depth and a two-view
/// depth that the new map needs to take the old map's scale from their ratios.
const MIN_SHARED_DEPTHS: usize = 10;

/// The middle value (the upper one of an even count); `values` must not be empty.
fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

impl Tracker {
    pub(crate) fn initialise(
        &mut self,
        input: &FrameMeta,
        cur: Features,
        m: Option<&Matches>,
    ) -> FrameOutput {
        let Some(kf) = self.keyframe.take() else {
            // first frame (or first after a loss): becomes the reference at the last pose
            let t_cam_world = self.last_t_cam_world;
            let out = self.output(
                input,
                TrackingState::Initializing,
                Some(t_cam_world),
                cur.len(),
                (0, 0),
                true,
            );
            self.set_reference(input.index, t_cam_world, cur);
            return out;
        };
        let Some(m) = m else {
            // no matches to the reference: start again from this frame
            return self.lost(input, cur, 0);
        };
        let mut disp: Vec<f64> = m
            .pairs
            .iter()
            .map(|&(a, b)| {
                let (p, q) = (kf.features.keypoints[a], cur.keypoints[b]);
                ((p[0] - q[0]) as f64).hypot((p[1] - q[1]) as f64)
            })
            .collect();
        disp.sort_by(f64::total_cmp);
        let parallax = disp.get(disp.len() / 2).copied().unwrap_or(0.0);
        tracing::debug!(
            frame = input.index,
            matches = m.pairs.len(),
            median_displacement_px = parallax,
            "initialising"
        );
        if m.pairs.len() < self.cfg.min_init_landmarks {
            // too few matches left for this reference ever to initialise (the view has moved
            // on, e.g. after a failed attempt in a turn): start again from this frame, unless
            // the frame is blind
            let state = TrackingState::Initializing;
            return self.unusable_reference(input, kf, cur, m.pairs.len(), state);
        }
        if parallax < self.cfg.min_parallax_px {
            return self.not_initialised_yet(input, kf, (&cur, m), 0);
        }
        let x1: Vec<Vec3> = m
            .pairs
            .iter()
            .map(|&(a, _)| bearing(&self.calib, &kf.features.keypoints[a]))
            .collect();
        let x2: Vec<Vec3> = m
            .pairs
            .iter()
            .map(|&(_, b)| bearing(&self.calib, &cur.keypoints[b]))
            .collect();
        let Some(est) = find_essential(&x1, &x2, self.focal(), &self.cfg.ransac) else {
            return self.not_initialised_yet(input, kf, (&cur, m), 0);
        };
        let (r_rel, t_rel, _) = recover_pose(&est.e, &x1, &x2, &est.inliers, 1e3);
        // scale: unit baseline at the first initialisation; afterwards keep the map's scale
        // by scaling the baseline so the median depth matches the last map's median depth
        let inl: Vec<(usize, usize)> = m
            .pairs
            .iter()
            .zip(&est.inliers)
            .filter(|(_, &b)| b)
            .map(|(p, _)| *p)
            .collect();
        let identity = (&Mat3::identity(), &Vec3::zeros());
        let unit =
            self.triangulate_pairs(identity, &kf.features.keypoints, &cur, &r_rel, &t_rel, &inl);
        if unit.len() < self.cfg.min_init_landmarks {
            return self.not_initialised_yet(input, kf, (&cur, m), unit.len());
        }
        let s = self.new_map_scale(&kf, &unit);
        // current camera: T_cur_world = T_cur_kf * T_kf_world
        let t_rel = t_rel * s;
        let t_cur_world = Pose::new(r_rel, t_rel).compose(&kf.t_cam_world);
        let cur_id = self.map.new_keyframe_id(t_cur_world, input.index);
        let (keypoints, landmark) = (cur.len(), vec![None; cur.len()]);
        let init = (&inl[..], self.cfg.min_init_parallax_deg);
        self.insert_keyframe(&kf, cur, (input.index, cur_id), t_cur_world, landmark, init);
        let backfilled = self.pose_initialising_frames(&self.reference_landmarks(&inl));
        // the motion per frame between reference and new keyframe is the first motion model:
        // should the next frame's PnP on the new (small) map fail, the prediction and the
        // local-map search still have a pose to start from
        let gap = input.index.saturating_sub(kf.frame).max(1) as f64;
        let r_step = supermvo_geometry::so3_exp(&(supermvo_geometry::so3_log(&r_rel) / gap));
        self.velocity = Some(Pose::new(r_step, t_rel / gap));
        self.unseen = 0;
        let counts = (m.pairs.len(), est.inlier_count());
        let mut out = self.output(
            input,
            TrackingState::Tracking,
            Some(t_cur_world),
            keypoints,
            counts,
            true,
        );
        out.backfilled = backfilled;
        out
    }

    /// The factor for a two-view map `unit` (points in `kf`'s camera, unit baseline): the
    /// old map's scale where `kf` saw its landmarks (see
    /// `TrackerConfig::reinitialise_at_map_scale`); otherwise the first map's median depth
    /// (1 for the first map itself, which sets it).
    fn new_map_scale(&mut self, kf: &Keyframe, unit: &[(usize, usize, Vec3)]) -> f64 {
        if let Some((_, depths)) = self.reference_depths.take().filter(|(id, _)| *id == kf.id) {
            let ratios: Vec<f64> = unit
                .iter()
                .filter_map(|(a, _, p)| Some(depths.get(*a).copied()?? / p.z))
                .collect();
            tracing::debug!(shared = ratios.len(), "a new map: landmark depths to keep");
            if ratios.len() >= MIN_SHARED_DEPTHS {
                return median(ratios);
            }
        }
        let m = median(unit.iter().map(|(_, _, p)| p.z).collect());
        match self.scale {
            Some(target) => target / m,
            None => {
                self.scale = Some(m);
                1.0
            }
        }
    }

    /// A frame that does not initialise against the reference `kf` yet (too little
    /// parallax, no essential matrix, too few landmarks from it: `landmarks`): no pose, the
    /// reference stays, and the frame is kept to be posed once the map exists.
    fn not_initialised_yet(
        &mut self,
        input: &FrameMeta,
        kf: Keyframe,
        (cur, m): (&Features, &Matches),
        landmarks: usize,
    ) -> FrameOutput {
        self.keep_initialising_frame(input, cur, m);
        let state = TrackingState::Initializing;
        self.keep_reference(input, kf, state, cur.len(), (m.pairs.len(), landmarks))
    }

    /// `(reference keypoint, landmark id)` of the initialisation's matches `(reference
    /// keypoint, keypoint of the new keyframe)` that became landmarks.
    fn reference_landmarks(&self, matches: &[(usize, usize)]) -> Vec<(usize, usize)> {
        let Some(kf) = self.keyframe.as_ref() else {
            return Vec::new();
        };
        matches
            .iter()
            .filter_map(|&(a, b)| kf.landmark.get(b).copied().flatten().map(|id| (a, id)))
            .collect()
    }

    /// Triangulates matched keypoints between a keyframe and the current frame (both
    /// `T_cam_world`), returning world points for pairs that are in front of both cameras,
    /// reproject within 2 px and have the configured parallax.
    pub(crate) fn triangulate_pairs(
        &self,
        (kf_r, kf_t): (&Mat3, &Vec3),
        kf_keypoints: &[[f32; 2]],
        cur: &Features,
        r: &Mat3,
        t: &Vec3,
        pairs: &[(usize, usize)],
    ) -> Vec<(usize, usize, Vec3)> {
        // relative pose T_cur_kf = T_cur_world * T_world_kf
        let r_rel = r * kf_r.transpose();
        let t_rel = t - r_rel * kf_t;
        let thr = 2.0 / self.focal();
        let mut out = Vec::new();
        for &(a, b) in pairs {
            let (x1, x2) = (
                bearing(&self.calib, &kf_keypoints[a]),
                bearing(&self.calib, &cur.keypoints[b]),
            );
            let views = [(Mat3::identity(), Vec3::zeros(), x1), (r_rel, t_rel, x2)];
            let Some(tri) = triangulate_checked(&views, thr) else {
                continue;
            };
            if tri.parallax_deg > self.cfg.min_init_parallax_deg {
                // world point: p_world = R_kf^T (p_kf - t_kf)
                out.push((a, b, kf_r.transpose() * (tri.point - kf_t)));
            }
        }
        out
    }
}
