#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
//! Each file of the VO crate keeps one job its name says: none grows past 500 lines
//! (issue 21's structure rule; `loops/mod.rs` once grew to 765 lines unnoticed).

use std::path::{Path, PathBuf};

const MAX_LINES: usize = 500;

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn no_file_of_the_vo_crate_is_over_500_lines() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for dir in ["src", "tests", "benches", "examples"] {
        if root.join(dir).is_dir() {
            rust_files(&root.join(dir), &mut files);
        }
    }
    // the walk sees the crate's files (so the rule below can fail)
    assert!(files.iter().any(|f| f.ends_with("src/lib.rs")), "{files:?}");
    assert!(files.len() > 20, "only {} files found", files.len());
    let long: Vec<String> = files
        .iter()
        .map(|f| (f, std::fs::read_to_string(f).unwrap().lines().count()))
        .filter(|&(_, n)| n > MAX_LINES)
        .map(|(f, n)| format!("{}: {n} lines", f.strip_prefix(root).unwrap().display()))
        .collect();
    assert!(
        long.is_empty(),
        "split these by job (at most {MAX_LINES} lines each):\n{}",
        long.join("\n")
    );
}
