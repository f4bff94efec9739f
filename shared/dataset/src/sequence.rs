//! A sequence of frames on disk, in any of the layouts `supermvo run` reads:
//!
//! ```text
//! KITTI      DIR/calib.txt ("P0: ..."), DIR/times.txt, DIR/image_0/*.png (or image_2)
//! EuRoC      DIR/mav0/cam0/data.csv ("#timestamp [ns],filename"), .../data/*.png, .../sensor.yaml
//!            (DIR may also be mav0/ or cam0/ itself)
//! TUM RGB-D  DIR/rgb.txt ("timestamp filename" lines, '#' comments), DIR/rgb/*.png
//! TUM monoVO DIR/images/*.jpg|png, DIR/times.txt ("id time exposure"), DIR/camera.txt (FOV)
//! images     DIR/*.png|jpg in natural order, with DIR/times.txt (seconds, one a line) or
//!            10 Hz assumed
//! video      FILE.mp4|mkv|avi|mov|webm|m4v|mpg, decoded by ffmpeg, its presentation times;
//!            the camera in --camera, FILE's stem + .yaml, or camera.yaml beside it
//! ```
//!
//! A camera file (`--camera`, or `camera.yaml` in DIR; EuRoC's `sensor.yaml` by default)
//! gives the intrinsics and lens distortion, and takes precedence over KITTI's `calib.txt`
//! (`supermvo synth --distortion` writes one beside it); distorted
//! frames are remapped to a pinhole camera as they are loaded ([`Sequence::load_frame`]).

use crate::camera::{Camera, Undistorter};
use crate::kitti::{image_files, read_times};
use crate::trajectory::{read_trajectory, Trajectory, TrajectoryFormat};
use crate::video::{is_video, Video};
use crate::{Calibration, DatasetError, GrayImage};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Which layout a sequence was read from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// KITTI odometry.
    Kitti,
    /// EuRoC MAV (`mav0/cam0`).
    Euroc,
    /// TUM RGB-D (`rgb.txt`).
    Tum,
    /// TUM monoVO (`camera.txt`, `images/`).
    TumMono,
    /// A folder of images.
    Images,
    /// A video file.
    Video,
}

/// One sequence of frames on disk (see the module docs).
#[derive(Debug, Clone)]
pub struct Sequence {
    /// The sequence directory (`.../sequences/NN` for KITTI; the file, for a video).
    pub dir: PathBuf,
    /// Pinhole intrinsics of the frames as [`Sequence::load_frame`] returns them.
    pub calib: Calibration,
    /// Timestamp of each frame, seconds.
    pub times: Vec<f64>,
    /// Image file of each frame, in order (none for a video: see [`Sequence::len`]).
    pub images: Vec<PathBuf>,
    /// The layout it was read from.
    pub layout: Layout,
    /// The remap of distorted frames, when the camera has distortion.
    undistort: Option<Arc<Undistorter>>,
    /// Whether [`Sequence::load_frame`] remaps distorted frames (the default) or returns
    /// them as recorded, for keypoints undistorted after extraction.
    remap: bool,
    /// The decoder of a video.
    video: Option<Arc<Video>>,
}

