//! `supermvo view` answered by a WebSocket client no one here wrote: `tools/ws_view_client.py`
//! (the `websockets` package, Foxglove's `foxglove.sdk.v1` subprotocol, the advertised
//! protobuf schema decoded by mcap_protobuf) connects while a lossless KITTI 07 daemon runs,
//! finds the channels of docs/recording.md, and receives the poses as they are estimated,
//! equal to the run's trajectory; the view ends by itself at the pipeline's end of stream.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

#[test]
fn a_websocket_client_receives_the_poses_while_the_daemon_runs() {
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
    let name = format!("viewtest-{}", std::process::id());
    // the view first: it waits for the pipeline, then serves on a free port
    let mut view = Command::new(env!("CARGO_BIN_EXE_supermvo"))
        .args(["view", "--name", &name, "--port", "0", "--wait", "120"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // and a recorder attached to the same pipeline
    let file = tmp.path().join("attached.mcap");
    let recorder = Command::new(env!("CARGO_BIN_EXE_supermvo"))
        .args([
            "record",
            file.to_str().unwrap(),
            "--name",
            &name,
            "--wait",
            "120",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let out = tmp.path().join("out");
    let mut daemon = Command::new(env!("CARGO_BIN_EXE_supermvo"))
        .args(["run", seq.to_str().unwrap(), "--name", &name, "-q", "--out"])
        .arg(&out)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(view.stdout.take().unwrap()).lines();
    let first = lines.next().unwrap().unwrap();
    let url = first
        .split_whitespace()
        .find(|w| w.starts_with("ws://"))
        .unwrap_or_else(|| panic!("no address in {first:?}"))
        .to_string();
    let got = common::python_tool_json(
        &pythonpath,
        "ws_view_client.py",
        &[url.as_str(), "--timeout", "300"],
    );
    let d = daemon.wait().unwrap();
    assert!(d.success(), "the daemon run failed");
    let rest: Vec<String> = lines.map(|l| l.unwrap()).collect();
    assert!(view.wait().unwrap().success(), "{rest:?}");
    assert!(
        rest.iter().any(|l| l.contains("(end of stream)")),
        "the view ends with the pipeline: {rest:?}"
    );

    // the recorder attached before the first frame, and a lossless run is slow enough for it
    let r = recorder.wait_with_output().unwrap();
    let said = String::from_utf8_lossy(&r.stdout);
    assert!(
        r.status.success(),
        "{said}{}",
        String::from_utf8_lossy(&r.stderr)
    );
    // every frame posed: the five seen while initialising come with the frame that
    // initialised
    assert!(said.contains("recorded 160 frames (160 posed"), "{said}");
    assert!(said.contains("(end of stream)"), "{said}");
    let read = common::read_mcap(&pythonpath, &file);
    assert_eq!(read["poses"].as_array().unwrap().len(), 160);
    assert_eq!(read["images"]["failed"], 0);

    assert_eq!(got["server"], "supermvo");
    let channels = got["channels"].as_object().unwrap();
    assert_eq!(
        channels.len(),
        supermvo_record::CHANNELS.len(),
        "{channels:?}"
    );
    for (topic, schema, _) in supermvo_record::CHANNELS {
        let schema = schema.trim_end_matches(" (JSON)");
        assert_eq!(channels[topic]["schema"].as_str(), Some(schema), "{topic}");
    }
    // the poses as estimated: the client attached before the first one, so it gets (almost)
    // every one; each equals the trajectory's position of the frame with its time
    let kitti = common::kitti_rows(&out.join("trajectory.kitti.txt"));
    let times = supermvo_dataset::read_times(&seq.join("times.txt")).unwrap();
    let poses = got["poses"].as_array().unwrap();
    assert!(poses.len() >= 145, "{} of 160 poses received", poses.len());
    for p in poses {
        let v: Vec<f64> = p
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        let stamp = v[0] + v[1] * 1e-9;
        let i = times.iter().position(|t| (t - stamp).abs() < 1e-6).unwrap();
        let t = [kitti[i][3], kitti[i][7], kitti[i][11]];
        assert_eq!([v[2], v[3], v[4]], t, "frame {i}");
    }
}
