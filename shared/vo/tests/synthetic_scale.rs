#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
//! The tracker's scale on synthetic features (the world in `world/`): the ratio of
//! estimated to true distance over 10-frame steps along drives with known keypoint noise
//! and wrong matches, and what holds it (local BA, the robust refinement).

mod world;
use world::*;

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
    if !long_tests("robust_refinement_makes_the_run_depend_less_on_the_seed") {
        return;
    }
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

/// A long straight road (400 frames, 400 m) with 1 px Gaussian keypoint noise, 30 % of the
/// true matches missed and 10 % wrong ones: the scale of every 50-frame stretch stays
/// within 5 % of the first stretch's, on each of two scenes, every frame posed after the
/// initialisation. (Measured over 600 frames: down by 1.6 and 2.0 %, steadily. The same
/// drive with the heavy tail of the other tests, 30 % of the keypoints at 4 px, does not
/// hold: docs/decisions/2026-12-02-scale-with-heavy-tailed-keypoint-noise.md.)
#[test]
fn the_scale_holds_on_a_long_straight_road_with_gaussian_noise() {
    if !long_tests("the_scale_holds_on_a_long_straight_road_with_gaussian_noise") {
        return;
    }
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
