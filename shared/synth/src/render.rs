//! A CPU rasteriser: every rectangle is clipped to the near plane, its projection bounds the
//! pixels it may cover, and each pixel's ray is intersected with the rectangle's plane
//! exactly (so depth and texture coordinates are perspective-correct). Texturing runs once
//! per pixel, for the visible surface only.

use crate::noise::hash2;
use crate::scene::{Footprint, Scene, V3};
use nalgebra::Matrix3;

/// A pinhole camera (KITTI `P0` without the baseline term).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraModel {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Focal lengths, pixels.
    pub fx: f64,
    /// Focal lengths, pixels.
    pub fy: f64,
    /// Principal point, pixels.
    pub cx: f64,
    /// Principal point, pixels.
    pub cy: f64,
}

impl CameraModel {
    /// KITTI odometry's left grey camera (sequences 00-02), 1241 x 376.
    pub fn kitti() -> Self {
        Self {
            width: 1241,
            height: 376,
            fx: 718.856,
            fy: 718.856,
            cx: 607.1928,
            cy: 185.2157,
        }
    }

    /// Pixel of a point in the camera frame (x right, y down, z forward), if in front.
    pub fn project(&self, p: &V3) -> Option<(f64, f64)> {
        (p.z > 1e-9).then(|| (self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }
}

/// A rendered frame: 8-bit intensities and the depth (camera z, metres; infinite for sky).
#[derive(Debug, Clone)]
pub struct Frame {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Intensities, row by row.
    pub gray: Vec<u8>,
    /// Depth along the optical axis, row by row.
    pub depth: Vec<f32>,
}

/// Photometric settings of one frame.
#[derive(Debug, Clone, Copy)]
pub struct Exposure {
    /// Multiplier on scene radiance.
    pub gain: f32,
    /// Standard deviation of sensor noise, grey levels.
    pub noise: f32,
    /// Frame number, seeding the sensor noise.
    pub frame: u64,
}

const NEAR: f64 = 0.05;
const NONE: u32 = u32::MAX;

/// Renders `scene` at `time` from a camera at `r_world_cam`, `t_world_cam`.
pub fn render(
    scene: &Scene,
    cam: &CameraModel,
    r_world_cam: &Matrix3<f64>,
    t_world_cam: &V3,
    time: f64,
    exposure: Exposure,
) -> Frame {
    let (w, h) = (cam.width, cam.height);
    let quads = scene.quads_at(time);
    let r_cam_world = r_world_cam.transpose();
    let mut depth = vec![f32::INFINITY; w * h];
    let mut zbuf = vec![f64::INFINITY; w * h];
    let mut id = vec![NONE; w * h];
    let mut uv = vec![(0.0f64, 0.0f64); w * h];
    for (qi, q) in quads.iter().enumerate() {
        let to_cam = |p: &V3| r_cam_world * (p - t_world_cam);
        let corners = q.corners().map(|c| to_cam(&c));
        let poly = clip_near(&corners);
        if poly.len() < 3 {
            continue;
        }
        let (mut x0, mut y0, mut x1, mut y1) = (
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        );
        for p in &poly {
            let (x, y) = (cam.fx * p.x / p.z + cam.cx, cam.fy * p.y / p.z + cam.cy);
            x0 = x0.min(x);
            y0 = y0.min(y);
            x1 = x1.max(x);
            y1 = y1.max(y);
        }
        // Pixel centres at integer + 0.5 inside the bounds.
        let xa = (x0 - 0.5).ceil().max(0.0);
        let ya = (y0 - 0.5).ceil().max(0.0);
        let xb = (x1 - 0.5).floor().min(w as f64 - 1.0);
        let yb = (y1 - 0.5).floor().min(h as f64 - 1.0);
        if xa > xb || ya > yb {
            continue;
        }
        let o = corners[0];
        let (u, v) = (r_cam_world * q.u, r_cam_world * q.v);
        let n = u.cross(&v);
        let dist = n.dot(&o);
        let (su, sv) = q.size;
        for py in ya as usize..=yb as usize {
            let ry = (py as f64 + 0.5 - cam.cy) / cam.fy;
            for px in xa as usize..=xb as usize {
                let rx = (px as f64 + 0.5 - cam.cx) / cam.fx;
                let denom = n.x * rx + n.y * ry + n.z;
                if denom.abs() < 1e-12 {
                    continue;
                }
                let z = dist / denom;
                let k = py * w + px;
                if z < NEAR || z >= zbuf[k] {
                    continue;
                }
                let d = V3::new(rx * z, ry * z, z) - o;
                let (a, b) = (d.dot(&u), d.dot(&v));
                if a < -1e-9 || b < -1e-9 || a > su + 1e-9 || b > sv + 1e-9 {
                    continue;
                }
                zbuf[k] = z;
                id[k] = qi as u32;
                uv[k] = (a, b);
            }
        }
    }
    let mut gray = vec![0u8; w * h];
    for py in 0..h {
        let ry = (py as f64 + 0.5 - cam.cy) / cam.fy;
        for px in 0..w {
            let k = py * w + px;
            let rx = (px as f64 + 0.5 - cam.cx) / cam.fx;
            let ray = V3::new(rx, ry, 1.0);
            let radiance = match quads.get(id[k] as usize) {
                None => scene.sky(&(r_world_cam * ray.normalize())),
                Some(q) => {
                    let z = zbuf[k];
                    depth[k] = z as f32;
                    let p = t_world_cam + r_world_cam * (ray * z);
                    let n = q.normal();
                    // Where the rays through the next pixels right and down meet the plane.
                    let hit = |rx: f64, ry: f64| {
                        let d = r_world_cam * V3::new(rx, ry, 1.0);
                        let denom = n.dot(&d);
                        let t = n.dot(&(q.origin - t_world_cam)) / denom;
                        (denom.abs() > 1e-12 && t > 0.0).then(|| t_world_cam + d * t - p)
                    };
                    let far = V3::repeat(z * ray.norm() / cam.fx * 10.0);
                    let fp = Footprint {
                        dx: hit(rx + 1.0 / cam.fx, ry).unwrap_or(far),
                        dy: hit(rx, ry + 1.0 / cam.fy).unwrap_or(far),
                    };
                    let (a, b) = uv[k];
                    scene.albedo(q, a, b, &p, &fp) * scene.shading(&n)
                }
            };
            let noise = if exposure.noise > 0.0 {
                let f = exposure.frame as i64;
                let u1 = hash2(k as i64, f, 0x5EED);
                let u2 = hash2(k as i64, f, 0xF00D);
                // Triangular distribution with the requested standard deviation.
                (u1 + u2 - 1.0) * exposure.noise * 2.449_489_7
            } else {
                0.0
            };
            gray[k] = (radiance * exposure.gain + noise).round().clamp(0.0, 255.0) as u8;
        }
    }
    Frame {
        width: w,
        height: h,
        gray,
        depth,
    }
}

/// Sutherland-Hodgman clipping of a convex polygon to `z >= NEAR`.
fn clip_near(poly: &[V3]) -> Vec<V3> {
    let mut out = Vec::with_capacity(poly.len() + 1);
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
        let (ina, inb) = (a.z >= NEAR, b.z >= NEAR);
        if ina {
            out.push(a);
        }
        if ina != inb {
            let t = (NEAR - a.z) / (b.z - a.z);
            out.push(a + (b - a) * t);
        }
    }
    out
}

/// Where a lens puts the pinhole image: per pixel of the distorted image, the position in
/// the pinhole image it shows. Computed once per sequence.
#[derive(Debug, Clone)]
pub struct LensMap(supermvo_dataset::Remap);

impl LensMap {
    /// The map of `distortion` for camera `cam` (`None` for a pinhole lens).
    pub fn new(cam: &CameraModel, distortion: &supermvo_dataset::Distortion) -> Option<Self> {
        if *distortion == supermvo_dataset::Distortion::None {
            return None;
        }
        let k = supermvo_dataset::Calibration {
            fx: cam.fx,
            fy: cam.fy,
            cx: cam.cx,
            cy: cam.cy,
        };
        let lens = |x, y| distortion.undistort(x, y);
        Some(Self(supermvo_dataset::Remap::new(
            &k, cam.width, cam.height, lens,
        )))
    }

    /// `frame` (rendered for the pinhole camera) as the lens shows it: bilinear for
    /// intensity, nearest for depth; black and infinitely far outside the pinhole image.
    pub fn apply(&self, frame: &Frame) -> Frame {
        let w = frame.width;
        let depth = self
            .0
            .sources()
            .map(|src| match src {
                Some((su, sv)) => frame.depth[(sv.round() as usize) * w + su.round() as usize],
                None => f32::INFINITY,
            })
            .collect();
        Frame {
            width: w,
            height: frame.height,
            gray: self.0.sample(&frame.gray),
            depth,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clipping_keeps_the_part_in_front() {
        let quad = [
            V3::new(-1.0, 0.0, -1.0),
            V3::new(1.0, 0.0, -1.0),
            V3::new(1.0, 0.0, 1.0),
            V3::new(-1.0, 0.0, 1.0),
        ];
        let c = clip_near(&quad);
        assert_eq!(c.len(), 4);
        assert!(c.iter().all(|p| p.z >= NEAR - 1e-12));
        assert!(clip_near(&quad.map(|p| p - V3::z() * 3.0)).is_empty());
    }
}
