//! Camera files and lens distortion: the OpenCV / ORB-SLAM3 YAML style (`Camera.fx: ...` or
//! `Camera1.fx: ...`, `Camera.type: "PinHole"` or `"KannalaBrandt8"`) and EuRoC's
//! `sensor.yaml` (`intrinsics: [fu, fv, cu, cv]`, `distortion_model: radial-tangential` or
//! `equidistant`, `distortion_coefficients: [...]`), with the radial-tangential
//! (Brown-Conrady, OpenCV's `k1 k2 p1 p2 k3`) and equidistant (Kannala-Brandt, OpenCV
//! fisheye's `k1..k4`) models. Images are remapped once to the pinhole camera of the same
//! intrinsics ([`Undistorter`], a [`Remap`]), so everything after loading sees a pinhole
//! camera.
//!
//! Only the keys above are read (OpenCV's `%YAML:1.0` header and `!!opencv-matrix` tags are
//! not standard YAML, so a general parser would refuse these files); other keys are ignored.

use crate::{Calibration, DatasetError, GrayImage};
use std::collections::BTreeMap;
use std::path::Path;

/// Lens distortion of normalised image coordinates.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Distortion {
    /// A pinhole camera.
    None,
    /// Radial-tangential: `k1 k2 p1 p2 k3`.
    RadTan([f64; 5]),
    /// Equidistant (fisheye): `k1 k2 k3 k4` on the angle from the axis.
    Equidistant([f64; 4]),
    /// Field of view (Devernay and Faugeras; TUM monoVO's cameras): `omega`, radians; a
    /// point at radius `r` appears at `atan(2 r tan(omega / 2)) / omega`.
    Fov(f64),
}

impl Distortion {
    /// Where the undistorted normalised point `(x, y)` appears in the distorted image
    /// (normalised coordinates).
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        match *self {
            Self::None => (x, y),
            Self::RadTan([k1, k2, p1, p2, k3]) => {
                let r2 = x * x + y * y;
                let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                (
                    x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                    y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
                )
            }
            Self::Equidistant([k1, k2, k3, k4]) => {
                let r = (x * x + y * y).sqrt();
                if r < 1e-12 {
                    return (x, y);
                }
                let th = r.atan();
                let th2 = th * th;
                let thd = th * (1.0 + th2 * (k1 + th2 * (k2 + th2 * (k3 + th2 * k4))));
                (x * thd / r, y * thd / r)
            }
            Self::Fov(w) => {
                let r = (x * x + y * y).sqrt();
                if r < 1e-12 || w == 0.0 {
                    return (x, y);
                }
                let f = (r * 2.0 * (w / 2.0).tan()).atan() / (w * r);
                (x * f, y * f)
            }
        }
    }

    /// The undistorted normalised point that [`Distortion::distort`] maps to `(xd, yd)`
    /// (fixed-point iteration; exact for `None`).
    pub fn undistort(&self, xd: f64, yd: f64) -> (f64, f64) {
        if *self == Self::None {
            return (xd, yd);
        }
        if let Self::Fov(w) = *self {
            // closed form: r = tan(rd omega) / (2 tan(omega / 2))
            let rd = (xd * xd + yd * yd).sqrt();
            if rd < 1e-12 || w == 0.0 {
                return (xd, yd);
            }
            let f = (rd * w).tan() / (2.0 * (w / 2.0).tan() * rd);
            return (xd * f, yd * f);
        }
        let (mut x, mut y) = (xd, yd);
        for _ in 0..30 {
            let (dx, dy) = self.distort(x, y);
            let (ex, ey) = (dx - xd, dy - yd);
            x -= ex;
            y -= ey;
            if ex.abs() + ey.abs() < 1e-12 {
                break;
            }
        }
        (x, y)
    }
}

/// A camera file: intrinsics, distortion and, when given, the image size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Pinhole intrinsics (of the distorted images, and of the undistorted ones).
    pub calib: Calibration,
    /// Lens distortion.
    pub distortion: Distortion,
    /// Image size `(width, height)` when the file gives it.
    pub size: Option<(usize, usize)>,
}

impl Camera {
    /// Where pixel `(u, v)` of the distorted image lies in the pinhole camera of the same
    /// intrinsics (the camera [`Undistorter`] remaps frames to): `None` where the lens
    /// model does not invert (beyond a fisheye's 90 degrees, or where the fixed-point
    /// iteration does not reproduce the pixel within 1e-3 px).
    pub fn undistort_pixel(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let k = &self.calib;
        let (xd, yd) = ((u - k.cx) / k.fx, (v - k.cy) / k.fy);
        let (x, y) = self.distortion.undistort(xd, yd);
        let (rx, ry) = self.distortion.distort(x, y);
        let err_px = ((rx - xd) * k.fx).hypot((ry - yd) * k.fy);
        (x.is_finite() && y.is_finite() && err_px < 1e-3)
            .then_some((k.fx * x + k.cx, k.fy * y + k.cy))
    }

