//! KITTI odometry sequence layout.
//!
//! ```text
//! sequences/NN/calib.txt      "P0: 12 numbers" (3x4 projection, row-major)
//! sequences/NN/times.txt      one timestamp (s) per frame
//! sequences/NN/image_0/*.png  grayscale left camera (image_2 for colour)
//! poses/NN.txt                ground truth, when available
//! ```

use crate::error::{parse_numbers, DatasetError};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

/// Pinhole intrinsics of the left camera, from the `P0:` row of `calib.txt`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Calibration {
    /// Focal length in x (pixels).
    pub fx: f64,
    /// Focal length in y (pixels).
    pub fy: f64,
    /// Principal point x (pixels).
    pub cx: f64,
    /// Principal point y (pixels).
    pub cy: f64,
}

impl Calibration {
    /// Reads the `P0:` line of a KITTI `calib.txt`.
    pub fn read_kitti(path: &Path) -> Result<Self, DatasetError> {
        let f = std::fs::File::open(path).map_err(|e| DatasetError::io(path, e))?;
        for (i, line) in BufReader::new(f).lines().enumerate() {
            let line = line.map_err(|e| DatasetError::io(path, e))?;
            let Some(rest) = line.trim().strip_prefix("P0:") else {
                continue;
            };
            let fields: Vec<&str> = rest.split_whitespace().collect();
            if fields.len() != 12 {
                return Err(DatasetError::parse(
                    path,
                    i + 1,
                    format!(
                        "P0 has {} numbers, expected 12 (3x4 projection matrix)",
                        fields.len()
                    ),
                ));
            }
            let v = parse_numbers(&fields, path, i + 1)?;
            if v[0] <= 0.0 || v[5] <= 0.0 {
                return Err(DatasetError::parse(
                    path,
                    i + 1,
                    "P0 focal lengths must be positive",
                ));
            }
            return Ok(Self {
                fx: v[0],
                fy: v[5],
                cx: v[2],
                cy: v[6],
            });
        }
        Err(DatasetError::invalid(
            path,
            "no 'P0:' line; a KITTI calib.txt needs 'P0: fx 0 cx 0 0 fy cy 0 0 0 1 0'",
        ))
    }

    /// The 3x3 camera matrix K.
    pub fn k(&self) -> nalgebra::Matrix3<f64> {
        nalgebra::Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }
}

/// The PNG and JPEG files of `dir` in natural order: numbers in names compare by value, so
/// `img_2.png` comes before `img_10.png` (as a camera that does not zero-pad writes them),
/// and KITTI's zero-padded names keep their order.
pub fn image_files(dir: &Path) -> Result<Vec<PathBuf>, DatasetError> {
    let is_image = |p: &Path| {
        p.extension().and_then(|x| x.to_str()).is_some_and(|x| {
            ["png", "jpg", "jpeg"]
                .iter()
                .any(|e| x.eq_ignore_ascii_case(e))
        })
    };
    let mut images: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| DatasetError::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| is_image(p))
        .collect();
    images.sort_by(|a, b| {
        let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
        natord::compare(&name(a).unwrap_or_default(), &name(b).unwrap_or_default())
    });
    Ok(images)
}

/// Reads a `times.txt`: one number (seconds) per line.
pub fn read_times(path: &Path) -> Result<Vec<f64>, DatasetError> {
    let f = std::fs::File::open(path).map_err(|e| DatasetError::io(path, e))?;
    let mut out = Vec::new();
    for (i, line) in BufReader::new(f).lines().enumerate() {
        let line = line.map_err(|e| DatasetError::io(path, e))?;
        let fields: Vec<&str> = line.split_whitespace().collect();
        if fields.is_empty() {
            continue;
        }
        if fields.len() != 1 {
            return Err(DatasetError::parse(
                path,
                i + 1,
                format!("found {} columns, expected 1 timestamp", fields.len()),
            ));
        }
        out.extend(parse_numbers(&fields, path, i + 1)?);
    }
    if out.is_empty() {
        return Err(DatasetError::Empty {
            path: path.to_path_buf(),
            expected: "one timestamp (seconds) a line".into(),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
    use super::*;

    #[test]
    fn image_files_sort_numbers_by_value_and_take_jpeg() {
        let d = tempfile::tempdir().unwrap();
        for n in [
            "img_10.png",
            "img_2.JPG",
            "img_1.jpeg",
            "notes.txt",
            "img_100.png",
        ] {
            std::fs::write(d.path().join(n), b"").unwrap();
        }
        let names = |dir: &Path| -> Vec<String> {
            image_files(dir)
                .unwrap()
                .iter()
                .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
                .collect()
        };
        assert_eq!(
            names(d.path()),
            ["img_1.jpeg", "img_2.JPG", "img_10.png", "img_100.png"]
        );
        // KITTI's zero-padded names keep their order
        let k = tempfile::tempdir().unwrap();
        for i in [10, 9, 0, 100] {
            std::fs::write(k.path().join(format!("{i:06}.png")), b"").unwrap();
        }
        assert_eq!(
            names(k.path()),
            ["000000.png", "000009.png", "000010.png", "000100.png"]
        );
    }

    #[test]
    fn calibration_without_p0_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("calib.txt");
        std::fs::write(&p, "P1: 1 0 0 0 0 1 0 0 0 0 1 0\n").unwrap();
        let err = Calibration::read_kitti(&p).unwrap_err().to_string();
        assert!(err.contains("no 'P0:' line"), "{err}");
        std::fs::write(&p, "P0: 718.8 0 607.1 0 0 718.8 185.2 0 0 0 1 0\n").unwrap();
        let c = Calibration::read_kitti(&p).unwrap();
        assert_eq!((c.fx, c.cy), (718.8, 185.2));
    }
}
