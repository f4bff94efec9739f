//! Fixture helpers shared by the OpenCV comparison tests.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code

use serde_json::Value;
use supermvo_geometry::{Mat3, Vec3};

/// Reads `tests/fixtures/<name>` at the workspace root.
pub fn fixture(name: &str) -> Value {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/fixtures")
        .join(name);
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// A 3x3 matrix from nested JSON arrays.
pub fn mat(v: &Value) -> Mat3 {
    Mat3::from_fn(|r, c| v[r][c].as_f64().unwrap())
}

/// A 3-vector from a JSON array.
pub fn vec3(v: &Value) -> Vec3 {
    Vec3::new(
        v[0].as_f64().unwrap(),
        v[1].as_f64().unwrap(),
        v[2].as_f64().unwrap(),
    )
}
