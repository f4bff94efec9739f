//! Crates depend downwards only: what each library must not pull in, checked on the
//! workspace's resolved dependency graph (`cargo metadata`), so a new edge that breaks the
//! layering fails here instead of going unnoticed.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::Command;

/// Normal (non-dev, non-build) dependencies by package name, from the resolved graph.
fn dependency_graph() -> BTreeMap<String, Vec<String>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    // this machine's platform only: the others' crates need not be downloaded
    let host = Command::new("rustc")
        .arg("-vV")
        .output()
        .expect("running rustc -vV");
    let host = String::from_utf8_lossy(&host.stdout)
        .lines()
        .find_map(|l| l.strip_prefix("host: ").map(str::to_string))
        .expect("rustc -vV names the host");
    let out = Command::new(cargo)
        .args(["metadata", "--format-version", "1", "--offline"])
        .args(["--filter-platform", &host])
        .current_dir(&root)
        .output()
        .expect("running cargo metadata");
    assert!(
        out.status.success(),
        "cargo metadata failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let name_of: BTreeMap<&str, &str> = meta["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| (p["id"].as_str().unwrap(), p["name"].as_str().unwrap()))
        .collect();
    let mut graph = BTreeMap::new();
    for node in meta["resolve"]["nodes"].as_array().unwrap() {
        let name = name_of[node["id"].as_str().unwrap()].to_string();
        let deps = node["deps"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|d| {
                d["dep_kinds"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .any(|k| k["kind"].is_null())
            })
            .map(|d| name_of[d["pkg"].as_str().unwrap()].to_string())
            .collect();
        graph.insert(name, deps);
    }
    graph
}

/// Every package `from` reaches through normal dependencies.
fn reachable(graph: &BTreeMap<String, Vec<String>>, from: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut todo = vec![from.to_string()];
    while let Some(p) = todo.pop() {
        for d in graph.get(&p).into_iter().flatten() {
            if seen.insert(d.clone()) {
                todo.push(d.clone());
            }
        }
    }
    seen
}

#[test]
fn libraries_do_not_pull_in_what_they_do_not_use() {
    let graph = dependency_graph();
    assert!(
        graph.contains_key("supermvo-messages"),
        "workspace not found"
    );
    // the walk does see the edges it checks for (so the rules below can fail)
    assert!(reachable(&graph, "supermvo-inference").contains("ort"));
    assert!(reachable(&graph, "supermvo-plot").contains("plotters"));
    assert!(reachable(&graph, "supermvo-geometry").contains("supermvo-optim"));
    // (crate, what it must not reach, why)
    let rules = [
        (
            "supermvo-messages",
            "ort",
            "messages only move features; the types live in supermvo-features",
        ),
        (
            "supermvo-config",
            "plotters",
            "configuration reads options; figures live in supermvo-plot",
        ),
        (
            "supermvo",
            "supermvo-services",
            "the CLI and the stage processes share supermvo-pipeline; the CLI starts the stage binaries, it does not link their crate",
        ),
        (
            "supermvo-optim",
            "supermvo-geometry",
            "the one least-squares core is at the bottom: the refinements in geometry, bundle adjustment and the pose graphs build on it",
        ),
        (
            "supermvo-features",
            "ort",
            "the feature types are shared by every stage",
        ),
    ];
    let mut broken = Vec::new();
    for (krate, banned, why) in rules {
        if reachable(&graph, krate).contains(banned) {
            broken.push(format!("{krate} depends on {banned} ({why})"));
        }
    }
    assert!(broken.is_empty(), "layering broken:\n{}", broken.join("\n"));
}
