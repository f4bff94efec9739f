//! Dataset and trajectory IO.
//!
//! * Trajectories: KITTI poses (12 numbers a line, 3x4 `T_world_cam` row-major), TUM
//!   (`t x y z qx qy qz qw`), EuRoC ground-truth CSV (`t[ns], p, q_wxyz, ...`).
//! * Sequences of frames: KITTI odometry, EuRoC MAV, TUM RGB-D and image folders, with
//!   camera files (ORB-SLAM3 / OpenCV YAML, EuRoC `sensor.yaml`) and lens distortion.
//!
//! Readers stream line by line and report the file and 1-based line of the first bad value.
//! Writers print every number in Rust's shortest round-trip form, so reading a written file
//! gives back the same bits.

mod camera;
mod error;
mod image;
mod kitti;
mod sequence;
mod trajectory;
mod tum_mono;
mod video;

pub use camera::{Camera, Distortion, Remap, Undistorter};
pub use error::DatasetError;
pub use image::GrayImage;
pub use kitti::{image_files, read_times, Calibration};
pub use sequence::{Layout, Sequence};
pub use trajectory::{
    hold_last_pose, read_trajectory, write_trajectory, PoseLines, StampedPose, Trajectory,
    TrajectoryFormat, ROTATION_TOLERANCE,
};
pub use video::{is_video, Video, VIDEO_EXTENSIONS};
