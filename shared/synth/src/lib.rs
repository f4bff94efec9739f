//! Synthetic driving sequences with exact ground truth, written in the KITTI odometry layout.
//!
//! A [`Sequence`] is a preset world ([`preset`]), a camera driven through it at 10 Hz and a
//! seed. [`Sequence::write`] renders every frame on the CPU (frames in parallel) to
//! `ROOT/sequences/NAME/image_0/NNNNNN.png` with `calib.txt` and `times.txt`, and the
//! ground-truth poses `T_cam0_cam` to `ROOT/poses/NAME.txt`, so every SuPerMVO command and
//! the KITTI devkit read it like a KITTI sequence.

pub mod noise;
pub mod path;
pub mod preset;
pub mod render;
pub mod scene;

use nalgebra::{Matrix3, Rotation3};
use noise::Rng;
use preset::{Photometry, Preset};
use render::{CameraModel, Exposure, Frame};
use scene::V3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use supermvo_geometry::Pose;

/// Frame rate of every sequence, Hz (KITTI's).
pub const RATE_HZ: f64 = 10.0;

/// Errors of the renderer and writer.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// The preset name is not known.
    #[error("unknown preset '{0}'; the presets are: {list}", list = preset::PRESETS.join(", "))]
    UnknownPreset(String),
    /// Invalid request.
    #[error("{0}")]
    Invalid(String),
    /// File-system failure.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// PNG encoding failure.
    #[error("{path}: cannot write PNG: {message}")]
    Png {
        /// The file.
        path: PathBuf,
        /// The cause.
        message: String,
    },
    /// Trajectory writing failure.
    #[error(transparent)]
    Dataset(#[from] supermvo_dataset::DatasetError),
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> SynthError + '_ {
    move |source| SynthError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// What a rendered sequence was made from; written next to the frames as `synth.json`, and
/// compared to decide whether a sequence on disk can be reused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Preset name.
    pub preset: String,
    /// Seed.
    pub seed: u64,
    /// Number of frames.
    pub frames: usize,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Renderer version (bumped whenever output changes).
    pub renderer: u32,
    /// Lens distortion the frames were rendered with (absent: a pinhole camera).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distortion: Option<supermvo_dataset::Distortion>,
    /// Length of the camera's path, metres.
    pub path_length_m: f64,
}

/// Bumped whenever the renderer's output for a given manifest changes: a cached sequence is
/// reused only when its manifest, this number included, is the same. (2: the anisotropic
/// texture filtering, which version 1's caches predate.)
pub const RENDERER_VERSION: u32 = 2;

/// Where a sequence was written.
#[derive(Debug, Clone)]
pub struct Written {
    /// The sequence directory (`ROOT/sequences/NAME`).
    pub sequence_dir: PathBuf,
    /// The ground-truth file (`ROOT/poses/NAME.txt`).
    pub poses: PathBuf,
    /// Whether an identical sequence was already there and nothing was rendered.
    pub reused: bool,
}

/// A preset, a camera, a number of frames and a seed.
#[derive(Debug, Clone)]
pub struct Sequence {
    /// The preset.
    pub preset: Preset,
    /// The camera.
    pub camera: CameraModel,
    /// Number of frames.
    pub frames: usize,
    /// Seed.
    pub seed: u64,
    /// Lens distortion of the rendered frames ([`Sequence::with_distortion`]).
    pub distortion: supermvo_dataset::Distortion,
    lens: Option<std::sync::Arc<render::LensMap>>,
    wobble: [f64; 8],
}

