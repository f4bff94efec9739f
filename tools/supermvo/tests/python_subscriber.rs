//! A client no one here wrote reads the daemon's shared memory: `examples/python/
//! pose_subscriber.py` (the official iceoryx2 Python bindings and ctypes, nothing from this
//! workspace) attached to a lossless KITTI 07 run receives every frame's result, in order,
//! and every pose it prints equals the run's `trajectory.kitti.txt` bit for bit.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use std::process::{Command, Stdio};

#[test]
fn the_python_subscriber_receives_every_pose_bit_for_bit() {
    let Some(seq) = common::shared_data("kitti/sequences/07") else {
        return;
    };
    let Some(pythonpath) = common::python_tools() else {
        return;
    };
    if !common::models_ready() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let name = format!("pysub-{}", std::process::id());
    // the subscriber first: it waits for the pipeline's services to appear
    let script = common::root().join("examples/python/pose_subscriber.py");
    let subscriber = Command::new("python3")
        .arg(&script)
        .args(["--name", &name, "--timeout", "120"])
        .env("PYTHONPATH", &pythonpath)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python3");
    let out = tmp.path().join("out");
    let run = common::supermvo(&[
        "run",
        seq.to_str().unwrap(),
        "--name",
        &name,
        "-q",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let printed = subscriber.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&printed.stdout);
    assert!(
        printed.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&printed.stderr)
    );

    let trajectory = common::kitti_rows(&out.join("trajectory.kitti.txt"));
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(
        lines.last().copied(),
        Some(format!("end of stream after {} frames", trajectory.len()).as_str()),
        "{text}"
    );
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    // frames seen while initialising, posed with the frame that initialised
    let (backfilled, frames): (Vec<&str>, Vec<&str>) = lines[..lines.len() - 1]
        .iter()
        .partition(|l| l.split_whitespace().nth(1) == Some("backfilled"));
    for line in &backfilled {
        let f: Vec<&str> = line.split_whitespace().collect();
        let i: usize = f[0].parse().unwrap();
        let pose: Vec<f64> = f[2..].iter().map(|v| v.parse().unwrap()).collect();
        assert_eq!(bits(&pose), bits(&trajectory[i]), "frame {i}: {line}");
    }
    assert!(
        !backfilled.is_empty(),
        "07's first frames are posed late: {text}"
    );
    assert_eq!(frames.len(), trajectory.len(), "one line per frame: {text}");
    let mut posed = backfilled.len();
    for (i, line) in frames.iter().enumerate() {
        let f: Vec<&str> = line.split_whitespace().collect();
        // in order, without gaps: seq and frame index both count up from 0
        assert_eq!(f[0], i.to_string(), "{line}");
        assert_eq!(f[1], i.to_string(), "{line}");
        if f[3] == "1" {
            let pose: Vec<f64> = f[5..].iter().map(|v| v.parse().unwrap()).collect();
            assert_eq!(bits(&pose), bits(&trajectory[i]), "frame {i}: {line}");
            posed += 1;
        } else {
            assert_eq!(f[5], "-", "{line}");
        }
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let unposed = report["unposed_frames"].as_array().unwrap().len();
    assert_eq!(posed + unposed, trajectory.len(), "{text}");
    assert!(posed > 140, "most of 07 is posed: {posed}");
}
