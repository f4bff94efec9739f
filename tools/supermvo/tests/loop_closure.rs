//! Loop closure end to end: on the synthetic `urban-loop` (a block driven 1.15 times) loops
//! are found and the drift drops; the renderer and the VO run as a user runs them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

fn report(dir: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap()
}

#[test]
fn urban_loop_is_closed_and_the_drift_drops() {
    if !common::models_ready() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("synth");
    let r = common::supermvo(&[
        "synth",
        "--preset",
        "urban-loop",
        "-q",
        "--out",
        root.to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let seq = root.join("sequences/urban-loop");
    let (with, without) = (tmp.path().join("with"), tmp.path().join("without"));
    for (out, extra) in [(&with, None), (&without, Some("--no-loop-closure"))] {
        let mut args = vec![
            "run",
            seq.to_str().unwrap(),
            "--mode",
            "inprocess",
            "-q",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend(extra);
        let r = common::supermvo(&args);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    let (a, b) = (report(&with), report(&without));
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
}
