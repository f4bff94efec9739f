//! The synthetic world of the tracker's tests, where every error source is known: a camera
//! drives forward at 1 m per frame through a field of points (60 frames straight, a
//! 90-degree turn over 30 frames, straight again), every point with its own random
//! descriptor; matches to the reference keyframe are right by construction except for a
//! fraction replaced by random wrong ones; keypoints carry Gaussian noise, 30 % of them four
//! times as much (a heavy tail). `run*` drive the tracker through it, `scale_*` measure the
//! trajectory's scale (estimated / true distance over steps of frames).
#![allow(dead_code, unused_imports)] // each test binary uses a part

pub use std::cell::{Cell, RefCell};
pub use std::rc::Rc;
pub use supermvo_dataset::Calibration;
pub use supermvo_geometry::{Mat3, Vec3};
pub use supermvo_inference::{Features, Matches};
pub use supermvo_vo::ba::{BaOutcome, LocalBa};
pub use supermvo_vo::mapping_solver::{MappingSolver, TriangulationBatch};
pub use supermvo_vo::tracker::{FrameMeta, LensResidual, Tracker, TrackerConfig};

/// Whether the long statistical runs (the full tier) run: `tools/test.sh`, the README's test
/// command, sets `SUPERMVO_LONG_TESTS=1`; plain `cargo test` prints that it skips `name`, so
/// that the crate's own tests take about a minute.
pub fn long_tests(name: &str) -> bool {
    let on = std::env::var("SUPERMVO_LONG_TESTS").as_deref() == Ok("1");
    if !on {
        println!(
            "skipped {name}: a long run of the full tier (SUPERMVO_LONG_TESTS=1, tools/test.sh)"
        );
    }
    on
}