    /// Reads a camera file in the ORB-SLAM3 / OpenCV YAML style or EuRoC's `sensor.yaml`.
    pub fn read(path: &Path) -> Result<Self, DatasetError> {
        let text = std::fs::read(path).map_err(|e| DatasetError::io(path, e))?;
        let text = String::from_utf8(text).map_err(|_| {
            DatasetError::invalid(path, "not a text file (a camera YAML file was expected)")
        })?;
        let keys = yaml_keys(&text);
        let number = |k: &str| -> Result<Option<f64>, DatasetError> {
            keys.get(k)
                .map(|(line, v)| {
                    v.trim_matches('"').parse::<f64>().map_err(|_| {
                        DatasetError::parse(path, *line, format!("{k}: '{v}' is not a number"))
                    })
                })
                .transpose()
        };
        let list = |k: &str| -> Result<Option<Vec<f64>>, DatasetError> {
            keys.get(k)
                .map(|(line, v)| {
                    v.trim_start_matches('[')
                        .trim_end_matches(']')
                        .split(',')
                        .map(|x| {
                            x.trim().parse::<f64>().map_err(|_| {
                                DatasetError::parse(
                                    path,
                                    *line,
                                    format!("{k}: '{v}' is not a list of numbers"),
                                )
                            })
                        })
                        .collect::<Result<Vec<f64>, _>>()
                })
                .transpose()
        };
        let camera = if keys.contains_key("intrinsics") {
            euroc_camera(path, &keys, list)?
        } else {
            orbslam_camera(path, &keys, number)?
        };
        if camera.calib.fx <= 0.0 || camera.calib.fy <= 0.0 {
            return Err(DatasetError::invalid(
                path,
                "focal lengths must be positive",
            ));
        }
        Ok(camera)
    }
}

/// EuRoC `sensor.yaml`.
fn euroc_camera(
    path: &Path,
    keys: &BTreeMap<String, (usize, String)>,
    list: impl Fn(&str) -> Result<Option<Vec<f64>>, DatasetError>,
) -> Result<Camera, DatasetError> {
    let k = list("intrinsics")?.unwrap_or_default();
    let [fx, fy, cx, cy] = k[..] else {
        return Err(DatasetError::invalid(
            path,
            "intrinsics: expected [fu, fv, cu, cv]",
        ));
    };
    let d = list("distortion_coefficients")?.unwrap_or_default();
    let model = keys
        .get("distortion_model")
        .map_or("none", |(_, v)| v.as_str());
    let distortion = match (model, &d[..]) {
        ("none", _) => Distortion::None,
        ("radial-tangential" | "radtan", [k1, k2, p1, p2]) => {
            Distortion::RadTan([*k1, *k2, *p1, *p2, 0.0])
        }
        ("radial-tangential" | "radtan", [k1, k2, p1, p2, k3]) => {
            Distortion::RadTan([*k1, *k2, *p1, *p2, *k3])
        }
        ("equidistant" | "fisheye", [k1, k2, k3, k4]) => {
            Distortion::Equidistant([*k1, *k2, *k3, *k4])
        }
        (m, c) => {
            return Err(DatasetError::invalid(
                path,
                format!(
                    "distortion_model '{m}' with {} coefficients is not supported; use radial-tangential (4 or 5) or equidistant (4)",
                    c.len()
                ),
            ))
        }
    };
    // all-zero coefficients describe a pinhole camera: no remap
    let distortion = match distortion {
        Distortion::RadTan(c) if c.iter().all(|v| *v == 0.0) => Distortion::None,
        Distortion::Equidistant(c) if c.iter().all(|v| *v == 0.0) => Distortion::None,
        d => d,
    };
    let size = list("resolution")?.and_then(|r| match r[..] {
        [w, h] if w > 0.0 && h > 0.0 => Some((w as usize, h as usize)),
        _ => None,
    });
    Ok(Camera {
        calib: Calibration { fx, fy, cx, cy },
        distortion,
        size,
    })
}

