//! Loop closure end to end: on the synthetic `urban-loop` (a block driven 1.15 times) loops
//! are found and the drift drops; the renderer and the VO run as a user runs them. The
//! daemon closes the same loops in its back-end process, bit for bit, across a kill -9.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

#[test]
fn urban_loop_is_closed_and_the_drift_drops() {
    if !common::models_ready() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let seq = common::synth(&tmp.path().join("synth"), "urban-loop");
    let a = common::run_inprocess(&seq, &tmp.path().join("with"), &[]);
    let b = common::run_inprocess(&seq, &tmp.path().join("without"), &["--no-loop-closure"]);
    let loops = a["loops"].as_array().unwrap();
    assert!(loops.len() >= 2, "no loop closed: {}", a["loops"]);
    // Every loop joins the second lap to the first: the query comes after one lap (303 m at
    // 0.8 m per frame is 378 frames) and sees a place of the first ~60 frames.
    for l in loops {
        let (q, m) = (
            l["query_frame"].as_u64().unwrap(),
            l["match_frame"].as_u64().unwrap(),
        );
        assert!(
            q >= 370 && m <= 80 && (q - m).abs_diff(378) <= 12,
            "implausible loop {l}"
        );
    }
    assert!(b["loops"].as_array().is_none_or(|l| l.is_empty()));
    let ape = |r: &serde_json::Value| r["eval"]["ape"]["trans"]["rmse"].as_f64().unwrap();
    let path = a["eval"]["reference_length_m"].as_f64().unwrap();
    let (after, before) = (ape(&a), ape(&b));
    eprintln!("urban-loop APE after Sim(3): {before:.3} m odometry only, {after:.3} m with loops, over {path:.0} m");
    // With the local-map tracker the odometry alone drifts little on this loop (about
    // 0.2 % of the path), so the loops must still lower the error, and the result must meet
    // issue 7's target of 0.3 % of the path.
    assert!(
        after < 0.9 * before,
        "loop closure did not reduce the drift: {before:.3} -> {after:.3} m"
    );
    assert!(
        after < 0.003 * path,
        "APE {after:.3} m is over 0.3 % of {path:.0} m"
    );
    the_daemon_closes_the_same_loops_across_a_killed_back_end(&seq, tmp.path(), &a);
}

/// The lossless daemon, whose back-end process closes the loops and sends its corrections
/// back to tracking, gives the in-process run's trajectory bit for bit, even with its back
/// end killed (-9) after the first loops: the restarted back end rebuilds the loop closer
/// from `frames.csv` and `keyframes.bin`, and the loops after the kill join the second lap
/// to keyframes of the first that only the restored loop closer knows.
fn the_daemon_closes_the_same_loops_across_a_killed_back_end(
    seq: &std::path::Path,
    tmp: &std::path::Path,
    inprocess: &serde_json::Value,
) {
    use nix::sys::signal::{kill, Signal};
    use nix::unistd::Pid;
    let out = tmp.join("daemon");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_supermvo"))
        .args(["run", seq.to_str().unwrap(), "--mode", "multiprocess", "-q"])
        .args(["--name", &format!("loops-{}", std::process::id())])
        .arg("--out")
        .arg(&out)
        .spawn()
        .unwrap();
    // the first loops close at frame 380 (see above); kill the back end a little later
    let kill_at = 392;
    let t0 = std::time::Instant::now();
    let recorded = || {
        std::fs::read_to_string(out.join("frames.csv"))
            .map_or(0, |t| t.lines().filter(|l| l.contains(",ok,")).count())
    };
    while recorded() < kill_at {
        assert!(t0.elapsed().as_secs() < 900, "the daemon stalled");
        assert!(
            child.try_wait().unwrap().is_none(),
            "the daemon ended early"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let processes: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("processes.json")).unwrap())
            .unwrap();
    let backend = processes
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["stage"] == "backend")
        .and_then(|p| p["pid"].as_i64())
        .unwrap();
    let local_bas =
        || std::fs::read_to_string(out.join("local_ba.csv")).map_or(0, |t| t.lines().count() - 1);
    let bas_before = local_bas();
    kill(Pid::from_raw(backend as i32), Signal::SIGKILL).unwrap();
    let killed_after = recorded();
    eprintln!("killed the back end (pid {backend}) after {killed_after} frames");
    assert!(child.wait().unwrap().success());

    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    let restarts = metrics["restarts"].as_array().unwrap();
    assert_eq!(restarts.len(), 1, "{restarts:?}");
    assert_eq!(restarts[0]["stage"], "backend");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let edges = |r: &serde_json::Value| -> Vec<(u64, u64)> {
        r["loops"]
            .as_array()
            .unwrap()
            .iter()
            .map(|l| {
                (
                    l["query_frame"].as_u64().unwrap(),
                    l["match_frame"].as_u64().unwrap(),
                )
            })
            .collect()
    };
    assert_eq!(edges(&report), edges(inprocess));
    assert!(
        edges(&report)
            .iter()
            .any(|(q, _)| *q as usize > killed_after + 2),
        "no loop closed after the restart: {:?}",
        edges(&report)
    );
    let trajectory =
        |dir: &std::path::Path| std::fs::read(dir.join("trajectory.kitti.txt")).unwrap();
    // the local BAs were solved in the back end, by the killed one and by its successor
    assert!(
        bas_before > 20,
        "{bas_before} local BAs in the back end before the kill"
    );
    assert!(
        local_bas() > bas_before + 10,
        "{} local BAs in the back end, {bas_before} before the kill",
        local_bas()
    );
    assert!(
        trajectory(&out) == trajectory(&tmp.join("with")),
        "the daemon's loop-corrected trajectory differs from the in-process run's"
    );
}

