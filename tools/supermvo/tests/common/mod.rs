//! Helpers shared by the CLI end-to-end tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The workspace root.
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// `../shared/data/<sub>` if present. When absent, prints why and returns `None` (the test
/// then skips), unless `SUPERMVO_REQUIRE_SHARED=1`, in which case the test fails.
pub fn shared_data(sub: &str) -> Option<PathBuf> {
    let base = std::env::var_os("SUPERMVO_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| root().join("../shared"));
    let p = base.join("data").join(sub);
    if p.exists() {
        return Some(p);
    }
    if std::env::var("SUPERMVO_REQUIRE_SHARED").as_deref() == Ok("1") {
        panic!("{} is missing and SUPERMVO_REQUIRE_SHARED=1", p.display());
    }
    eprintln!(
        "SKIP: {} not found (set SUPERMVO_SHARED or place the shared data beside the repo)",
        p.display()
    );
    None
}

/// Runs the `supermvo` binary.
pub fn supermvo(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_supermvo"))
        .args(args)
        .output()
        .expect("run supermvo")
}

/// Runs `supermvo` and expects failure with one clear error line containing every `needle`.
pub fn expect_error(args: &[&str], needles: &[&str]) {
    let out = supermvo(args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "expected failure for {args:?}");
    assert_eq!(
        out.status.code(),
        Some(2),
        "clean error exit, not a panic: {stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    for n in needles {
        assert!(stderr.contains(n), "stderr lacks '{n}':\n{stderr}");
    }
}