impl Sequence {
    /// Opens `dir` in whichever layout it has (module docs), with the camera file `camera`
    /// when given (it replaces KITTI's `calib.txt` and EuRoC's `sensor.yaml`).
    pub fn open_with_camera(dir: &Path, camera: Option<&Path>) -> Result<Self, DatasetError> {
        if is_video(dir) {
            return Self::open_video(dir, camera);
        }
        if !dir.is_dir() {
            return Err(DatasetError::invalid(dir, "sequence directory not found"));
        }
        if let Some(cam0) = euroc_camera_dir(dir) {
            let data = cam0.join("data.csv");
            let (times, images) = read_euroc_list(&data, &cam0.join("data"))?;
            let camera = Camera::read(camera.unwrap_or(&cam0.join("sensor.yaml")))?;
            return Self::with_camera(dir, Layout::Euroc, times, images, &camera);
        }
        if dir.join("rgb.txt").is_file() {
            let (times, images) = read_tum_list(&dir.join("rgb.txt"), dir)?;
            let camera = Camera::read(&camera_file(dir, camera, "TUM RGB-D")?)?;
            return Self::with_camera(dir, Layout::Tum, times, images, &camera);
        }
        if crate::tum_mono::is_tum_mono(dir) {
            let images = image_files(&dir.join("images"))?;
            let times = crate::tum_mono::read_times(&dir.join("times.txt"))?;
            if times.len() != images.len() {
                return Err(DatasetError::invalid(
                    dir.join("times.txt"),
                    format!(
                        "{} timestamps but {} images in images/",
                        times.len(),
                        images.len()
                    ),
                ));
            }
            let first = images
                .first()
                .ok_or_else(|| DatasetError::invalid(dir, "no frames in images/"))?;
            let camera = match camera {
                Some(p) => Camera::read(p)?,
                None => {
                    let img = GrayImage::load(first)?;
                    crate::tum_mono::read_camera(&dir.join("camera.txt"), (img.width, img.height))?
                }
            };
            return Self::with_camera(dir, Layout::TumMono, times, images, &camera);
        }
        let kitti = dir.join("image_0").is_dir() || dir.join("image_2").is_dir();
        if kitti {
            let mut seq = Self::open(dir)?;
            // a camera file (given, or camera.yaml beside calib.txt) describes the lens
            let beside = Some(dir.join("camera.yaml")).filter(|p| p.is_file());
            if let Some(path) = camera.map(Path::to_path_buf).or(beside) {
                let camera = Camera::read(&path)?;
                seq = Self::with_camera(dir, Layout::Kitti, seq.times, seq.images, &camera)?;
            }
            return Ok(seq);
        }
        let images = image_files(dir)?;
        if images.is_empty() {
            return Err(DatasetError::invalid(
                dir,
                "no frames: expected a KITTI (image_0/), EuRoC (mav0/cam0/data.csv) or TUM (rgb.txt) layout, or PNG/JPEG images",
            ));
        }
        let times_path = dir.join("times.txt");
        let times = if times_path.is_file() {
            read_times(&times_path)?
        } else {
            // no timestamps: 10 Hz, as the module docs and docs/usage.md say
            (0..images.len()).map(|i| i as f64 * 0.1).collect()
        };
        if times.len() != images.len() {
            return Err(DatasetError::invalid(
                &times_path,
                format!("{} timestamps but {} images", times.len(), images.len()),
            ));
        }
        let camera = Camera::read(&camera_file(dir, camera, "an image folder")?)?;
        Self::with_camera(dir, Layout::Images, times, images, &camera)
    }

    /// A video file seen through `camera` (or the camera file beside it).
    fn open_video(file: &Path, camera: Option<&Path>) -> Result<Self, DatasetError> {
        let beside = [
            file.with_extension("yaml"),
            file.with_file_name("camera.yaml"),
        ]
        .into_iter()
        .find(|p| p.is_file());
        let path = camera.map(Path::to_path_buf).or(beside).ok_or_else(|| {
            DatasetError::invalid(
                file,
                "a video needs a camera file: give --camera FILE.yaml (ORB-SLAM3 or EuRoC style) or put one beside it (same name with .yaml, or camera.yaml)",
            )
        })?;
        let camera = Camera::read(&path)?;
        let video = Video::open(file)?;
        let (w, h) = camera.size.unwrap_or(video.size);
        let undistort = (camera.distortion != crate::camera::Distortion::None)
            .then(|| Undistorter::new(&camera, w, h).map(Arc::new))
            .flatten();
        Ok(Self {
            dir: file.to_path_buf(),
            calib: camera.calib,
            times: video.stamps.clone(),
            images: Vec::new(),
            layout: Layout::Video,
            undistort,
            remap: true,
            video: Some(Arc::new(video)),
        })
    }

    /// Frames in the sequence.
    pub fn len(&self) -> usize {
        self.times.len()
    }

    /// Whether it has no frames.
    pub fn is_empty(&self) -> bool {
        self.times.is_empty()
    }

