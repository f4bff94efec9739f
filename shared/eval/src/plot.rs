//! PNG figures.
use std::path::{Path, PathBuf};
/// Writes all figures.
pub fn write_all(
    _dir: &Path,
    _r: &[(String, crate::Evaluation)],
) -> Result<Vec<PathBuf>, std::io::Error> {
    Ok(vec![])
}
