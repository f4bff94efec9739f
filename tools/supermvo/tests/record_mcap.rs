//! A recorded KITTI 07 run read back by an independent reader: `tools/read_mcap.py` (the
//! `mcap` package with its protobuf decoders, Pillow for the images) finds every posed
//! frame's pose, equal to `trajectory.kitti.txt` and stamped at its `times.txt` time, the
//! channels and schemas of docs/recording.md, and images that decode.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

/// `topic -> schema` of the table in docs/recording.md.
fn documented_channels() -> Vec<(String, String)> {
    let doc = std::fs::read_to_string(common::root().join("docs/recording.md")).unwrap();
    doc.lines()
        .filter_map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            let topic = cells.get(1)?.strip_prefix("`/")?.strip_suffix('`')?;
            let schema = cells.get(2)?.trim_matches('`');
            let schema = schema.trim_end_matches(" (JSON)");
            Some((format!("/{topic}"), schema.to_string()))
        })
        .collect()
}

#[test]
fn a_recorded_kitti_run_reads_back_with_the_mcap_package() {
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
    let (out, file) = (tmp.path().join("out"), tmp.path().join("run.mcap"));
    let r = common::supermvo(&[
        "run",
        seq.to_str().unwrap(),
        "--mode",
        "inprocess",
        "-q",
        "--out",
        out.to_str().unwrap(),
        "--record",
        file.to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(
        String::from_utf8_lossy(&r.stdout).contains("recorded 160 frames"),
        "{}",
        String::from_utf8_lossy(&r.stdout)
    );
    let read = common::read_mcap(&pythonpath, &file);

    // channels and schemas as documented; every documented channel with messages here
    let documented = documented_channels();
    assert_eq!(documented.len(), 10, "{documented:?}");
    let channels = read["channels"].as_object().unwrap();
    for (topic, ch) in channels {
        let schema = &documented
            .iter()
            .find(|(t, _)| t == topic)
            .unwrap_or_else(|| panic!("{topic} is not documented"))
            .1;
        assert_eq!(ch["schema"].as_str(), Some(schema.as_str()), "{topic}");
        let encoding = if schema.starts_with("foxglove.") {
            "protobuf"
        } else {
            "json"
        };
        assert_eq!(ch["message_encoding"].as_str(), Some(encoding), "{topic}");
    }
    for (topic, _) in documented
        .iter()
        .filter(|(t, _)| !t.starts_with("/loops") && t != "/log")
    {
        assert!(
            channels.contains_key(topic),
            "{topic} missing: {channels:?}"
        );
    }
    assert_eq!(channels["/supermvo/frame"]["messages"], 160);
    assert_eq!(channels["/supermvo/timing"]["messages"], 160);

    // every posed frame's pose, in order, at its dataset time
    let kitti = common::kitti_rows(&out.join("trajectory.kitti.txt"));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let unposed: Vec<usize> = report["unposed_frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap() as usize)
        .collect();
    let times = supermvo_dataset::read_times(&seq.join("times.txt")).unwrap();
    let posed: Vec<usize> = (0..kitti.len()).filter(|i| !unposed.contains(i)).collect();
    let poses = read["poses"].as_array().unwrap();
    assert_eq!(poses.len(), posed.len(), "one pose per posed frame");
    for (p, &i) in poses.iter().zip(&posed) {
        let v: Vec<f64> = p
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        let stamp = v[0] + v[1] * 1e-9;
        assert!(
            (stamp - times[i]).abs() < 1e-6,
            "frame {i}: {stamp} vs {}",
            times[i]
        );
        // the position exactly (protobuf doubles), the rotation through its quaternion
        let t = [kitti[i][3], kitti[i][7], kitti[i][11]];
        assert_eq!([v[2], v[3], v[4]], t, "frame {i}");
        let (x, y, z, w) = (v[5], v[6], v[7], v[8]);
        let r00 = 1.0 - 2.0 * (y * y + z * z);
        let r12 = 2.0 * (y * z - x * w);
        assert!(
            (r00 - kitti[i][0]).abs() < 1e-9 && (r12 - kitti[i][6]).abs() < 1e-9,
            "frame {i}"
        );
    }

    // every image decodes, at the sequence's size; the map has points
    let first = image::open(seq.join("image_0/000000.png")).unwrap();
    assert_eq!(read["images"]["decoded"], 160);
    assert_eq!(read["images"]["failed"], 0);
    assert_eq!(
        read["images"]["size"],
        serde_json::json!([first.width(), first.height()])
    );
    assert!(
        read["map_points"].as_u64().unwrap() > 100,
        "{}",
        read["map_points"]
    );
}