impl Sequence {
    /// Preset `name` with `seed`, `frames` frames (the preset's default if `None`), seen by
    /// `camera`.
    pub fn new(
        name: &str,
        seed: u64,
        frames: Option<usize>,
        camera: CameraModel,
    ) -> Result<Self, SynthError> {
        let preset = preset::preset_for(name, seed, frames)
            .ok_or_else(|| SynthError::UnknownPreset(name.into()))?;
        let frames = frames.unwrap_or(preset.default_frames);
        if frames < 2 {
            return Err(SynthError::Invalid(format!(
                "--frames must be at least 2, got {frames}"
            )));
        }
        let (road, d) = (&preset.scene.path, &preset.drive);
        if !road.is_closed() && d.arc_length((frames - 1) as f64 / RATE_HZ) > road.length() {
            let most = (0..frames)
                .take_while(|&i| d.arc_length(i as f64 / RATE_HZ) <= road.length())
                .count();
            return Err(SynthError::Invalid(format!(
                "--frames {frames}: preset {name}'s road is {:.0} m long and ends after {most} \
                 frames at its speed; ask for at most {most} frames (urban-loop drives a \
                 closed block and takes any number)",
                road.length()
            )));
        }
        if camera.width < 16 || camera.height < 16 {
            return Err(SynthError::Invalid(format!(
                "image size {}x{} is too small (at least 16x16)",
                camera.width, camera.height
            )));
        }
        let mut rng = Rng::new(seed, 99);
        let wobble = std::array::from_fn(|_| rng.range(0.0, std::f64::consts::TAU));
        Ok(Self {
            preset,
            camera,
            frames,
            seed,
            distortion: supermvo_dataset::Distortion::None,
            lens: None,
            wobble,
        })
    }

    /// The same sequence seen through a lens with `distortion` (of the camera's normalised
    /// coordinates, same intrinsics): each frame is rendered for the pinhole camera and
    /// resampled where the lens puts each pixel, and a `camera.yaml` describing the lens is
    /// written beside `calib.txt`.
    pub fn with_distortion(mut self, distortion: supermvo_dataset::Distortion) -> Self {
        self.distortion = distortion;
        self.lens = render::LensMap::new(&self.camera, &distortion).map(std::sync::Arc::new);
        self
    }

    /// Time of frame `i`, seconds.
    pub fn time(&self, i: usize) -> f64 {
        i as f64 / RATE_HZ
    }

    /// The camera's pose in the world at frame `i`: rotation (columns are the camera's
    /// right, down and forward axes) and position.
    pub fn world_from_camera(&self, i: usize) -> (Matrix3<f64>, V3) {
        let t = self.time(i);
        let d = &self.preset.drive;
        let (p, tan) = self.preset.scene.path.offset(d.arc_length(t), d.lateral);
        let pan = d.pan_at(t);
        let heading = tan.y.atan2(tan.x);
        let (sh, ch) = heading.sin_cos();
        let base = Matrix3::from_columns(&[
            V3::new(sh, -ch, 0.0),
            V3::new(0.0, 0.0, -1.0),
            V3::new(ch, sh, 0.0),
        ]);
        // Small suspension and steering motion, as a real car has.
        let w = &self.wobble;
        let deg = std::f64::consts::PI / 180.0;
        let pitch = 0.3 * deg * (2.0 * std::f64::consts::PI * 0.7 * t + w[0]).sin();
        let yaw = 0.25 * deg * (2.0 * std::f64::consts::PI * 0.3 * t + w[1]).sin() + pan;
        let roll = 0.2 * deg * (2.0 * std::f64::consts::PI * 0.5 * t + w[2]).sin();
        // (the bounce follows the moving time: a stopped car's camera only turns)
        let bounce = 0.015 * (2.0 * std::f64::consts::PI * 1.1 * d.moving_time(t) + w[3]).sin();
        let r = base
            * Rotation3::from_axis_angle(&V3::x_axis(), pitch).into_inner()
            * Rotation3::from_axis_angle(&V3::y_axis(), yaw).into_inner()
            * Rotation3::from_axis_angle(&V3::z_axis(), roll).into_inner();
        (r, V3::new(p.x, p.y, d.height + bounce))
    }

    /// Ground truth of frame `i`: `T_cam0_cam`, the KITTI convention (frame 0 is identity).
    pub fn ground_truth(&self, i: usize) -> Pose {
        let (r0, t0) = self.world_from_camera(0);
        let (r, t) = self.world_from_camera(i);
        Pose::new(r0.transpose() * r, r0.transpose() * (t - t0))
    }

    /// A world point expressed in the ground-truth frame (the first camera's).
    pub fn world_to_ground_truth_frame(&self, p: &V3) -> V3 {
        let (r0, t0) = self.world_from_camera(0);
        r0.transpose() * (p - t0)
    }

