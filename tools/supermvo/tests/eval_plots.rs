//! `supermvo eval --plot` writes the four kinds of figure as valid PNG files.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

#[test]
fn plots_for_two_estimates() {
    let Some(dir) = common::shared_data("trajectories/supermvo-paper") else {
        return;
    };
    let out = tempfile::tempdir().unwrap();
    let (gt, a, b) = (
        dir.join("00_gt_tum.txt"),
        dir.join("00_supermvo_tum.txt"),
        dir.join("00_orb_tum.txt"),
    );
    let res = common::supermvo(&[
        "eval",
        "-q",
        "--format",
        "tum",
        "--t-max-diff",
        "0.02",
        "--align",
        "sim3",
        "--gt",
        gt.to_str().unwrap(),
        "--est",
        &format!("supermvo={}", a.display()),
        "--est",
        &format!("orb={}", b.display()),
        "--plot",
        out.path().to_str().unwrap(),
        "--json",
        out.path().join("r.json").to_str().unwrap(),
    ]);
    assert!(
        res.status.success(),
        "{}",
        String::from_utf8_lossy(&res.stderr)
    );
    // -q means what it means in `run`: the results print, the list of files written does not
    let stdout = String::from_utf8_lossy(&res.stdout);
    assert!(
        stdout.contains("supermvo") && stdout.contains("orb") && stdout.contains("APE"),
        "{stdout}"
    );
    assert!(!stdout.contains("wrote "), "{stdout}");
    for f in [
        "trajectory_xz.png",
        "xyz.png",
        "rpy.png",
        "ape_supermvo.png",
        "ape_orb.png",
    ] {
        let bytes = std::fs::read(out.path().join(f)).unwrap();
        assert!(bytes.len() > 10_000, "{f} is suspiciously small");
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{f} is not a PNG");
    }
    // with several estimates the JSON is keyed by label
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.path().join("r.json")).unwrap()).unwrap();
    assert!(
        r["supermvo"]["ape"]["trans"]["rmse"].as_f64().unwrap()
            < r["orb"]["ape"]["trans"]["rmse"].as_f64().unwrap()
    );
}
