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
        self.map.forget_keyframes();
        self.map.segment_start = 0;
        self.frames_since_keyframe = 0;
        self.last_frame = None;
        self.pending_ba = None;
    }

    /// Moves the whole map (landmarks, keyframe poses, the reference and the last pose) by
    /// the similarity `x -> s R x + t`: the loop closer's correction of the world frame, so
    /// that tracking continues in the corrected world at the corrected scale.
    pub fn apply_correction(&mut self, c: &supermvo_optim::lie::Sim3) {
        // Corrections and the poses they move go round a loop (the loop closer corrects
        // poses the tracker reports after earlier corrections), so rounding off SO(3) would
        // grow with every pass: each moved pose is a rotation again.
        let c = c.with_nearest_rotation();
        let move_pose = |Pose { r, t }: Pose| {
            let centre = -(r.transpose() * t);
            let centre = c.s * (c.r * centre) + c.t;
            let r2 = supermvo_optim::so3::nearest_rotation(&(r * c.r.transpose()));
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

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)] // test code
    use super::*;
    use crate::tracker::TrackerConfig;
    use supermvo_dataset::Calibration;
    use supermvo_geometry::{so3_exp, Mat3, Vec3};
    use supermvo_optim::lie::Sim3;

    fn off_so3(r: &Mat3) -> f64 {
        (r.transpose() * r - Mat3::identity()).abs().max()
    }

    /// The real-time daemon's lap replays issued a correction every other keyframe; each
    /// came back a little further off SO(3) (rounding, then the tracker's poses corrected
    /// again), five times further per pass, until after 20 the poses held a scale of 10^7
    /// and every new map failed. Corrections that are not quite rotations leave the
    /// tracker's poses rotations.
    #[test]
    fn corrections_leave_the_poses_rotations() {
        let calib = Calibration {
            fx: 700.0,
            fy: 700.0,
            cx: 600.0,
            cy: 180.0,
        };
        let mut tr = Tracker::new(calib, TrackerConfig::default());
        tr.last_t_cam_world =
            Pose::new(so3_exp(&Vec3::new(0.1, 0.3, 0.0)), Vec3::new(1.0, 0.0, 2.0));
        tr.map.keyframe_poses = vec![Pose::identity(), tr.last_t_cam_world];
        let skewed = Mat3::new(1.0, 2e-6, 0.0, 0.0, 1.0, -1e-6, 1e-6, 0.0, 1.0);
        for k in 0..30 {
            let c = Sim3 {
                r: so3_exp(&Vec3::new(0.01, -0.02 * k as f64, 0.005)) * skewed,
                t: Vec3::new(0.5, 0.0, -0.3),
                s: 1.02,
            };
            tr.apply_correction(&c);
        }
        assert!(
            off_so3(&tr.last_t_cam_world.r) < 1e-12,
            "{}",
            off_so3(&tr.last_t_cam_world.r)
        );
        for p in &tr.map.keyframe_poses {
            assert!(off_so3(&p.r) < 1e-12, "{}", off_so3(&p.r));
        }
    }
}
