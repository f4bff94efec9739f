//! The TUM monoVO layout (Engel, Usenko and Cremers' monocular odometry benchmark, as DSO
//! reads it): `DIR/images/*.jpg|png`, `DIR/times.txt` (`id time exposure` lines) and
//! `DIR/camera.txt`, whose first line is the camera, `[FOV|RadTan|...] fx fy cx cy omega`:
//! relative to the image size when cx and cy are below 1 (then, as DSO does, scaled by width
//! and height with half a pixel taken from cx and cy, the file's origin being the top-left
//! pixel's corner), and omega, the FOV model's field of view (0: a pinhole camera). The
//! file's further lines (DSO's rectification target) are not used: frames are remapped to the
//! pinhole camera of the same intrinsics, as every other layout's.

use crate::camera::{Camera, Distortion};
use crate::{Calibration, DatasetError};
use std::path::Path;

/// Whether `dir` holds the TUM monoVO layout.
pub fn is_tum_mono(dir: &Path) -> bool {
    dir.join("camera.txt").is_file() && dir.join("images").is_dir()
}

/// The camera of `camera.txt` for images of `size`.
pub fn read_camera(path: &Path, size: (usize, usize)) -> Result<Camera, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
    let first = text.lines().next().unwrap_or_default();
    let mut words = first.split_whitespace().peekable();
    let model = match words.peek() {
        Some(w) if w.parse::<f64>().is_err() => words.next().map(str::to_string),
        _ => None,
    };
    let v: Vec<f64> = words
        .map(|w| w.parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| {
            DatasetError::parse(path, 1, format!("'{first}': expected fx fy cx cy omega"))
        })?;
    let omega = match (model.as_deref(), v.len()) {
        (None | Some("FOV"), 5) => v[4],
        (Some("Pinhole"), 4 | 5) | (None, 4) => 0.0,
        _ => {
            return Err(DatasetError::parse(
                path,
                1,
                format!(
                "'{first}': expected [FOV] fx fy cx cy omega (other models of DSO's are not read)"
            ),
            ))
        }
    };
    let (w, h) = (size.0 as f64, size.1 as f64);
    let calib = if v[2] < 1.0 && v[3] < 1.0 {
        Calibration {
            fx: v[0] * w,
            fy: v[1] * h,
            cx: v[2] * w - 0.5,
            cy: v[3] * h - 0.5,
        }
    } else {
        Calibration {
            fx: v[0],
            fy: v[1],
            cx: v[2],
            cy: v[3],
        }
    };
    Ok(Camera {
        calib,
        distortion: if omega == 0.0 {
            Distortion::None
        } else {
            Distortion::Fov(omega)
        },
        size: Some(size),
    })
}

/// The times of `times.txt` (`id time [exposure]` lines), seconds.
pub fn read_times(path: &Path) -> Result<Vec<f64>, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.starts_with('#'))
        .map(|(i, l)| {
            l.split_whitespace()
                .nth(1)
                .and_then(|t| t.parse::<f64>().ok())
                .ok_or_else(|| {
                    DatasetError::parse(path, i + 1, format!("'{l}': expected 'id time exposure'"))
                })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_intrinsics_scale_with_the_image_and_shift_half_a_pixel() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("camera.txt");
        std::fs::write(
            &p,
            "0.349153 0.436593 0.493140 0.499021 0.933271\n1280 1024\ncrop\n640 480\n",
        )
        .unwrap();
        let c = read_camera(&p, (1280, 1024)).unwrap();
        assert!((c.calib.fx - 0.349153 * 1280.0).abs() < 1e-9);
        assert!((c.calib.cy - (0.499021 * 1024.0 - 0.5)).abs() < 1e-9);
        assert_eq!(c.distortion, Distortion::Fov(0.933271));
        std::fs::write(&p, "FOV 500 500 320 240 0\n").unwrap();
        let c = read_camera(&p, (640, 480)).unwrap();
        assert_eq!(
            (c.calib.fx, c.calib.cx, c.distortion),
            (500.0, 320.0, Distortion::None)
        );
        std::fs::write(&p, "KannalaBrandt 1 2 3 4 5 6 7 8\n").unwrap();
        let err = read_camera(&p, (640, 480)).unwrap_err().to_string();
        assert!(err.contains("camera.txt") && err.contains("FOV"), "{err}");
    }

    #[test]
    fn the_fov_model_maps_radii_as_its_formula_and_inverts() {
        let d = Distortion::Fov(0.9);
        let (x, y) = (0.3, -0.4);
        let (xd, yd) = d.distort(x, y);
        let rd = (xd * xd + yd * yd).sqrt();
        let expect = (0.5 * 2.0 * (0.45f64).tan()).atan() / 0.9;
        assert!((rd - expect).abs() < 1e-12, "{rd} vs {expect}");
        let (xu, yu) = d.undistort(xd, yd);
        assert!((xu - x).abs() < 1e-12 && (yu - y).abs() < 1e-12);
    }

    #[test]
    fn times_are_the_second_column() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("times.txt");
        std::fs::write(
            &p,
            "00000 1399380889.5423 13.4\n00001 1399380889.5756 13.4\n",
        )
        .unwrap();
        assert_eq!(
            read_times(&p).unwrap(),
            vec![1399380889.5423, 1399380889.5756]
        );
        std::fs::write(&p, "00000\n").unwrap();
        assert!(read_times(&p)
            .unwrap_err()
            .to_string()
            .contains("id time exposure"));
    }
}