    /// Exposure gain at frame `i`.
    pub fn gain(&self, i: usize) -> f32 {
        match self.preset.photometry {
            Photometry::Steady => 1.0,
            Photometry::Changing => {
                let t = self.time(i);
                let drift =
                    1.0 + 0.35 * (2.0 * std::f64::consts::PI * t / 6.0 + self.wobble[4]).sin();
                // Every 2.5 s the exposure jumps (up or down) and stays for the next stretch.
                let stretch = (t / 2.5).floor() as i64;
                let jump = 0.6 + 0.8 * noise::hash2(stretch, 0, self.seed) as f64;
                (drift * jump) as f32
            }
        }
    }

    /// Renders frame `i` (through the lens, when there is one).
    pub fn render(&self, i: usize) -> Frame {
        let pinhole = self.render_pinhole(i);
        match &self.lens {
            Some(lens) => lens.apply(&pinhole),
            None => pinhole,
        }
    }

    /// Renders frame `i` for the pinhole camera.
    fn render_pinhole(&self, i: usize) -> Frame {
        let (r, t) = self.world_from_camera(i);
        render::render(
            &self.preset.scene,
            &self.camera,
            &r,
            &t,
            self.time(i),
            Exposure {
                gain: self.gain(i),
                noise: 1.5,
                frame: i as u64 ^ self.seed.rotate_left(17),
            },
        )
    }

    /// Length of the camera's path, metres.
    pub fn path_length(&self) -> f64 {
        let d = &self.preset.drive;
        d.speed.abs() * d.moving_time(self.time(self.frames - 1))
    }

    /// Centres of the painted dashes of the dashed lane lines, in the world frame (the
    /// renderer's test points).
    pub fn dash_centres(&self) -> Vec<V3> {
        let road = &self.preset.scene.road;
        let path = &self.preset.scene.path;
        let period = road.dash.0 + road.dash.1;
        let n = (path.length() / period).floor() as usize;
        let mut out = Vec::new();
        for k in 0..n {
            let s = k as f64 * period + road.dash.0 / 2.0;
            for &lateral in &road.dashed {
                let (p, _) = path.offset(s, lateral);
                out.push(V3::new(p.x, p.y, 0.0));
            }
        }
        out
    }

    /// The manifest of this sequence.
    pub fn manifest(&self) -> Manifest {
        Manifest {
            preset: self.preset.name.to_string(),
            seed: self.seed,
            frames: self.frames,
            width: self.camera.width,
            height: self.camera.height,
            renderer: RENDERER_VERSION,
            path_length_m: self.path_length(),
            distortion: (self.distortion != supermvo_dataset::Distortion::None)
                .then_some(self.distortion),
        }
    }