/// ORB-SLAM2/3 and OpenCV style: `Camera.fx` (or `Camera1.fx`), `Camera.k1`, ...
fn orbslam_camera(
    path: &Path,
    keys: &BTreeMap<String, (usize, String)>,
    number: impl Fn(&str) -> Result<Option<f64>, DatasetError>,
) -> Result<Camera, DatasetError> {
    let prefix = if keys.contains_key("Camera1.fx") {
        "Camera1"
    } else {
        "Camera"
    };
    let get = |k: &str| number(&format!("{prefix}.{k}"));
    let need = |k: &str| {
        get(k)?.ok_or_else(|| {
            DatasetError::invalid(
                path,
                format!("no '{prefix}.{k}'; a camera file needs fx, fy, cx and cy (ORB-SLAM3 style) or intrinsics (EuRoC sensor.yaml)"),
            )
        })
    };
    let calib = Calibration {
        fx: need("fx")?,
        fy: need("fy")?,
        cx: need("cx")?,
        cy: need("cy")?,
    };
    let kind = keys
        .get("Camera.type")
        .map_or(String::from("PinHole"), |(_, v)| {
            v.trim_matches('"').to_string()
        });
    let c = |k: &str| get(k).map(|v| v.unwrap_or(0.0));
    let distortion = match kind.as_str() {
        "KannalaBrandt8" | "fisheye" => {
            Distortion::Equidistant([c("k1")?, c("k2")?, c("k3")?, c("k4")?])
        }
        // not an ORB-SLAM3 type: TUM monoVO's model, as `supermvo synth --distortion fov`
        // writes it
        "FOV" => match c("omega")? {
            0.0 => Distortion::None,
            w => Distortion::Fov(w),
        },
        "PinHole" | "Pinhole" | "pinhole" => {
            let d = [c("k1")?, c("k2")?, c("p1")?, c("p2")?, c("k3")?];
            if d.iter().all(|v| *v == 0.0) {
                Distortion::None
            } else {
                Distortion::RadTan(d)
            }
        }
        other => {
            return Err(DatasetError::invalid(
                path,
                format!(
                    "Camera.type '{other}' is not supported; use PinHole, KannalaBrandt8 or FOV"
                ),
            ))
        }
    };
    let size = match (number("Camera.width")?, number("Camera.height")?) {
        (Some(w), Some(h)) if w > 0.0 && h > 0.0 => Some((w as usize, h as usize)),
        _ => None,
    };
    Ok(Camera {
        calib,
        distortion,
        size,
    })
}

/// `key: value` pairs of a YAML-like file with their 1-based line: comments dropped,
/// flow lists that span lines joined, nested keys skipped.
fn yaml_keys(text: &str) -> BTreeMap<String, (usize, String)> {
    let mut out = BTreeMap::new();
    let mut open: Option<(String, usize, String)> = None;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("");
        if let Some((key, at, mut value)) = open.take() {
            value.push_str(line.trim());
            if value.contains(']') {
                out.insert(key, (at, value));
            } else {
                open = Some((key, at, value));
            }
            continue;
        }
        if line.starts_with([' ', '\t']) || line.starts_with('%') {
            continue;
        }
        let Some((key, value)) = line.split_once(':') else {
            continue;
        };
        let value = value.trim().to_string();
        if value.starts_with('[') && !value.contains(']') {
            open = Some((key.trim().to_string(), i + 1, value));
        } else {
            out.insert(key.trim().to_string(), (i + 1, value));
        }
    }
    out
}

/// A resampling of images: per output pixel, the position in the input image it shows
/// (NaN where that falls outside), computed once; bilinear sampling.
#[derive(Debug, Clone)]
pub struct Remap {
    width: usize,
    height: usize,
    source: Vec<(f32, f32)>,
}

impl Remap {
    /// The remap of `width x height` images of camera `k` in which the output pixel at
    /// normalised coordinates `(x, y)` shows the input at normalised `lens(x, y)`.
    pub fn new(
        k: &Calibration,
        width: usize,
        height: usize,
        lens: impl Fn(f64, f64) -> (f64, f64),
    ) -> Self {
        let mut source = Vec::with_capacity(width * height);
        for v in 0..height {
            for u in 0..width {
                let (x, y) = lens((u as f64 - k.cx) / k.fx, (v as f64 - k.cy) / k.fy);
                let (su, sv) = (k.fx * x + k.cx, k.fy * y + k.cy);
                let inside =
                    su >= 0.0 && sv >= 0.0 && su <= (width - 1) as f64 && sv <= (height - 1) as f64;
                source.push(if inside {
                    (su as f32, sv as f32)
                } else {
                    (f32::NAN, f32::NAN)
                });
            }
        }
        Self {
            width,
            height,
            source,
        }
    }

