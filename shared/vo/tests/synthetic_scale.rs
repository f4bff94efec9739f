#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
//! The tracker on synthetic features, where every error source is known: a camera drives
//! forward at 1 m per frame through a field of points (60 frames straight, a 90-degree
//! turn over 30 frames, straight again), every point with its own random descriptor;
//! matches to the reference keyframe are right by construction except for a fraction
//! replaced by random wrong ones; keypoints carry Gaussian noise, 30 % of them four times
//! as much (a heavy tail). Measures the trajectory's scale (estimated / true distance over
//! 10-frame steps) along the run.

use std::cell::{Cell, RefCell};
use std::rc::Rc;
use supermvo_dataset::Calibration;
use supermvo_geometry::{Mat3, Vec3};
use supermvo_inference::{Features, Matches};
use supermvo_vo::ba::{BaOutcome, BaSolver, LocalBa};
use supermvo_vo::tracker::{FrameMeta, Tracker, TrackerConfig};

/// xorshift64: deterministic across platforms.
struct Rng(u64);
impl Rng {
    fn u(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn gauss(&mut self) -> f64 {
        let (a, b) = (self.u().max(1e-300), self.u());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }
}

const W: usize = 1241;
const H: usize = 376;
const STRAIGHT: usize = 60;
const TURN: usize = 30;
const FRAMES: usize = 160;

fn calib() -> Calibration {
    Calibration {
        fx: 718.856,
        fy: 718.856,
        cx: 607.19,
        cy: 185.22,
    }
}

/// How the camera is driven along the path.
#[derive(Debug, Clone, Copy, Default)]
struct Drive {
    /// The camera is mounted this many metres ahead of the point that follows the path (a
    /// car's rear axle): in a turn it then moves sideways as well as forwards, as a car's
    /// camera does (KITTI 03's ground truth: the direction of motion leads the camera's
    /// heading by 7-12 degrees through its slow turn).
    lever: f64,
    /// Slow down to 0.3 m per frame over the 10 frames before the turn, take the turn at
    /// that speed (3 degrees per frame, as KITTI's intersection turns) and speed up to 1 m
    /// per frame over the 30 frames after it; 1 m per frame throughout otherwise.
    slow_turn: bool,
    /// Frames `blind.0..blind.1` see nothing (a covered lens, a black image): no keypoints.
    blind: (usize, usize),
    /// The matcher misses this fraction of the true matches to the reference keyframe, at
    /// random (a learned matcher does not find every correspondence twice in a row).
    missed: f64,
    /// 0.3 m per frame over the first 10 frames (a car pulling away), then 1 m per frame.
    slow_start: bool,
    /// Frames of the run (0: `FRAMES`); `straight`: no turn, a straight road throughout.
    frames: usize,
    straight: bool,
    /// Every keypoint with the same Gaussian noise, without the heavy tail.
    gaussian: bool,
    /// From frame 10 on, frames `k` with `k % dropped.0 < dropped.1` never reach the tracker
    /// (a real-time pipeline that drops frames it cannot take); `(0, 0)`: none.
    dropped: (usize, usize),
}

impl Drive {
    fn frames(&self) -> usize {
        if self.frames == 0 {
            FRAMES
        } else {
            self.frames
        }
    }
    /// Frame at which the turn starts.
    fn turn_at(&self) -> usize {
        if self.straight {
            usize::MAX - TURN
        } else {
            STRAIGHT
        }
    }
}

/// Camera centre and heading (yaw about the camera's y axis, radians) at frame `k`.
fn path_with(k: usize, drive: Drive) -> (Vec3, f64) {
    let (c, yaw) = path_axle(k, drive);
    (c + drive.lever * Vec3::new(yaw.sin(), 0.0, yaw.cos()), yaw)
}

fn path_axle(k: usize, drive: Drive) -> (Vec3, f64) {
    let mut c = Vec3::zeros();
    let mut yaw = 0.0f64;
    let rate = std::f64::consts::FRAC_PI_2 / TURN as f64;
    for i in 0..k {
        if (drive.turn_at()..drive.turn_at() + TURN).contains(&i) {
            yaw += rate;
        }
        c += speed(i, drive) * Vec3::new(yaw.sin(), 0.0, yaw.cos());
    }
    (c, yaw)
}

/// Metres driven from frame `i` to the next.
fn speed(i: usize, drive: Drive) -> f64 {
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

fn rot_y(a: f64) -> Mat3 {
    Mat3::new(a.cos(), 0.0, a.sin(), 0.0, 1.0, 0.0, -a.sin(), 0.0, a.cos())
}

struct Scene {
    points: Vec<Vec3>,
    desc: Vec<Vec<f32>>,
}

/// 40 points per metre of path, 3-18 m to either side, from the ground (y = 1.65 m, y
/// points down) to 3.35 m above the camera.
fn scene(rng: &mut Rng, drive: Drive) -> Scene {
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
fn observe(
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
        let u = c.fx * q.x / q.z + c.cx + sigma * rng.gauss();
        let v = c.fy * q.y / q.z + c.cy + sigma * rng.gauss();
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
fn run(seed: u64, noise_px: f64, outliers: f64, cfg: TrackerConfig) -> Vec<(Option<Vec3>, Vec3)> {
    run_with(seed, noise_px, outliers, cfg, Drive::default())
}

/// [`run`] for a [`Drive`].
fn run_with(
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
fn run_counted(
    seed: u64,
    noise_px: f64,
    outliers: f64,
    cfg: TrackerConfig,
    drive: Drive,
) -> Counted {
    run_counted_with(seed, (noise_px, outliers), cfg, drive, |_, _| {})
}

/// [`run_counted`] with `before(k, tracker)` called before each frame `k`.
fn run_counted_with(
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
                    if match_rng.u() < outliers {
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
fn scale_steps(traj: &[(Option<Vec3>, Vec3)]) -> Vec<f64> {
    scale_over(traj, 10)
}

/// Estimated / true distance over consecutive `step`-frame stretches, from 5 frames after
/// the initialisation on (NaN where either end has no pose).
fn scale_over(traj: &[(Option<Vec3>, Vec3)], step: usize) -> Vec<f64> {
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
fn worst_change(steps: &[f64]) -> f64 {
    steps
        .iter()
        .map(|s| (s / steps[0] - 1.0).abs())
        .fold(0.0, f64::max)
}

/// The geometry keeps one scale: with matches right by construction (plus 10 % random
/// wrong ones) and 0.5 px keypoint noise (2 px for 30 % of the keypoints), the ratio of
/// estimated to true distance stays within 2 % of its first value through the straight,
/// the 90-degree turn and the second straight, with no frame lost, on each of three
/// scenes. (Measured: within 1 % on each. KITTI's scale rises by 10-20 % over
/// runs like this one: docs/vo.md, "Monocular VO".)
#[test]
fn one_scale_through_a_turn_on_synthetic_features() {
    for seed in 0..3 {
        let traj = run(seed, 0.5, 0.1, TrackerConfig::default());
        // frame 0 is the reference (posed), the next frames wait for parallax; every
        // frame from the initialisation on has a pose
        let unposed = traj.iter().rposition(|t| t.0.is_none()).unwrap_or(0);
        assert!(unposed <= 10, "scene {seed}: frame {unposed} has no pose");
        let steps = scale_steps(&traj);
        println!("scene {seed}, scale per 10 frames: {steps:.3?}");
        assert!(steps.len() >= 14, "scene {seed}: {} steps", steps.len());
        let worst = worst_change(&steps);
        assert!(worst < 0.02, "scene {seed}: scale changed by {worst:.4}");
    }
}

/// The matcher runs where geometry cannot guide: the frames between keyframes are tracked
/// by projecting the last frame's landmarks, so it runs on well under all frames (measured:
/// 55 of 160 on each scene), against every frame but the first with `match_every_frame`; the scale holds
/// within 2 % either way.
#[test]
fn frames_between_keyframes_are_tracked_without_the_matcher() {
    for (every, most) in [(false, 0.5), (true, 1.0)] {
        let cfg = TrackerConfig {
            match_every_frame: every,
            ..TrackerConfig::default()
        };
        for seed in 0..3 {
            let (traj, matched, _, _) = run_counted(seed, 0.5, 0.1, cfg.clone(), Drive::default());
            let share = matched as f64 / FRAMES as f64;
            let worst = worst_change(&scale_steps(&traj));
            println!("match_every_frame {every}, scene {seed}: {matched} of {FRAMES} matched, scale within {worst:.4}");
            assert!(share <= most, "scene {seed}: {matched} frames matched");
            if every {
                assert_eq!(matched, FRAMES - 1, "scene {seed}");
            }
            assert!(worst < 0.02, "scene {seed}: scale changed by {worst:.4}");
        }
    }
}

/// A local BA solved elsewhere (as the daemon's back end does) with the same solver gives
/// the trajectory bit for bit, and every window goes through the solver.
#[test]
fn a_local_ba_solved_elsewhere_gives_the_same_trajectory() {
    struct Counting(Rc<Cell<usize>>);
    impl BaSolver for Counting {
        fn solve(&mut self, ba: &mut LocalBa, iterations: usize) -> BaOutcome {
            self.0.set(self.0.get() + 1);
            let (c0, c1) = ba.solve(iterations);
            BaOutcome::Solved(c0, c1)
        }
    }
    let solved = Rc::new(Cell::new(0));
    let mut counter = Some(Counting(solved.clone()));
    let cfg = TrackerConfig::default();
    let here = run_counted(0, 0.5, 0.1, cfg.clone(), Drive::default());
    let there = run_counted_with(0, (0.5, 0.1), cfg, Drive::default(), |_, t| {
        if let Some(c) = counter.take() {
            t.set_ba_solver(Box::new(c));
        }
    });
    println!("{} local BAs solved elsewhere", solved.get());
    assert!(solved.get() >= 5, "{} local BAs", solved.get());
    assert_eq!(here.0, there.0);
    assert_eq!(here.3, there.3);
}

/// Local BAs solved while tracking goes on (the daemon's real-time mode: each window's
/// solution is applied a few frames after its keyframe, unless a newer window replaced it)
/// still hold the scale as the local BA in place does, where the runs without it drift (the
/// test below).
#[test]
fn a_local_ba_applied_frames_later_still_holds_the_scale() {
    /// Frames between a keyframe and its window's solution.
    const LAG: usize = 2;
    /// `(frame asked, id, window)` of the windows handed off, and the frame now.
    type Queue = Rc<RefCell<Vec<(usize, u64, LocalBa)>>>;
    struct Deferring(Queue, Rc<Cell<usize>>, u64);
    impl BaSolver for Deferring {
        fn solve(&mut self, ba: &mut LocalBa, _iterations: usize) -> BaOutcome {
            self.2 += 1;
            self.0.borrow_mut().push((self.1.get(), self.2, ba.clone()));
            BaOutcome::Deferred(self.2)
        }
    }
    for seed in 0..3 {
        let cfg = TrackerConfig::default();
        let (in_place, ..) = run_counted(seed, 0.5, 0.1, cfg.clone(), Drive::default());
        let posed_in_place = in_place.iter().filter(|t| t.0.is_some()).count();
        let (queue, now): (Queue, Rc<Cell<usize>>) = Default::default();
        let mut solver = Some(Deferring(queue.clone(), now.clone(), 0));
        let (mut sent, mut applied) = (0, 0);
        let (traj, ..) = run_counted_with(seed, (0.5, 0.1), cfg, Drive::default(), |k, t| {
            if let Some(s) = solver.take() {
                t.set_ba_solver(Box::new(s));
            }
            now.set(k);
            let (due, waiting) = std::mem::take(&mut *queue.borrow_mut())
                .into_iter()
                .partition(|(asked, ..)| k >= asked + LAG);
            *queue.borrow_mut() = waiting;
            for (_, id, mut ba) in due {
                sent += 1;
                ba.solve(10);
                applied += t.apply_local_ba(id, &ba.poses, &ba.points) as usize;
            }
        });
        let posed = traj.iter().filter(|t| t.0.is_some()).count();
        let worst = worst_change(&scale_steps(&traj));
        let worst_in_place = worst_change(&scale_steps(&in_place));
        println!("scene {seed}: {applied} of {sent} windows applied {LAG} frames later, {posed} of {} posed ({posed_in_place} in place), scale within {worst:.4} ({worst_in_place:.4} in place)", traj.len());
        assert!(
            applied * 2 >= sent && applied >= 5,
            "scene {seed}: {applied} of {sent}"
        );
        assert!(posed >= posed_in_place, "scene {seed}: {posed} posed");
        assert!(worst < 0.02, "scene {seed}: scale changed by {worst:.4}");
    }
}

/// Frames dropped before the tracker (two of every three, as a real-time pipeline that
/// falls behind does): the frames it sees are still posed, most without the matcher, and
/// the scale holds.
#[test]
fn tracking_continues_across_frames_dropped_upstream() {
    let cfg = TrackerConfig {
        match_every_frame: false,
        ..TrackerConfig::default()
    };
    for seed in 0..3 {
        let drive = Drive {
            dropped: (3, 2),
            ..Drive::default()
        };
        let (traj, matched, _, _) = run_counted(seed, 0.5, 0.1, cfg.clone(), drive);
        let seen = traj.len();
        let posed = traj.iter().filter(|t| t.0.is_some()).count();
        let worst = worst_change(&scale_over(&traj, 4));
        println!("scene {seed}: {seen} frames seen, {posed} posed, {matched} matched, scale within {worst:.4}");
        assert!(posed + 3 >= seen, "scene {seed}: {posed} of {seen} posed");
        assert!(
            matched * 2 <= seen,
            "scene {seed}: {matched} of {seen} matched"
        );
        assert!(worst < 0.03, "scene {seed}: scale changed by {worst:.4}");
    }
}

/// The same runs without the local bundle adjustment drift: their scale changes by more
/// than 3 % on average over the three scenes (measured: 16, 1.7 and 9 %; a random walk,
/// so one scene may stay close), so the test above can fail.
#[test]
fn without_bundle_adjustment_the_scale_drifts() {
    let cfg = TrackerConfig {
        local_ba_window: 0,
        ..TrackerConfig::default()
    };
    let mut worst = Vec::new();
    for seed in 0..3 {
        let steps = scale_steps(&run(seed, 0.5, 0.1, cfg.clone()));
        println!("scene {seed} without BA, scale per 10 frames: {steps:.3?}");
        worst.push(worst_change(&steps));
    }
    let mean = worst.iter().sum::<f64>() / worst.len() as f64;
    assert!(mean > 0.03, "scale changes {worst:.4?}");
}

/// `pipeline.seed`: another RANSAC seed gives another run (some pose differs), and that run
/// is as deterministic as the default one and holds the scale as well.
#[test]
fn another_ransac_seed_gives_another_deterministic_run() {
    let seeded = TrackerConfig::default().with_seed(1);
    assert_eq!(
        TrackerConfig::default().with_seed(0).pnp.seed,
        TrackerConfig::default().pnp.seed
    );
    let a = run(0, 0.5, 0.1, TrackerConfig::default());
    let b = run(0, 0.5, 0.1, seeded.clone());
    let c = run(0, 0.5, 0.1, seeded);
    assert!(
        a.iter().zip(&b).any(|(x, y)| x.0 != y.0),
        "seed 1 ran as seed 0"
    );
    assert!(
        b.iter().zip(&c).all(|(x, y)| x.0 == y.0),
        "seed 1 is not deterministic"
    );
    let worst = worst_change(&scale_steps(&b));
    assert!(worst < 0.02, "seed 1: scale changed by {worst:.4}");
}

/// Not a check, a measurement (docs/vo.md, "Monocular VO"): with noise like KITTI's (0.75 px,
/// 30 % of keypoints at 3 px) the scale walks through the turn, less with a longer local
/// BA window. `cargo test --release -p supermvo-vo --test synthetic_scale -- --ignored
/// --nocapture` prints the last step's scale over the first for six scenes per window.
#[test]
#[ignore]
fn scale_walk_with_kitti_like_noise() {
    for window in [6, 10, 20] {
        let cfg = TrackerConfig {
            local_ba_window: window,
            ..TrackerConfig::default()
        };
        let ratios: Vec<f64> = (0..6)
            .map(|seed| {
                let steps = scale_steps(&run(seed, 0.75, 0.1, cfg.clone()));
                steps[steps.len() - 1] / steps[0]
            })
            .collect();
        println!("window {window}: last / first step {ratios:.3?}");
    }
}

/// Not a check, a measurement (docs/vo.md, "Where the spread comes from"): does a car's geometry
/// in a slow turn make the scale grow as it does on KITTI? The KITTI-like noise runs, at
/// constant speed and with the slow turn, with the camera 0, 2 and 4 m ahead of the rear
/// axle. `cargo test --release -p supermvo-vo --test synthetic_scale -- --ignored
/// --nocapture axle` prints the last step's scale over the first for six scenes each.
#[test]
#[ignore]
fn scale_walk_with_the_camera_ahead_of_the_axle() {
    for slow_turn in [false, true] {
        for lever in [0.0, 2.0, 4.0] {
            let drive = Drive {
                lever,
                slow_turn,
                ..Drive::default()
            };
            let ratios: Vec<f64> = (0..6)
                .map(|seed| {
                    let cfg = TrackerConfig::default();
                    let steps = scale_steps(&run_with(seed, 0.75, 0.1, cfg, drive));
                    steps[steps.len() - 1] / steps[0]
                })
                .collect();
            println!("{drive:?}: last / first step {ratios:.3?}");
        }
    }
}

/// `TrackerConfig::robust_refinement`: a run then depends less on its RANSAC seed. On three
/// scenes with KITTI-like noise, the mean distance between the trajectories of seeds 0 and
/// 1 (both scaled to the true path length) is smaller with the robust final refinement than
/// with the pose refined on the inliers a hard threshold selected: by at least a fifth on
/// average over the three scenes (measured: 0.11 / 0.31 / 0.09 m against 0.28 / 0.25 / 0.28
/// m; one scene goes the other way, so this is an average, not a per-scene claim).
#[test]
fn robust_refinement_makes_the_run_depend_less_on_the_seed() {
    let gap = |robust: bool, scene: u64| {
        let cfg = |seed| TrackerConfig {
            robust_refinement: robust,
            ..TrackerConfig::default().with_seed(seed)
        };
        let (a, b) = (run(scene, 0.75, 0.1, cfg(0)), run(scene, 0.75, 0.1, cfg(1)));
        let scaled = |t: &[(Option<Vec3>, Vec3)]| {
            let first = t.iter().position(|x| x.0.is_some()).unwrap_or(0) + 10;
            let est = (t[t.len() - 1].0.unwrap() - t[first].0.unwrap()).norm();
            let truth = (t[t.len() - 1].1 - t[first].1).norm();
            truth / est
        };
        let (sa, sb) = (scaled(&a), scaled(&b));
        let d: Vec<f64> = a
            .iter()
            .zip(&b)
            .filter_map(|(x, y)| Some((x.0? * sa - y.0? * sb).norm()))
            .collect();
        d.iter().sum::<f64>() / d.len() as f64
    };
    let (mut hard, mut robust) = (0.0, 0.0);
    for scene in 0..3 {
        let (h, r) = (gap(false, scene), gap(true, scene));
        println!(
            "scene {scene}: seeds 0 and 1 {h:.4} m apart with hard selection, {r:.4} m robust"
        );
        hard += h / 3.0;
        robust += r / 3.0;
    }
    assert!(
        robust < 0.8 * hard,
        "robust {robust:.4} m against {hard:.4} m"
    );
}

/// `TrackerConfig::relocalisation_frames`: two frames that see nothing (frames 40 and 41, in
/// the first straight) are lost, and frame 42 is tracked again against the map kept for it,
/// at the map's scale: on three scenes every frame from 42 on has a pose, the scale over
/// the ten frames after the gap is within 2 % of the ten before, and the distance across
/// the gap is right to 5 % at that scale (measured: within 0.3 % and 0.5 %). With
/// relocalisation off, the same runs start a new map after the gap, leave at least two more
/// frames without a pose while it initialises, and carry the scale only through the median
/// depth: more than 5 % off (measured: 14-18 %), so the test can fail.
#[test]
fn frames_that_see_nothing_are_relocalised_at_the_map_scale() {
    let drive = Drive {
        blind: (40, 42),
        ..Drive::default()
    };
    let dist = |t: &[(Option<Vec3>, Vec3)], a: usize, b: usize| {
        (t[b].0.unwrap() - t[a].0.unwrap()).norm() / (t[b].1 - t[a].1).norm()
    };
    for scene in 0..3 {
        let t = run_with(scene, 0.5, 0.1, TrackerConfig::default(), drive);
        assert!(t[40].0.is_none() && t[41].0.is_none(), "scene {scene}");
        let unposed = (42..FRAMES).filter(|&k| t[k].0.is_none()).count();
        assert_eq!(
            unposed, 0,
            "scene {scene}: frames after the gap without a pose"
        );
        let (before, after, across) = (dist(&t, 29, 39), dist(&t, 43, 53), dist(&t, 39, 42));
        println!(
            "scene {scene}: scale {before:.4} before the gap, {after:.4} after, {across:.4} across"
        );
        assert!((after / before - 1.0).abs() < 0.02, "scene {scene}");
        assert!((across / before - 1.0).abs() < 0.05, "scene {scene}");
        let off = TrackerConfig {
            relocalisation_frames: 0,
            ..TrackerConfig::default()
        };
        let t0 = run_with(scene, 0.5, 0.1, off, drive);
        let unposed = (42..FRAMES).filter(|&k| t0[k].0.is_none()).count();
        let (before, after) = (dist(&t0, 29, 39), dist(&t0, 45, 55));
        println!(
            "scene {scene} without relocalisation: {unposed} frames after the gap without a \
             pose, scale {before:.4} before, {after:.4} after"
        );
        assert!(unposed >= 2, "scene {scene}: {unposed}");
        assert!((after / before - 1.0).abs() > 0.05, "scene {scene}");
    }
}

/// `TrackerConfig::covisible_triangulation_keyframes`: when the matcher misses a third of
/// the true matches at random, a point whose chain of keyframe matches breaks never becomes
/// a landmark from the reference pair alone; pairing each new keyframe's free keypoints
/// with the keyframe before its reference along the epipolar line gives them back. On three
/// scenes the median number of landmarks a pose rests on is higher with it than without
/// (measured: 558 / 556 / 565 against 488 / 481 / 491), and the scale holds within 2 %
/// either way.
#[test]
fn keyframes_triangulate_with_the_keyframe_before_their_reference() {
    let drive = Drive {
        missed: 0.33,
        ..Drive::default()
    };
    for scene in 0..3 {
        let median_tracked = |n: usize| {
            let cfg = TrackerConfig {
                covisible_triangulation_keyframes: n,
                ..TrackerConfig::default()
            };
            let (traj, _, mut tracked, _) = run_counted(scene, 0.5, 0.1, cfg, drive);
            let worst = worst_change(&scale_steps(&traj));
            assert!(
                worst < 0.02,
                "scene {scene}, {n} keyframes: scale changed by {worst:.4}"
            );
            tracked.retain(|&t| t > 0);
            tracked.sort_unstable();
            tracked[tracked.len() / 2]
        };
        let (without, with) = (median_tracked(0), median_tracked(1));
        println!("scene {scene}: median tracked {without} without, {with} with");
        assert!(with > without, "scene {scene}: {with} against {without}");
    }
}

/// `TrackerConfig::backfill_frames`: the frames between the first frame and the one that
/// initialises (too little parallax to initialise yet) get no pose as they come, but once
/// the map exists each is posed on it from its kept matches to the first frame, and comes
/// with the initialising frame's output. On three scenes every such frame is posed, each
/// camera centre within 2 % of the distance driven to the initialising frame of the truth
/// scaled to the map (measured: within 0.5 %); with the option off they stay unposed.
#[test]
fn frames_seen_while_initialising_are_posed_once_the_map_exists() {
    // 0.3 m per frame: a few frames pass before the parallax suffices
    let drive = Drive {
        slow_start: true,
        ..Drive::default()
    };
    for scene in 0..3 {
        let (traj, _, _, backfilled) =
            run_counted(scene, 0.5, 0.1, TrackerConfig::default(), drive);
        let init = (1..FRAMES).find(|&k| traj[k].0.is_some()).unwrap();
        assert!(init >= 3, "scene {scene}: initialised at frame {init}");
        let indices: Vec<usize> = backfilled.iter().map(|b| b.0).collect();
        assert_eq!(indices, (1..init).collect::<Vec<_>>(), "scene {scene}");
        let (est_init, true_init) = (traj[init].0.unwrap(), traj[init].1);
        let scale = est_init.norm() / true_init.norm();
        for &(k, c) in &backfilled {
            let err = (c - scale * traj[k].1).norm() / est_init.norm();
            println!("scene {scene}: frame {k} of {init}, error {err:.4} of the distance");
            assert!(err < 0.02, "scene {scene}, frame {k}: {err:.4}");
        }
        let off = TrackerConfig {
            backfill_frames: 0,
            ..TrackerConfig::default()
        };
        let (traj0, _, _, none) = run_counted(scene, 0.5, 0.1, off, drive);
        assert!(none.is_empty() && traj0[1].0.is_none(), "scene {scene}");
    }
}

/// A long straight road (400 frames, 400 m) with 1 px Gaussian keypoint noise, 30 % of the
/// true matches missed and 10 % wrong ones: the scale of every 50-frame stretch stays
/// within 5 % of the first stretch's, on each of two scenes, every frame posed after the
/// initialisation. (Measured over 600 frames: down by 1.6 and 2.0 %, steadily. The same
/// drive with the heavy tail of the other tests, 30 % of the keypoints at 4 px, does not
/// hold: docs/decisions/2026-12-02-scale-with-heavy-tailed-keypoint-noise.md.)
#[test]
fn the_scale_holds_on_a_long_straight_road_with_gaussian_noise() {
    let drive = Drive {
        frames: 400,
        straight: true,
        gaussian: true,
        missed: 0.3,
        ..Drive::default()
    };
    for seed in 0..2 {
        let traj = run_with(seed, 1.0, 0.1, TrackerConfig::default(), drive);
        let unposed = traj.iter().rposition(|t| t.0.is_none()).unwrap_or(0);
        assert!(unposed <= 10, "scene {seed}: frame {unposed} has no pose");
        let steps = scale_over(&traj, 50);
        println!("scene {seed}, scale per 50 frames: {steps:.3?}");
        assert!(steps.len() >= 6, "scene {seed}: {} stretches", steps.len());
        let worst = worst_change(&steps);
        assert!(worst < 0.05, "scene {seed}: scale changed by {worst:.4}");
    }
}

/// Not a check, a measurement (docs/decisions/2026-12-02-scale-with-heavy-tailed-keypoint-noise.md):
/// the 600-frame straight drive with the heavy-tailed keypoint noise, three scenes, each
/// local-BA window choice; prints the scale of the last 50-frame stretch over the first's,
/// and the worst change of any stretch. `cargo test --release -p supermvo-vo --test
/// synthetic_scale -- --ignored --nocapture heavy_tailed`.
#[test]
#[ignore]
fn scale_on_a_long_heavy_tailed_drive_by_ba_window() {
    let drive = Drive {
        frames: 600,
        straight: true,
        missed: 0.3,
        ..Drive::default()
    };
    for (window, min_shared) in [(6, 0), (12, 0), (12, 15), (20, 15), (20, 30)] {
        let cfg = TrackerConfig {
            local_ba_window: window,
            local_ba_min_shared: min_shared,
            ..TrackerConfig::default()
        };
        let per_scene: Vec<(f64, f64)> = (0..3)
            .map(|seed| {
                let steps = scale_over(&run_with(seed, 1.0, 0.1, cfg.clone(), drive), 50);
                (steps[steps.len() - 1] / steps[0], worst_change(&steps))
            })
            .collect();
        println!("window {window}, min shared {min_shared}: (last / first, worst) {per_scene:.3?}");
    }
}