/// xorshift64: deterministic across platforms.
pub struct Rng(pub u64);
impl Rng {
    pub fn u(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn gauss(&mut self) -> f64 {
        let (a, b) = (self.u().max(1e-300), self.u());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }
}

pub const W: usize = 1241;
pub const H: usize = 376;
pub const STRAIGHT: usize = 60;
pub const TURN: usize = 30;
pub const FRAMES: usize = 160;

pub fn calib() -> Calibration {
    Calibration {
        fx: 718.856,
        fy: 718.856,
        cx: 607.19,
        cy: 185.22,
    }
}

/// How the camera is driven along the path.
#[derive(Debug, Clone, Copy, Default)]
pub struct Drive {
    /// The camera is mounted this many metres ahead of the point that follows the path (a
    /// car's rear axle): in a turn it then moves sideways as well as forwards, as a car's
    /// camera does (KITTI 03's ground truth: the direction of motion leads the camera's
    /// heading by 7-12 degrees through its slow turn).
    pub lever: f64,
    /// Slow down to 0.3 m per frame over the 10 frames before the turn, take the turn at
    /// that speed (3 degrees per frame, as KITTI's intersection turns) and speed up to 1 m
    /// per frame over the 30 frames after it; 1 m per frame throughout otherwise.
    pub slow_turn: bool,
    /// Frames `blind.0..blind.1` see nothing (a covered lens, a black image): no keypoints.
    pub blind: (usize, usize),
    /// The matcher misses this fraction of the true matches to the reference keyframe, at
    /// random (a learned matcher does not find every correspondence twice in a row).
    pub missed: f64,
    /// 0.3 m per frame over the first 10 frames (a car pulling away), then 1 m per frame.
    pub slow_start: bool,
    /// Frames of the run (0: `FRAMES`); `straight`: no turn, a straight road throughout.
    pub frames: usize,
    pub straight: bool,
    /// Every keypoint with the same Gaussian noise, without the heavy tail.
    pub gaussian: bool,
    /// This frame's matches are all wrong and its descriptors random (a frame the matcher
    /// gets wrong): it agrees neither with the reference keyframe's map nor with the local
    /// map, so tracking fails and a new map starts from the reference keyframe.
    pub scrambled: Option<usize>,
    /// From frame 10 on, frames `k` with `k % dropped.0 < dropped.1` never reach the tracker
    /// (a real-time pipeline that drops frames it cannot take); `(0, 0)`: none.
    pub dropped: (usize, usize),
    /// The keypoints are seen through a lens with this radial coefficient (of normalised
    /// coordinates, `x (1 + k1 |x|^2)`), which the calibration does not know.
    pub lens_k1: f64,
    /// Turns of the drive (0: one), `TURN_PERIOD` frames apart, all the same way.
    pub turns: usize,
}

/// Frames from one turn's start to the next's.
pub const TURN_PERIOD: usize = 130;

impl Drive {
    pub fn frames(&self) -> usize {
        if self.frames == 0 {
            FRAMES
        } else {
            self.frames
        }
    }
    /// Whether frame `i` is in a turn.
    pub fn turning(&self, i: usize) -> bool {
        (0..self.turns.max(1)).any(|n| {
            let a = self.turn_at().saturating_add(n * TURN_PERIOD);
            (a..a.saturating_add(TURN)).contains(&i)
        })
    }
    /// Frame at which the turn starts.
    pub fn turn_at(&self) -> usize {
        if self.straight {
            usize::MAX - TURN
        } else {
            STRAIGHT
        }
    }
}

/// Camera centre and heading (yaw about the camera's y axis, radians) at frame `k`.
pub fn path_with(k: usize, drive: Drive) -> (Vec3, f64) {
    let (c, yaw) = path_axle(k, drive);
    (c + drive.lever * Vec3::new(yaw.sin(), 0.0, yaw.cos()), yaw)
}

pub fn path_axle(k: usize, drive: Drive) -> (Vec3, f64) {
    let mut c = Vec3::zeros();
    let mut yaw = 0.0f64;
    let rate = std::f64::consts::FRAC_PI_2 / TURN as f64;
    for i in 0..k {
        if drive.turning(i) {
            yaw += rate;
        }
        c += speed(i, drive) * Vec3::new(yaw.sin(), 0.0, yaw.cos());
    }
    (c, yaw)
}

/// Metres driven from frame `i` to the next.
pub fn speed(i: usize, drive: Drive) -> f64 {
    if drive.slow_start && i < 10 {
        return 0.3;
    }
    if !drive.slow_turn {
        return 1.0;
    }
    let slow = 0.3;
    let (a, b) = (drive.turn_at() as f64, (drive.turn_at() + TURN) as f64);
    let i = i as f64;
    if i < a - 10.0 {
        1.0
    } else if i < a {
        1.0 - (1.0 - slow) * (i - (a - 10.0)) / 10.0
    } else if i < b {
        slow
    } else if i < b + 30.0 {
        slow + (1.0 - slow) * (i - b) / 30.0
    } else {
        1.0
    }
}

pub fn rot_y(a: f64) -> Mat3 {
    Mat3::new(a.cos(), 0.0, a.sin(), 0.0, 1.0, 0.0, -a.sin(), 0.0, a.cos())
}

pub struct Scene {
    pub points: Vec<Vec3>,
    pub desc: Vec<Vec<f32>>,
}

/// 40 points per metre of path, 3-18 m to either side, from the ground (y = 1.65 m, y
/// points down) to 3.35 m above the camera.
pub fn scene(rng: &mut Rng, drive: Drive) -> Scene {
    let mut points = Vec::new();
    for k in 0..drive.frames() + 80 {
        let (c, yaw) = path_axle(k, drive);
        let r = rot_y(yaw);
        for _ in 0..40 {
            let mut x = rng.u() * 30.0 - 15.0;
            if x.abs() < 3.0 {
                x += 3.0 * x.signum();
            }
            let y = 1.65 - rng.u() * 5.0;
            let z = rng.u() * 2.0 - 1.0;
            points.push(c + r * Vec3::new(x, y, z));
        }
    }
    let desc = (0..points.len())
        .map(|_| {
            let v: Vec<f32> = (0..64).map(|_| rng.gauss() as f32).collect();
            let n = v.iter().map(|a| a * a).sum::<f32>().sqrt();
            v.iter().map(|a| a / n).collect()
        })
        .collect();
    Scene { points, desc }
}

/// Features of frame `k` (points 1-80 m ahead that land in the image, at most 2000) and
/// the point id of each keypoint.
pub fn observe(
    s: &Scene,
    k: usize,
    noise_px: f64,
    drive: Drive,
    rng: &mut Rng,
) -> (Features, Vec<usize>) {
    let c = calib();
    let (centre, yaw) = path_with(k, drive);
    let r_cw = rot_y(yaw).transpose();
    let mut f = Features {
        keypoints: Vec::new(),
        scores: Vec::new(),
        descriptors: Vec::new(),
        dim: 64,
        image_size: (W, H),
    };
    let mut ids = Vec::new();
    for (i, p) in s.points.iter().enumerate() {
        let q = r_cw * (p - centre);
        if q.z < 1.0 || q.z > 80.0 {
            continue;
        }
        let sigma = if rng.u() < 0.3 && !drive.gaussian {
            4.0 * noise_px
        } else {
            noise_px
        };
        let (x, y) = (q.x / q.z, q.y / q.z);
        let lens = 1.0 + drive.lens_k1 * (x * x + y * y);
        let u = c.fx * q.x / q.z * lens + c.cx + sigma * rng.gauss();
        let v = c.fy * q.y / q.z * lens + c.cy + sigma * rng.gauss();
        if u < 0.0 || v < 0.0 || u >= W as f64 || v >= H as f64 || ids.len() == 2000 {
            continue;
        }
        f.keypoints.push([u as f32, v as f32]);
        f.scores.push(1.0);
        f.descriptors.extend_from_slice(&s.desc[i]);
        ids.push(i);
    }
    (f, ids)
}

/// Runs the tracker over the whole path; per frame the estimated camera centre (when
/// posed) and the true one.
pub fn run(
    seed: u64,
    noise_px: f64,
    outliers: f64,
    cfg: TrackerConfig,
) -> Vec<(Option<Vec3>, Vec3)> {
    run_with(seed, noise_px, outliers, cfg, Drive::default())
}

/// [`run`] for a [`Drive`].
pub fn run_with(
    seed: u64,
    noise_px: f64,
    outliers: f64,
    cfg: TrackerConfig,
    drive: Drive,
) -> Vec<(Option<Vec3>, Vec3)> {
    run_counted(seed, noise_px, outliers, cfg, drive).0
}

/// What a run gives: per frame the estimated camera centre (when posed) and the true one;
/// the frames the matcher ran for; per frame the landmarks its pose rests on; the frames
/// posed later, by the initialisation after them, with their centres.
type Counted = (
    Vec<(Option<Vec3>, Vec3)>,
    usize,
    Vec<usize>,
    Vec<(usize, Vec3)>,
);

/// [`run_with`], also counting the frames for which the tracker asked for matches.
pub fn run_counted(
    seed: u64,
    noise_px: f64,
    outliers: f64,
    cfg: TrackerConfig,
    drive: Drive,
) -> Counted {
    run_counted_with(seed, (noise_px, outliers), cfg, drive, |_, _| {})
}

/// [`run_counted`] with `before(k, tracker)` called before each frame `k`.
pub fn run_counted_with(
    seed: u64,
    (noise_px, outliers): (f64, f64),
    cfg: TrackerConfig,
    drive: Drive,
    mut before: impl FnMut(usize, &mut Tracker),
) -> Counted {
    let mut matched = 0;
    let mut tracked = Vec::new();
    let mut backfilled = Vec::new();
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15 ^ seed.wrapping_mul(0x0123_4567));
    let mut match_rng = Rng(12345 + seed);
    let mut miss_rng = Rng(777 + seed);
    let s = scene(&mut rng, drive);
    let mut tracker = Tracker::new(calib(), cfg);
    let mut ids_of: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    let mut out = Vec::new();
    for k in 0..drive.frames() {
        before(k, &mut tracker);
        let (mut f, mut ids) = observe(&s, k, noise_px, drive, &mut rng);
        if k >= 10 && drive.dropped.0 > 0 && k % drive.dropped.0 < drive.dropped.1 {
            continue;
        }
        if (drive.blind.0..drive.blind.1).contains(&k) {
            (f.keypoints, f.scores, f.descriptors, ids) = Default::default();
        }
        let scrambled = drive.scrambled == Some(k);
        if scrambled {
            f.descriptors
                .iter_mut()
                .for_each(|d| *d = match_rng.gauss() as f32);
        }
        let meta = FrameMeta {
            index: k,
            stamp: k as f64 * 0.1,
        };
        if let Some(o) = tracker.track_without_matches(meta, &f) {
            tracked.push(o.inliers);
            ids_of.insert(k, ids);
            out.push((o.t_world_cam.map(|p| p.t), path_with(k, drive).0));
            continue;
        }
        let matches = tracker.reference().map(|(reference, _)| {
            matched += 1;
            let at: std::collections::HashMap<usize, usize> =
                ids.iter().enumerate().map(|(j, &i)| (i, j)).collect();
            let pairs: Vec<(usize, usize)> = ids_of[&reference]
                .iter()
                .enumerate()
                .filter_map(|(a, i)| at.get(i).map(|&b| (a, b)))
                .filter(|_| drive.missed == 0.0 || miss_rng.u() >= drive.missed)
                .map(|(a, b)| {
                    if scrambled || match_rng.u() < outliers {
                        (a, (match_rng.u() * ids.len() as f64) as usize % ids.len())
                    } else {
                        (a, b)
                    }
                })
                .collect();
            Matches {
                scores: vec![1.0; pairs.len()],
                pairs,
            }
        });
        ids_of.insert(k, ids);
        let o = tracker.step(meta, f, matches.as_ref());
        tracked.push(o.inliers);
        backfilled.extend(o.backfilled.iter().map(|l| (l.index, l.t_world_cam.t)));
        let est = o.t_world_cam.map(|p| p.t);
        out.push((est, path_with(k, drive).0));
    }
    (out, matched, tracked, backfilled)
}

/// Estimated / true distance over consecutive 10-frame steps, from 5 frames after the
/// initialisation on.
pub fn scale_steps(traj: &[(Option<Vec3>, Vec3)]) -> Vec<f64> {
    scale_over(traj, 10)
}

/// Estimated / true distance over consecutive `step`-frame stretches, from 5 frames after
/// the initialisation on (NaN where either end has no pose).
pub fn scale_over(traj: &[(Option<Vec3>, Vec3)], step: usize) -> Vec<f64> {
    let first = traj.iter().rposition(|t| t.0.is_none()).unwrap_or(0) + 5;
    (first..traj.len().saturating_sub(step))
        .step_by(step)
        .map(|a| match (traj[a].0, traj[a + step].0) {
            (Some(ea), Some(eb)) => (eb - ea).norm() / (traj[a + step].1 - traj[a].1).norm(),
            _ => f64::NAN,
        })
        .collect()
}

/// Largest relative change of the scale from its first step.
pub fn worst_change(steps: &[f64]) -> f64 {
    steps
        .iter()
        .map(|s| (s / steps[0] - 1.0).abs())
        .fold(0.0, f64::max)
}