    /// A sequence of `images` at `times` seen through `camera`.
    fn with_camera(
        dir: &Path,
        layout: Layout,
        times: Vec<f64>,
        images: Vec<PathBuf>,
        camera: &Camera,
    ) -> Result<Self, DatasetError> {
        let first = images
            .first()
            .ok_or_else(|| DatasetError::invalid(dir, "no frames listed"))?;
        let undistort = if camera.distortion == crate::camera::Distortion::None {
            None
        } else {
            let (w, h) = match camera.size {
                Some(size) => size,
                None => {
                    let img = GrayImage::load(first)?;
                    (img.width, img.height)
                }
            };
            Undistorter::new(camera, w, h).map(Arc::new)
        };
        Ok(Self {
            dir: dir.to_path_buf(),
            calib: camera.calib,
            times,
            images,
            layout,
            undistort,
            remap: true,
            video: None,
        })
    }

    /// Frame `i`, remapped to the pinhole camera [`Sequence::calib`] when the lens distorts.
    pub fn load_frame(&self, i: usize) -> Result<GrayImage, DatasetError> {
        let remap = self.undistort.as_ref().filter(|_| self.remap);
        if let Some(v) = &self.video {
            let img = v.frame(i)?;
            return match remap {
                Some(u) => u.apply(&img, &self.dir),
                None => Ok(img),
            };
        }
        let path = self
            .images
            .get(i)
            .ok_or_else(|| DatasetError::invalid(&self.dir, format!("no frame {i}")))?;
        let img = GrayImage::load(path)?;
        match remap {
            Some(u) => u.apply(&img, path),
            None => Ok(img),
        }
    }

    /// The camera of a lens with distortion (`None` for a pinhole camera): what keypoints
    /// found on frames that were not remapped are undistorted with
    /// ([`Camera::undistort_pixel`]).
    pub fn lens(&self) -> Option<&Camera> {
        self.undistort.as_deref().map(Undistorter::camera)
    }

    /// A frame as [`Sequence::load_frame`] gave it, remapped to the pinhole camera its
    /// undistorted keypoints live in, for views that draw them on it; `None` when the frames
    /// already load as pinhole images (no lens, or remapped as they load).
    pub fn pinhole_view(&self, img: &GrayImage) -> Option<GrayImage> {
        let u = self.undistort.as_ref().filter(|_| !self.remap)?;
        u.apply(img, &self.dir).ok()
    }

    /// Whether [`Sequence::load_frame`] remaps distorted frames to the pinhole camera (true,
    /// the default) or returns them as recorded (false: the keypoints found on them are
    /// undistorted instead, which resamples nothing).
    pub fn set_remap_frames(&mut self, remap: bool) {
        self.remap = remap;
    }

    /// Opens a KITTI sequence `dir` (a `sequences/NN` directory), using `image_0` (or
    /// `image_2` if absent).
    ///
    /// Checks that `times.txt` has one line per image.
    pub fn open(dir: &Path) -> Result<Self, DatasetError> {
        if !dir.is_dir() {
            return Err(DatasetError::invalid(dir, "sequence directory not found"));
        }
        let calib = Calibration::read_kitti(&dir.join("calib.txt"))?;
        let times_path = dir.join("times.txt");
        let times = read_times(&times_path)?;
        let img_dir = ["image_0", "image_2"]
            .iter()
            .map(|d| dir.join(d))
            .find(|d| d.is_dir())
            .ok_or_else(|| {
                DatasetError::invalid(dir, "no image_0/ or image_2/ directory with the frames")
            })?;
        let images = image_files(&img_dir)?;
        if images.is_empty() {
            return Err(DatasetError::invalid(
                &img_dir,
                "no PNG or JPEG frames found",
            ));
        }
        if images.len() != times.len() {
            return Err(DatasetError::invalid(
                &times_path,
                format!(
                    "{} timestamps but {} images in {}",
                    times.len(),
                    images.len(),
                    img_dir.display()
                ),
            ));
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            calib,
            times,
            images,
            layout: Layout::Kitti,
            undistort: None,
            remap: true,
            video: None,
        })
    }

    /// Sequence name (the directory name, e.g. `00`; a video's file stem).
    pub fn name(&self) -> String {
        let name = match self.layout {
            Layout::Video => self.dir.file_stem(),
            _ => self.dir.file_name(),
        };
        name.map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    }

    /// Where the conventional ground-truth file `../../poses/NN.txt` would be (`None` when
    /// the sequence directory has no grandparent).
    pub fn ground_truth_candidate(&self) -> Option<PathBuf> {
        let root = self.dir.parent()?.parent()?;
        Some(root.join("poses").join(format!("{}.txt", self.name())))
    }

    /// The conventional ground-truth file `../../poses/NN.txt`, if it exists.
    pub fn default_ground_truth(&self) -> Option<PathBuf> {
        self.ground_truth_candidate().filter(|p| p.is_file())
    }

    /// Reads ground truth (KITTI poses) and attaches this sequence's timestamps; the
    /// number of poses must equal the number of frames.
    pub fn read_ground_truth(&self, path: &Path) -> Result<Trajectory, DatasetError> {
        let mut gt = read_trajectory(path, TrajectoryFormat::Kitti)?;
        if gt.len() != self.times.len() {
            return Err(DatasetError::invalid(
                path,
                format!(
                    "{} poses but the sequence has {} frames",
                    gt.len(),
                    self.times.len()
                ),
            ));
        }
        gt.stamps = Some(self.times.clone());
        Ok(gt)
    }
}