    /// Writes the sequence under `root` (KITTI layout) with `threads` rendering threads,
    /// calling `progress(done)` after each frame. An identical sequence already there (same
    /// manifest, every frame present) is reused unless `force`.
    pub fn write(
        &self,
        root: &Path,
        threads: usize,
        force: bool,
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<Written, SynthError> {
        let name = self.preset.name;
        let seq_dir = root.join("sequences").join(name);
        let img_dir = seq_dir.join("image_0");
        let poses_dir = root.join("poses");
        let poses = poses_dir.join(format!("{name}.txt"));
        let manifest_path = seq_dir.join("synth.json");
        let frame_path = |i: usize| img_dir.join(format!("{i:06}.png"));
        let written = Written {
            sequence_dir: seq_dir.clone(),
            poses: poses.clone(),
            reused: true,
        };
        if !force && self.already_written(&manifest_path, &poses, &frame_path) {
            progress(self.frames);
            return Ok(written);
        }
        for d in [&img_dir, &poses_dir] {
            std::fs::create_dir_all(d).map_err(io_err(d))?;
        }
        // Stale frames of a longer earlier render would be read as part of this sequence.
        let _ = std::fs::remove_file(&manifest_path);
        for entry in std::fs::read_dir(&img_dir)
            .map_err(io_err(&img_dir))?
            .flatten()
        {
            let p = entry.path();
            if p.extension().is_some_and(|e| e == "png") {
                std::fs::remove_file(&p).map_err(io_err(&p))?;
            }
        }
        let next = AtomicUsize::new(0);
        let done = AtomicUsize::new(0);
        let failure: Mutex<Option<SynthError>> = Mutex::new(None);
        std::thread::scope(|scope| {
            for _ in 0..threads.max(1) {
                scope.spawn(|| loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= self.frames || failure.lock().map(|f| f.is_some()).unwrap_or(true) {
                        break;
                    }
                    let frame = self.render(i);
                    let path = frame_path(i);
                    if let Err(e) = image::save_buffer(
                        &path,
                        &frame.gray,
                        frame.width as u32,
                        frame.height as u32,
                        image::ExtendedColorType::L8,
                    ) {
                        if let Ok(mut f) = failure.lock() {
                            f.get_or_insert(SynthError::Png {
                                path,
                                message: e.to_string(),
                            });
                        }
                        break;
                    }
                    progress(done.fetch_add(1, Ordering::Relaxed) + 1);
                });
            }
        });
        if let Some(e) = failure.into_inner().ok().flatten() {
            return Err(e);
        }
        let c = &self.camera;
        let calib = format!(
            "P0: {:.12e} 0.000000000000e+00 {:.12e} 0.000000000000e+00 0.000000000000e+00 {:.12e} {:.12e} 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00\n",
            c.fx, c.cx, c.fy, c.cy
        );
        let calib_path = seq_dir.join("calib.txt");
        std::fs::write(&calib_path, calib).map_err(io_err(&calib_path))?;
        let camera_path = seq_dir.join("camera.yaml");
        let _ = std::fs::remove_file(&camera_path);
        if let Some(yaml) = self.camera_yaml() {
            std::fs::write(&camera_path, yaml).map_err(io_err(&camera_path))?;
        }
        let times: String = (0..self.frames)
            .map(|i| format!("{:.6e}\n", self.time(i)))
            .collect();
        let times_path = seq_dir.join("times.txt");
        std::fs::write(&times_path, times).map_err(io_err(&times_path))?;
        let traj = supermvo_dataset::Trajectory {
            stamps: Some((0..self.frames).map(|i| self.time(i)).collect()),
            poses: (0..self.frames).map(|i| self.ground_truth(i)).collect(),
            quaternions: None,
        };
        supermvo_dataset::write_trajectory(
            &poses,
            supermvo_dataset::TrajectoryFormat::Kitti,
            &traj,
        )?;
        let json = serde_json::to_string_pretty(&self.manifest())
            .map_err(|e| SynthError::Invalid(format!("manifest: {e}")))?;
        std::fs::write(&manifest_path, json).map_err(io_err(&manifest_path))?;
        Ok(Written {
            reused: false,
            ..written
        })
    }

    /// The lens as an ORB-SLAM3-style camera file (`None` for a pinhole camera).
    fn camera_yaml(&self) -> Option<String> {
        let c = &self.camera;
        let head = format!(
            "%YAML:1.0\n# written by supermvo synth: the lens the frames were rendered with\n\
             Camera.width: {}\nCamera.height: {}\nCamera.fx: {}\nCamera.fy: {}\nCamera.cx: {}\nCamera.cy: {}\n",
            c.width, c.height, c.fx, c.fy, c.cx, c.cy
        );
        match self.distortion {
            supermvo_dataset::Distortion::None => None,
            supermvo_dataset::Distortion::RadTan([k1, k2, p1, p2, k3]) => Some(format!(
                "{head}Camera.type: \"PinHole\"\nCamera.k1: {k1}\nCamera.k2: {k2}\nCamera.p1: {p1}\nCamera.p2: {p2}\nCamera.k3: {k3}\n"
            )),
            supermvo_dataset::Distortion::Equidistant([k1, k2, k3, k4]) => Some(format!(
                "{head}Camera.type: \"KannalaBrandt8\"\nCamera.k1: {k1}\nCamera.k2: {k2}\nCamera.k3: {k3}\nCamera.k4: {k4}\n"
            )),
            supermvo_dataset::Distortion::Fov(w) => {
                Some(format!("{head}Camera.type: \"FOV\"\nCamera.omega: {w}\n"))
            }
        }
    }

    fn already_written(
        &self,
        manifest: &Path,
        poses: &Path,
        frame_path: &dyn Fn(usize) -> PathBuf,
    ) -> bool {
        let Ok(text) = std::fs::read_to_string(manifest) else {
            return false;
        };
        let Ok(m) = serde_json::from_str::<Manifest>(&text) else {
            return false;
        };
        m == self.manifest() && poses.is_file() && (0..self.frames).all(|i| frame_path(i).is_file())
    }
}