    /// `(width, height)` of the images it takes and gives.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Per output pixel (row by row), the input position it shows, or `None` outside.
    pub fn sources(&self) -> impl Iterator<Item = Option<(f32, f32)>> + '_ {
        self.source
            .iter()
            .map(|&(su, sv)| (!su.is_nan()).then_some((su, sv)))
    }

    /// The resampled intensities of a `width x height` image (0 outside the input).
    pub fn sample(&self, data: &[u8]) -> Vec<u8> {
        let (w, h) = (self.width, self.height);
        self.sources()
            .map(|src| {
                let Some((su, sv)) = src else {
                    return 0;
                };
                let (x0, y0) = (su.floor() as usize, sv.floor() as usize);
                let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
                let (fx, fy) = (su - x0 as f32, sv - y0 as f32);
                let p = |x: usize, y: usize| data[y * w + x] as f32;
                let top = p(x0, y0) * (1.0 - fx) + p(x1, y0) * fx;
                let bottom = p(x0, y1) * (1.0 - fx) + p(x1, y1) * fx;
                (top * (1.0 - fy) + bottom * fy).round() as u8
            })
            .collect()
    }
}

/// Remaps distorted images to the pinhole camera of the same intrinsics and size.
#[derive(Debug, Clone)]
pub struct Undistorter {
    remap: Remap,
    camera: Camera,
}

impl Undistorter {
    /// The map for `width x height` images of `camera` (`None` for a pinhole camera).
    pub fn new(camera: &Camera, width: usize, height: usize) -> Option<Self> {
        if camera.distortion == Distortion::None {
            return None;
        }
        let lens = |x, y| camera.distortion.distort(x, y);
        Some(Self {
            remap: Remap::new(&camera.calib, width, height, lens),
            camera: *camera,
        })
    }

