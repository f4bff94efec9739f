#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
//! The tracker's behaviour on synthetic features (the world in `world/`): frames between
//! keyframes tracked without the matcher, the local mapping run elsewhere or its BA applied
//! late,
//! frames dropped upstream or seeing nothing, a new map after a failure at the old map's
//! scale, triangulation against the keyframe before the reference, frames seen while
//! initialising.

mod world;
use world::*;

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

/// With the matcher only for keyframes, the frame that becomes a keyframe by the frame count
/// alone (`max_frames_between_keyframes` after the last) is matched at once, not tracked by
/// projection first and then matched; the frames before it are offered to projection.
#[test]
fn a_keyframe_due_by_the_frame_count_is_matched_at_once() {
    let cfg = TrackerConfig {
        match_every_frame: false,
        ..TrackerConfig::default()
    };
    let limit = cfg.max_frames_between_keyframes;
    let (mut due, mut offered, mut late) = (0, 0, Vec::new());
    run_counted_with(0, (0.5, 0.1), cfg, Drive::default(), |k, tracker| {
        let Some(since) = tracker.reference().map(|(r, _)| k - r) else {
            return;
        };
        let wants = tracker.wants_matches();
        if since >= limit {
            due += 1;
            if !wants {
                late.push(k);
            }
        } else if !wants {
            offered += 1;
        }
    });
    println!("{due} frames due by the count, {offered} offered to projection");
    assert!(due > 10 && offered > 10, "{due} due, {offered} offered");
    assert!(late.is_empty(), "tried by projection first: {late:?}");
}

/// The local mapping run elsewhere (as the daemon's back end does: each keyframe's
/// triangulations and its local BA) with the same solvers gives the trajectory bit for bit,
/// every window goes through the solver, and so does every triangulation the keyframes need.
#[test]
fn local_mapping_run_elsewhere_gives_the_same_trajectory() {
    type Count = Rc<Cell<(usize, usize)>>;
    struct Counting(Count);
    impl MappingSolver for Counting {
        fn solve(&mut self, ba: &mut LocalBa, iterations: usize) -> BaOutcome {
            let (bas, queries) = self.0.get();
            self.0.set((bas + 1, queries));
            let (c0, c1) = ba.solve(iterations);
            BaOutcome::Solved(c0, c1)
        }
        fn triangulates(&self) -> bool {
            true
        }
        fn triangulate(
            &mut self,
            batch: &TriangulationBatch,
        ) -> Option<Vec<Option<supermvo_geometry::essential::Triangulated>>> {
            let (bas, queries) = self.0.get();
            self.0.set((bas, queries + batch.queries.len()));
            Some(batch.solve())
        }
    }
    let solved: Count = Default::default();
    let mut counter = Some(Counting(solved.clone()));
    let counts = Cell::new((0, 0));
    let cfg = TrackerConfig::default();
    let here = run_counted(0, 0.5, 0.1, cfg.clone(), Drive::default());
    let there = run_counted_with(0, (0.5, 0.1), cfg, Drive::default(), |_, t| {
        if let Some(c) = counter.take() {
            t.set_mapping_solver(Box::new(c));
        }
        counts.set(t.triangulation_counts());
    });
    let (bas, queries) = solved.get();
    let (answered, computed_here) = counts.get();
    println!("{bas} local BAs and {queries} triangulations sent elsewhere; {answered} used, {computed_here} computed here");
    assert!(bas >= 5, "{bas} local BAs");
    assert!(
        answered >= 200,
        "{answered} triangulations answered elsewhere"
    );
    assert_eq!(
        computed_here, 0,
        "every keyframe triangulation was asked for"
    );
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
    impl MappingSolver for Deferring {
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
                t.set_mapping_solver(Box::new(s));
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

/// A frame that contradicts the map (every match wrong) in the middle of the turn, while
/// the reference keyframe is sound: the new map starts from that keyframe and takes the old
/// map's scale from the landmarks the keyframe saw (`TrackerConfig::reinitialise_at_map_scale`),
/// so the distance per frame after the failure is the one before within 2 % on three scenes
/// (measured: 0.3-0.7 %). Without, the new map's median depth is set to the first map's,
/// which the turn's view does not share: more than 10 % off (measured: 25-27 %), so the test
/// can fail. KITTI 00 at every third frame fails this way in its turn on some RANSAC seeds.
#[test]
fn a_new_map_after_a_failure_continues_at_the_old_scale() {
    const AT: usize = 75;
    let drive = Drive {
        scrambled: Some(AT),
        ..Drive::default()
    };
    let dist = |t: &[(Option<Vec3>, Vec3)], a: usize, b: usize| {
        (t[b].0.unwrap() - t[a].0.unwrap()).norm() / (t[b].1 - t[a].1).norm()
    };
    for scene in 0..3 {
        for at_scale in [true, false] {
            let cfg = TrackerConfig {
                reinitialise_at_map_scale: at_scale,
                ..TrackerConfig::default()
            };
            let t = run_with(scene, 0.5, 0.1, cfg, drive);
            let unposed = (AT + 3..FRAMES).filter(|&k| t[k].0.is_none()).count();
            assert_eq!(unposed, 0, "scene {scene}: frames without a pose");
            let (before, after) = (dist(&t, AT - 11, AT - 1), dist(&t, AT + 5, AT + 15));
            let change = (after / before - 1.0).abs();
            println!(
                "scene {scene}, old map's scale {at_scale}: {before:.4} before, {after:.4} after"
            );
            if at_scale {
                assert!(change < 0.02, "scene {scene}: {change:.4}");
            } else {
                assert!(change > 0.10, "scene {scene}: {change:.4}");
            }
        }
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
