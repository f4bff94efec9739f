//! `supermvo graph optimize` against GTSAM 4.3's numbers (tests/fixtures, written by
//! tools/gtsam_parity.py), and its bad-input errors.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use serde_json::Value;

#[test]
fn same_errors_as_gtsam_on_every_graph() {
    let Some(dir) = common::shared_data("posegraph") else {
        return;
    };
    let fx: Value = serde_json::from_str(
        &std::fs::read_to_string(common::root().join("tests/fixtures/gtsam_4.3.0_posegraph.json"))
            .unwrap(),
    )
    .unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let graphs = fx["graphs"].as_object().unwrap();
    assert_eq!(graphs.len(), 6);
    for (name, g) in graphs {
        let js = tmp.path().join(format!("{name}.json"));
        let file = dir.join(format!("{name}.g2o"));
        let out = common::supermvo(&[
            "graph",
            "optimize",
            file.to_str().unwrap(),
            "--json",
            js.to_str().unwrap(),
        ]);
        assert!(
            out.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let ours: Value = serde_json::from_str(&std::fs::read_to_string(&js).unwrap()).unwrap();
        for key in ["initial_error", "final_error"] {
            let (a, b) = (g[key].as_f64().unwrap(), ours[key].as_f64().unwrap());
            assert!(
                (a - b).abs() <= 1e-3 * a.abs(),
                "{name} {key}: GTSAM {a}, ours {b}"
            );
        }
        assert_eq!(g["iterations"], ours["iterations"], "{name}: iterations");
        for key in ["initial_error", "final_error", "iterations", "seconds"] {
            assert!(!ours[key].is_null(), "{name}: JSON lacks {key}");
        }
    }
}

#[test]
fn optimized_graph_is_written_and_reread() {
    let Some(dir) = common::shared_data("posegraph") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (out, js) = (tmp.path().join("ring_opt.g2o"), tmp.path().join("r.json"));
    let file = dir.join("ring.g2o");
    let r = common::supermvo(&[
        "graph",
        "optimize",
        file.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(r.status.success());
    // optimising the optimised graph starts at the optimum
    let r = common::supermvo(&[
        "graph",
        "optimize",
        out.to_str().unwrap(),
        "--json",
        js.to_str().unwrap(),
    ]);
    assert!(r.status.success());
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&js).unwrap()).unwrap();
    let (i, f) = (
        v["initial_error"].as_f64().unwrap(),
        v["final_error"].as_f64().unwrap(),
    );
    assert!((i - 5.581551).abs() < 1e-3, "re-read optimum has error {i}");
    assert!(f <= i);
}

fn write(dir: &std::path::Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

const V: &str = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n";
const INFO: &str = "100 0 0 100 0 1000";

#[test]
fn bad_g2o_input() {
    let d = tempfile::tempdir().unwrap();
    let p = write(d.path(), "short.g2o", &format!("{V}EDGE_SE2 0 1 1 0\n"));
    common::expect_error(
        &["graph", "optimize", &p],
        &["short.g2o:3:", "EDGE_SE2 needs 11 values"],
    );
    let p = write(
        d.path(),
        "nan.g2o",
        &format!("{V}EDGE_SE2 0 1 1 0 nan {INFO}\n"),
    );
    common::expect_error(
        &["graph", "optimize", &p],
        &["nan.g2o:3:", "not a finite number"],
    );
    let p = write(
        d.path(),
        "missing.g2o",
        &format!("{V}EDGE_SE2 0 7 1 0 0 {INFO}\n"),
    );
    common::expect_error(
        &["graph", "optimize", &p],
        &["missing.g2o:3:", "vertex 7, which is not defined"],
    );
    let p = write(
        d.path(),
        "npd.g2o",
        &format!("{V}EDGE_SE2 0 1 1 0 0 1 2 0 1 0 1\n"),
    );
    common::expect_error(
        &["graph", "optimize", &p],
        &["npd.g2o:3:", "not positive definite"],
    );
    // a truncated file: vertices 2 and 3 lost their edges, so nothing places them
    let p = write(
        d.path(),
        "truncated.g2o",
        &format!("{V}VERTEX_SE2 2 2 0 0\nVERTEX_SE2 3 3 0 0\nEDGE_SE2 0 1 1 0 0 {INFO}\n"),
    );
    common::expect_error(
        &["graph", "optimize", &p],
        &[
            "truncated.g2o",
            "not connected",
            "2 of 4 vertices",
            "vertex 2",
        ],
    );
    let p = write(d.path(), "empty.g2o", "# nothing\n");
    common::expect_error(
        &["graph", "optimize", &p],
        &["empty.g2o", "no VERTEX_SE2 or VERTEX_SE3:QUAT"],
    );
    // unknown tags are skipped with a warning count, not an error
    let p = write(
        d.path(),
        "unknown.g2o",
        &format!("{V}FIX 0\nFIX 1\nEDGE_SE2 0 1 1 0 0 {INFO}\n"),
    );
    let out = common::supermvo(&["graph", "optimize", &p]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("skipped 2 line(s) with unknown tag FIX"));
}