    /// The camera (with its lens) the map undoes.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The undistorted image; `img` must have the map's size.
    pub fn apply(&self, img: &GrayImage, path: &Path) -> Result<GrayImage, DatasetError> {
        let (w, h) = self.remap.size();
        if (img.width, img.height) != (w, h) {
            return Err(DatasetError::invalid(
                path,
                format!(
                    "{}x{} differs from the {w}x{h} the camera file was set up for",
                    img.width, img.height
                ),
            ));
        }
        Ok(GrayImage {
            width: w,
            height: h,
            data: self.remap.sample(&img.data),
        })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
    use super::*;

    #[test]
    fn undistort_inverts_distort_for_both_models() {
        for d in [
            Distortion::RadTan([-0.2834, 0.0740, 0.0002, 1.8e-5, 0.0]),
            Distortion::Equidistant([-0.01, 0.05, -0.06, 0.02]),
        ] {
            for (x, y) in [(0.0, 0.0), (0.3, -0.2), (-0.6, 0.45), (0.7, 0.5)] {
                let (xd, yd) = d.distort(x, y);
                let (xu, yu) = d.undistort(xd, yd);
                assert!(
                    (xu - x).abs() < 1e-9 && (yu - y).abs() < 1e-9,
                    "{d:?} at ({x}, {y})"
                );
            }
        }
    }

    /// A pixel of the distorted image goes to where the pinhole camera of the same
    /// intrinsics sees the same ray: distorting it back lands on the pixel again, and the
    /// remap of whole frames takes that pixel's intensity from the same place.
    #[test]
    fn keypoints_undistort_to_where_the_remapped_frame_shows_them() {
        let camera = Camera {
            calib: Calibration {
                fx: 458.654,
                fy: 457.296,
                cx: 367.215,
                cy: 248.375,
            },
            distortion: Distortion::RadTan([-0.2834, 0.0740, 0.0002, 1.8e-5, 0.0]),
            size: Some((752, 480)),
        };
        let remap = Undistorter::new(&camera, 752, 480).unwrap();
        let sources: Vec<Option<(f32, f32)>> = remap.remap.sources().collect();
        for (u, v) in [(100.0, 80.0), (367.0, 248.0), (700.0, 450.0), (20.0, 400.0)] {
            let (pu, pv) = camera.undistort_pixel(u, v).unwrap();
            // the remapped frame's pixel nearest to (pu, pv) shows the input near (u, v)
            let (iu, iv) = (pu.round(), pv.round());
            if iu < 0.0 || iv < 0.0 || iu >= 752.0 || iv >= 480.0 {
                continue;
            }
            let (su, sv) = sources[iv as usize * 752 + iu as usize].unwrap();
            assert!(
                (su as f64 - u).abs() < 1.0 && (sv as f64 - v).abs() < 1.0,
                "({u}, {v}) -> ({pu:.2}, {pv:.2}) shows ({su}, {sv})"
            );
        }
        // the edge moves outwards under barrel distortion
        let (pu, _) = camera.undistort_pixel(0.0, 248.375).unwrap();
        assert!(pu < -10.0, "{pu}");
        // a pinhole camera leaves pixels where they are
        let pinhole = Camera {
            distortion: Distortion::None,
            ..camera
        };
        assert_eq!(pinhole.undistort_pixel(12.5, 40.0), Some((12.5, 40.0)));
    }

    #[test]
    fn reads_euroc_and_orbslam3_camera_files() {
        let dir = tempfile::tempdir().unwrap();
        let euroc = dir.path().join("sensor.yaml");
        std::fs::write(
            &euroc,
            "%YAML:1.0\nT_BS:\n  cols: 4\n  data: [1, 0, 0, 0,\n    0, 1, 0, 0]\nresolution: [752, 480]\n\
             intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv\n\
             distortion_model: radial-tangential\n\
             distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]\n",
        )
        .unwrap();
        let c = Camera::read(&euroc).unwrap();
        assert_eq!(c.calib.fx, 458.654);
        assert_eq!(c.calib.cy, 248.375);
        assert_eq!(c.size, Some((752, 480)));
        assert_eq!(
            c.distortion,
            Distortion::RadTan([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0])
        );
        let orb = dir.path().join("fisheye.yaml");
        std::fs::write(
            &orb,
            "%YAML:1.0\nCamera.type: \"KannalaBrandt8\"\nCamera1.fx: 190.97\nCamera1.fy: 190.97\n\
             Camera1.cx: 254.93\nCamera1.cy: 256.89\nCamera1.k1: 0.0034\nCamera1.k2: 0.0007\n\
             Camera1.k3: -0.0020\nCamera1.k4: 0.0002\nCamera.width: 512\nCamera.height: 512\n",
        )
        .unwrap();
        let c = Camera::read(&orb).unwrap();
        assert_eq!(c.calib.fx, 190.97);
        assert_eq!(
            c.distortion,
            Distortion::Equidistant([0.0034, 0.0007, -0.0020, 0.0002])
        );
        assert_eq!(c.size, Some((512, 512)));
        // a missing key is named
        let bad = dir.path().join("bad.yaml");
        std::fs::write(&bad, "Camera.fx: 500\nCamera.fy: 500\nCamera.cx: 320\n").unwrap();
        let e = Camera::read(&bad).unwrap_err().to_string();
        assert!(e.contains("Camera.cy") && e.contains("bad.yaml"), "{e}");
        std::fs::write(&bad, "Camera.fx: five\n").unwrap();
        let e = Camera::read(&bad).unwrap_err().to_string();
        assert!(e.contains("line 1") || e.contains(":1"), "{e}");
    }

    #[test]
    fn remapping_moves_a_distorted_dot_to_its_pinhole_position() {
        let camera = Camera {
            calib: Calibration {
                fx: 300.0,
                fy: 300.0,
                cx: 160.0,
                cy: 120.0,
            },
            distortion: Distortion::RadTan([-0.3, 0.08, 0.0, 0.0, 0.0]),
            size: None,
        };
        // a bright dot where the undistorted pixel (280, 200) appears in the distorted image
        let (x, y) = ((280.0 - 160.0) / 300.0, (200.0 - 120.0) / 300.0);
        let (xd, yd) = camera.distortion.distort(x, y);
        let (u, v) = (
            (300.0 * xd + 160.0).round() as usize,
            (300.0 * yd + 120.0).round() as usize,
        );
        let mut img = GrayImage::new(320, 240, vec![0; 320 * 240]).unwrap();
        for dv in 0..3 {
            for du in 0..3 {
                img.data[(v + dv - 1) * 320 + u + du - 1] = 255;
            }
        }
        let out = Undistorter::new(&camera, 320, 240)
            .unwrap()
            .apply(&img, Path::new("dot.png"))
            .unwrap();
        let brightest = (0..out.data.len()).max_by_key(|&i| out.data[i]).unwrap();
        let (bu, bv) = (brightest % 320, brightest / 320);
        assert!(
            (bu as i64 - 280).abs() <= 2 && (bv as i64 - 200).abs() <= 2,
            "({bu}, {bv})"
        );
        assert!(Undistorter::new(
            &Camera {
                distortion: Distortion::None,
                ..camera
            },
            320,
            240
        )
        .is_none());
    }
}