/// The EuRoC camera folder (holding `data.csv`) under `dir`: `dir/mav0/cam0`, `dir/cam0`
/// or `dir` itself.
fn euroc_camera_dir(dir: &Path) -> Option<PathBuf> {
    [dir.join("mav0/cam0"), dir.join("cam0"), dir.to_path_buf()]
        .into_iter()
        .find(|d| d.join("data.csv").is_file() && d.join("data").is_dir())
}

/// The camera file for a layout without its own: `--camera`, or `camera.yaml` in `dir`.
fn camera_file(dir: &Path, given: Option<&Path>, layout: &str) -> Result<PathBuf, DatasetError> {
    if let Some(p) = given {
        return Ok(p.to_path_buf());
    }
    let default = dir.join("camera.yaml");
    if default.is_file() {
        return Ok(default);
    }
    Err(DatasetError::invalid(
        dir,
        format!("{layout} needs a camera file: give --camera FILE.yaml (ORB-SLAM3 or EuRoC style) or put camera.yaml in the folder"),
    ))
}

/// EuRoC `data.csv`: `timestamp [ns],filename` lines after a `#` header.
fn read_euroc_list(csv: &Path, data: &Path) -> Result<(Vec<f64>, Vec<PathBuf>), DatasetError> {
    read_frame_list(csv, data, "'timestamp [ns],filename'", |line| {
        let (t, name) = line.split_once(',')?;
        let ns: u64 = t.trim().parse().ok()?;
        Some((ns as f64 * 1e-9, name.trim()))
    })
}

/// TUM `rgb.txt`: `timestamp filename` lines, `#` comments.
fn read_tum_list(list: &Path, dir: &Path) -> Result<(Vec<f64>, Vec<PathBuf>), DatasetError> {
    read_frame_list(list, dir, "'timestamp filename' (seconds)", |line| {
        let mut f = line.split_whitespace();
        let (t, name) = (f.next()?, f.next()?);
        Some((t.parse().ok()?, name))
    })
}

/// A list of frames, one `(timestamp in seconds, file name under base)` per line as `parse`
/// reads it; blank lines and `#` comments skipped, a line `parse` refuses reported with its
/// number and the `expected` form.
fn read_frame_list(
    list: &Path,
    base: &Path,
    expected: &str,
    parse: impl Fn(&str) -> Option<(f64, &str)>,
) -> Result<(Vec<f64>, Vec<PathBuf>), DatasetError> {
    let text = std::fs::read_to_string(list).map_err(|e| DatasetError::io(list, e))?;
    let mut times = Vec::new();
    let mut images = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let (t, name) = parse(line).ok_or_else(|| {
            DatasetError::parse(list, i + 1, format!("'{line}': expected {expected}"))
        })?;
        times.push(t);
        images.push(base.join(name));
    }
    Ok((times, images))
}
