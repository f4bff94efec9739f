//! Loop closure end to end: on the synthetic `urban-loop` (a block driven 1.15 times) loops
//! are found and the drift drops; the renderer and the VO run as a user runs them.
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
}
