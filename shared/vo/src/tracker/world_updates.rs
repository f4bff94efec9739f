//! What moves the tracker's world from outside: a restore after the tracking process
//! restarted, and the loop closer's correction of the world frame.

use super::Tracker;
use supermvo_geometry::Pose;

impl Tracker {
    /// Restarts from `T_world_cam` with the map scale of an earlier run (a restarted tracking
    /// process continues the trajectory the back end recorded). Clears map and reference.
    pub fn restore(&mut self, t_world_cam: &Pose, scale: Option<f64>) {
        self.last_t_cam_world = t_world_cam.inverse();
        self.velocity = None;
        self.lost_streak = 0;
        self.unseen = 0;
        self.scale = scale;
        self.keyframe = None;
        self.map.landmarks.clear();
        self.map.tracks.clear();
        self.map.keyframe_poses.clear();
        self.map.keyframe_keypoints.clear();
        self.map.segment_start = 0;
        self.frames_since_keyframe = 0;
        self.last_frame = None;
        self.pending_ba = None;
    }

    /// Moves the whole map (landmarks, keyframe poses, the reference and the last pose) by
    /// the similarity `x -> s R x + t`: the loop closer's correction of the world frame, so
    /// that tracking continues in the corrected world at the corrected scale.
    pub fn apply_correction(&mut self, c: &supermvo_optim::lie::Sim3) {
        let move_pose = |Pose { r, t }: Pose| {
            let centre = -(r.transpose() * t);
            let centre = c.s * (c.r * centre) + c.t;
            let r2 = r * c.r.transpose();
            Pose::new(r2, -(r2 * centre))
        };
        for p in self.map.keyframe_poses.iter_mut() {
            *p = move_pose(*p);
        }
        for lm in self.map.landmarks.values_mut() {
            lm.p = c.s * (c.r * lm.p) + c.t;
        }
        if let Some(kf) = self.keyframe.as_mut() {
            kf.t_cam_world = move_pose(kf.t_cam_world);
        }
        self.last_t_cam_world = move_pose(self.last_t_cam_world);
        if let Some(v) = self.velocity.as_mut() {
            v.t *= c.s;
        }
        self.scale = self.scale.map(|s| s * c.s);
        // a window solved in the world before this correction no longer fits
        self.pending_ba = None;
    }
}
