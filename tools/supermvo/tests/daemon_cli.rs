//! `supermvo monitor` and `inspect` without a running pipeline: clear answers, no hang.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

#[test]
fn monitor_of_a_pipeline_that_is_not_running_is_a_clear_error() {
    let name = format!("not-running-{}", std::process::id());
    common::expect_error(
        &["monitor", "--name", &name],
        &[
            &format!("pipeline '{name}' is not running"),
            "supermvo inspect",
        ],
    );
}

#[test]
fn inspect_lists_without_error() {
    let out = common::supermvo(&["inspect", "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["nodes"].is_array() && v["services"].is_array());
}