/// KITTI 07 replayed three times through the lossless daemon (`--loops 3`): at each lap
/// boundary the images jump back to the start, tracking fails there and starts a new map
/// from its last reference keyframe, and the next laps close loops with the first. The
/// loop closer's odometry edge across the failed frame is weak, so those loops place the
/// new map: every frame after the boundaries is tracked again. (With the edge as tight as
/// the others the pose graph shrank lap 2 to 0.29 of its scale, and from lap 3 on the
/// tracker started a new map every two or three frames: 416 of 480 frames posed.)
#[test]
fn a_replay_looped_three_times_keeps_tracking_across_its_loops() {
    let Some(seq) = common::shared_data("kitti/sequences/07") else {
        return;
    };
    if !common::models_ready() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("looped");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_supermvo"))
        .args(["run", seq.to_str().unwrap(), "--mode", "multiprocess", "-q"])
        .args([
            "--loops",
            "3",
            "--name",
            &format!("looped-{}", std::process::id()),
        ])
        .arg("--out")
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let posed = report["estimated"].as_u64().unwrap();
    let loops = report["loops"].as_array().unwrap().len();
    eprintln!("07 looped 3 times: {posed} of 480 frames posed, {loops} loops closed");
    // measured: 478 posed (the two boundary frames lost), 90 loops (38 before loops in a
    // correction's cool-down joined the pose graph)
    assert!(posed >= 470, "{posed} of 480 frames posed");
    assert!(loops >= 10, "{loops} loops closed");
    // Every pose recorded is a rotation: the tracker applies corrections the loop closer
    // computed from poses the tracker reported after earlier corrections, and without
    // projecting back onto SO(3) the rounding grew about fivefold per correction (in the
    // real-time replay of 03 four times the poses reached a scale of 10^7 by lap 2).
    let csv = std::fs::read_to_string(out.join("frames.csv")).unwrap();
    let mut worst = 0.0_f64;
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() < 20 || f[8].is_empty() {
            continue;
        }
        let v: Vec<f64> = f[8..20].iter().map(|x| x.parse().unwrap()).collect();
        let col = |j: usize| [v[j], v[4 + j], v[8 + j]];
        for a in 0..3 {
            for b in 0..3 {
                let dot: f64 = (0..3).map(|k| col(a)[k] * col(b)[k]).sum();
                worst = worst.max((dot - f64::from(u8::from(a == b))).abs());
            }
        }
    }
    assert!(
        worst < 1e-9,
        "a recorded rotation is off SO(3) by {worst:e}"
    );
}
