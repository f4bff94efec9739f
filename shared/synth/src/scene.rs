//! The 3D world: textured rectangles (static and on moving bodies), a ground plane whose
//! texture follows the road's centre line, and a sky.

use crate::noise::{coverage, fbm, hash2};
use crate::path::Path;
use nalgebra::{Rotation3, Vector2, Vector3};

pub(crate) type V2 = Vector2<f64>;
pub(crate) type V3 = Vector3<f64>;

/// Surface appearance of a rectangle. Intensities are 8-bit albedo before lighting.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Material {
    /// The ground: road, markings, kerb, pavement and verge, laid out along the scene's path.
    Ground,
    /// A building front: rendered plaster with a grid of windows.
    Facade {
        /// Wall albedo.
        base: f32,
        /// Storey height, metres.
        floor: f64,
        /// Window spacing along the wall, metres.
        pitch: f64,
        /// Window width and height, metres.
        window: (f64, f64),
    },
    /// Leaves (tree crowns, hedges): busy high-frequency texture.
    Foliage,
    /// Tree trunk.
    Bark,
    /// Painted metal or concrete with little texture (poles, barriers, guard rails).
    Plain {
        /// Albedo.
        base: f32,
        /// Noise amplitude.
        contrast: f32,
    },
    /// A car's lower body: paint, with dark wheels at the bottom.
    CarBody {
        /// Paint albedo.
        base: f32,
    },
    /// A car's cabin: a dark window band on paint.
    CarCabin {
        /// Paint albedo.
        base: f32,
    },
    /// A sign or poster: high-contrast blocks.
    Sign,
    /// Distant hills: very low-frequency texture.
    Hill,
}

/// A textured rectangle `origin + a u + b v`, `a` in `[0, su]`, `b` in `[0, sv]`, with `u` and
/// `v` orthonormal. Texture coordinates are `(a, b)` in metres.
#[derive(Debug, Clone, Copy)]
pub struct Quad {
    /// Corner.
    pub origin: V3,
    /// Unit edge direction of the first side.
    pub u: V3,
    /// Unit edge direction of the second side.
    pub v: V3,
    /// Side lengths, metres.
    pub size: (f64, f64),
    /// Appearance.
    pub material: Material,
    /// Texture seed.
    pub seed: u64,
}

impl Quad {
    /// The same rectangle moved by the rotation about +z by `yaw` and the translation `t`.
    pub fn moved(&self, yaw: f64, t: V3) -> Quad {
        let r = Rotation3::from_axis_angle(&V3::z_axis(), yaw);
        Quad {
            origin: r * self.origin + t,
            u: r * self.u,
            v: r * self.v,
            ..*self
        }
    }

    /// Unit normal `u x v`.
    pub fn normal(&self) -> V3 {
        self.u.cross(&self.v)
    }

    /// The four corners.
    pub fn corners(&self) -> [V3; 4] {
        let (a, b) = (self.u * self.size.0, self.v * self.size.1);
        [
            self.origin,
            self.origin + a,
            self.origin + a + b,
            self.origin + b,
        ]
    }
}

/// The patch of a surface one pixel sees: how far the surface point moves for a step of one
/// pixel right (`dx`) and down (`dy`), in metres.
#[derive(Debug, Clone, Copy)]
pub struct Footprint {
    /// Surface step per pixel to the right.
    pub dx: V3,
    /// Surface step per pixel down.
    pub dy: V3,
}

impl Footprint {
    /// Width of the pixel's box filter along unit direction `e` on the surface.
    pub fn along(&self, e: &V3) -> f64 {
        self.dx.dot(e).abs() + self.dy.dot(e).abs()
    }

    /// An isotropic footprint (the larger step), for noise.
    pub fn iso(&self) -> f64 {
        self.dx.norm().max(self.dy.norm())
    }
}

/// How the road surface looks across its width.
#[derive(Debug, Clone)]
pub struct RoadStyle {
    /// Half width of the asphalt, metres.
    pub half_width: f64,
    /// Width of kerb plus pavement on each side, metres.
    pub pavement: f64,
    /// Lateral offsets of dashed lane lines.
    pub dashed: Vec<f64>,
    /// Lateral offsets of solid lines.
    pub solid: Vec<f64>,
    /// Dash length and gap, metres.
    pub dash: (f64, f64),
    /// Asphalt albedo and noise amplitude.
    pub asphalt: (f32, f32),
    /// Verge beyond the pavement: albedo and noise amplitude.
    pub verge: (f32, f32),
}

/// How a body moves.
#[derive(Debug, Clone, Copy)]
pub enum Motion {
    /// Along the scene's path: start arc length, lateral offset (left > 0), speed in m/s
    /// (negative drives against the path's direction).
    Road {
        /// Arc length at time 0.
        s0: f64,
        /// Lateral offset.
        lateral: f64,
        /// Speed, m/s.
        speed: f64,
    },
    /// Back and forth along a straight segment from `a` to `b` at `speed`.
    Shuttle {
        /// One end.
        a: V2,
        /// The other end.
        b: V2,
        /// Speed, m/s.
        speed: f64,
        /// Phase offset, seconds.
        phase: f64,
    },
}

/// A rigid body made of rectangles (in its own frame: x forward, z up) and its motion.
#[derive(Debug, Clone)]
pub struct Mover {
    /// Rectangles in the body frame.
    pub quads: Vec<Quad>,
    /// Motion.
    pub motion: Motion,
}

/// A world to render.
#[derive(Debug, Clone)]
pub struct Scene {
    /// The road's centre line.
    pub path: Path,
    /// The road's cross-section.
    pub road: RoadStyle,
    /// Static rectangles (the ground first).
    pub statics: Vec<Quad>,
    /// Moving bodies.
    pub movers: Vec<Mover>,
    /// Direction towards the sun (unit).
    pub sun: V3,
    /// Scene seed (ground texture).
    pub seed: u64,
}

impl Scene {
    /// Every rectangle at time `time`, in the world frame.
    pub fn quads_at(&self, time: f64) -> Vec<Quad> {
        let mut out = self.statics.clone();
        for m in &self.movers {
            let (pos, yaw) = self.mover_pose(&m.motion, time);
            out.extend(m.quads.iter().map(|q| q.moved(yaw, pos)));
        }
        out
    }

    fn mover_pose(&self, motion: &Motion, time: f64) -> (V3, f64) {
        match *motion {
            Motion::Road { s0, lateral, speed } => {
                let (p, t) = self.path.offset(s0 + speed * time, lateral);
                let yaw = t.y.atan2(t.x)
                    + if speed < 0.0 {
                        std::f64::consts::PI
                    } else {
                        0.0
                    };
                (V3::new(p.x, p.y, 0.0), yaw)
            }
            Motion::Shuttle { a, b, speed, phase } => {
                let len = (b - a).norm().max(1e-9);
                let period = 2.0 * len / speed.abs().max(1e-9);
                let tt = (time + phase).rem_euclid(period) * speed.abs();
                let (along, dir) = if tt <= len {
                    (tt, b - a)
                } else {
                    (2.0 * len - tt, a - b)
                };
                let p = a + (b - a) * (along / len);
                (V3::new(p.x, p.y, 0.0), dir.y.atan2(dir.x))
            }
        }
    }

    /// Albedo (0-255) of `quad` at texture coordinates `(a, b)` and world point `p`, seen
    /// through a pixel whose footprint on the surface is `fp`.
    pub fn albedo(&self, quad: &Quad, a: f64, b: f64, p: &V3, fp: &Footprint) -> f32 {
        let seed = quad.seed;
        let fw = fp.iso();
        let (fu, fv) = (fp.along(&quad.u), fp.along(&quad.v));
        match quad.material {
            Material::Ground => self.ground(p, fp),
            Material::Facade {
                base,
                floor,
                pitch,
                window,
            } => {
                let tone = base + 30.0 * fbm(a, b, 0.7, 5, fw, seed);
                // Windows from the first floor up, on a regular grid; each one lit or not.
                let storey = (b / floor).floor();
                let bay = (a / pitch).floor();
                let (wa, wb) = (a - bay * pitch, b - storey * floor);
                let (x0, y0) = ((pitch - window.0) / 2.0, 0.9);
                let cov = coverage(wa, x0, x0 + window.0, fu) * coverage(wb, y0, y0 + window.1, fv);
                let frame = coverage(wa, x0 - 0.12, x0 + window.0 + 0.12, fu)
                    * coverage(wb, y0 - 0.12, y0 + window.1 + 0.12, fv);
                let lit = hash2(bay as i64, storey as i64, seed);
                let glass = 25.0 + 90.0 * lit * lit + 12.0 * fbm(a, b, 3.0, 2, fw, seed ^ 5);
                let with_frame = tone + (tone * 0.55 - tone) * (frame - cov).max(0.0);
                with_frame + (glass - with_frame) * cov
            }
            Material::Foliage => 95.0 + 150.0 * fbm(a, b, 2.5, 5, fw, seed),
            Material::Bark => 70.0 + 60.0 * fbm(a * 8.0, b, 1.0, 4, fw * 8.0, seed),
            Material::Plain { base, contrast } => base + contrast * fbm(a, b, 1.0, 4, fw, seed),
            Material::CarBody { base } => {
                let wheel = coverage(b, -1.0, 0.35, fv);
                let paint = base + 12.0 * fbm(a, b, 2.0, 3, fw, seed);
                paint + (20.0 - paint) * wheel
            }
            Material::CarCabin { base } => {
                let glass = coverage(b, 0.12, quad.size.1 - 0.08, fv)
                    * coverage(a, 0.12, quad.size.0 - 0.12, fu);
                let paint = base + 10.0 * fbm(a, b, 2.0, 3, fw, seed);
                paint + (35.0 - paint) * glass
            }
            Material::Sign => {
                let cell = 0.25;
                let v = hash2((a / cell).floor() as i64, (b / cell).floor() as i64, seed);
                let blocky = if v > 0.5 { 220.0 } else { 40.0 };
                // Fade the blocks to grey where they are finer than a pixel.
                let w = (2.0 - 4.0 * fw / cell).clamp(0.0, 1.0) as f32;
                130.0 + (blocky - 130.0) * w
            }
            Material::Hill => 120.0 + 70.0 * fbm(a, b, 0.02, 6, fw, seed),
        }
    }

    fn ground(&self, p: &V3, fp: &Footprint) -> f32 {
        let r = &self.road;
        let (s, d) = self.path.project(V2::new(p.x, p.y));
        let (_, t) = self.path.at(s);
        let fw = fp.iso();
        // Box-filter widths across and along the road.
        let fd = fp.along(&V3::new(-t.y, t.x, 0.0));
        let fs = fp.along(&V3::new(t.x, t.y, 0.0));
        let ad = d.abs();
        let seed = self.seed;
        let asphalt = r.asphalt.0 + r.asphalt.1 * fbm(p.x, p.y, 1.5, 6, fw, seed);
        let mut v = asphalt;
        let mut paint = 0.0f32;
        for &x in &r.solid {
            paint = paint.max(coverage(d, x - 0.08, x + 0.08, fd));
        }
        let period = r.dash.0 + r.dash.1;
        let along = s.rem_euclid(period);
        let dash_cov =
            coverage(along, 0.0, r.dash.0, fs).max(coverage(along, period, period + r.dash.0, fs));
        for &x in &r.dashed {
            paint = paint.max(coverage(d, x - 0.08, x + 0.08, fd) * dash_cov);
        }
        v += (215.0 - v) * paint;
        // Kerb (0.25 m, bright) and paving slabs with dark joints.
        let kerb = coverage(ad, r.half_width, r.half_width + 0.25, fd);
        let slab = 150.0 + 25.0 * fbm(p.x, p.y, 2.0, 4, fw, seed ^ 3);
        let (ja, jb) = (s.rem_euclid(0.6), (ad - r.half_width).rem_euclid(0.6));
        let joints = coverage(ja, 0.0, 0.03, fs).max(coverage(jb, 0.0, 0.03, fd));
        let w = (2.0 - 4.0 * fs.max(fd) / 0.6).clamp(0.0, 1.0) as f32;
        let paving = slab + (85.0 - slab) * joints * w;
        let pave_cov = coverage(ad, r.half_width + 0.25, r.half_width + r.pavement, fd);
        v += (185.0 - v) * kerb;
        v += (paving - v) * pave_cov;
        let verge = r.verge.0 + r.verge.1 * fbm(p.x, p.y, 0.8, 7, fw, seed ^ 9);
        let verge_cov = coverage(ad, r.half_width + r.pavement, f64::INFINITY, fd);
        v + (verge - v) * verge_cov
    }

    /// Sky brightness for a viewing direction (world frame, unit).
    pub fn sky(&self, dir: &V3) -> f32 {
        let elev = dir.z.clamp(-1.0, 1.0);
        let az = dir.y.atan2(dir.x);
        let clouds = fbm(az * 4.0, elev * 8.0, 0.5, 3, 0.0, self.seed ^ 77);
        (205.0 - 50.0 * elev as f32 + 25.0 * clouds).clamp(0.0, 255.0)
    }

    /// Lambertian-style shading factor of a surface with normal `n`.
    pub fn shading(&self, n: &V3) -> f32 {
        0.55 + 0.45 * n.dot(&self.sun).abs() as f32
    }
}

/// Helpers that put boxes into a scene.
pub mod build {
    use super::*;

    /// A vertical rectangle from base point `p` along horizontal direction `dir` (unit),
    /// `len` long and `height` high, starting `z0` above the ground.
    pub fn wall(
        p: V2,
        dir: V2,
        len: f64,
        z0: f64,
        height: f64,
        material: Material,
        seed: u64,
    ) -> Quad {
        Quad {
            origin: V3::new(p.x, p.y, z0),
            u: V3::new(dir.x, dir.y, 0.0),
            v: V3::z(),
            size: (len, height),
            material,
            seed,
        }
    }

    /// An axis-aligned box in a frame at `centre` (ground point) turned by `yaw`: `length`
    /// along the frame's x, `width` along y, from `z0` to `z0 + height`. Four walls, plus the
    /// bottom face when `bottom` (visible from below, e.g. tree crowns).
    #[allow(clippy::too_many_arguments)]
    pub fn boxed(
        out: &mut Vec<Quad>,
        centre: V2,
        yaw: f64,
        (length, width, height): (f64, f64, f64),
        z0: f64,
        material: Material,
        seed: u64,
        bottom: bool,
    ) {
        let fx = V2::new(yaw.cos(), yaw.sin());
        let fy = V2::new(-yaw.sin(), yaw.cos());
        let (hl, hw) = (length / 2.0, width / 2.0);
        let c = [
            centre - fx * hl - fy * hw,
            centre + fx * hl - fy * hw,
            centre + fx * hl + fy * hw,
            centre - fx * hl + fy * hw,
        ];
        for i in 0..4 {
            let (a, b) = (c[i], c[(i + 1) % 4]);
            let len = (b - a).norm();
            out.push(wall(
                a,
                (b - a) / len,
                len,
                z0,
                height,
                material,
                seed.wrapping_add(i as u64),
            ));
        }
        if bottom {
            out.push(Quad {
                origin: V3::new(c[0].x, c[0].y, z0),
                u: V3::new(fx.x, fx.y, 0.0),
                v: V3::new(fy.x, fy.y, 0.0),
                size: (length, width),
                material,
                seed: seed.wrapping_add(4),
            });
        }
    }

    /// A car in its body frame (x forward, z up, centred on the ground): body and cabin.
    pub fn car(base: f32, seed: u64, size: (f64, f64)) -> Vec<Quad> {
        let mut q = Vec::new();
        let (l, w) = size;
        boxed(
            &mut q,
            V2::zeros(),
            0.0,
            (l, w, 0.8),
            0.15,
            Material::CarBody { base },
            seed,
            false,
        );
        boxed(
            &mut q,
            V2::new(-0.15 * l, 0.0),
            0.0,
            (0.5 * l, w * 0.92, 0.55),
            0.95,
            Material::CarCabin { base },
            seed ^ 0x55,
            false,
        );
        q
    }

    /// A tree: trunk and a boxy crown, at ground point `p`.
    pub fn tree(out: &mut Vec<Quad>, p: V2, height: f64, crown: f64, seed: u64) {
        boxed(
            out,
            p,
            (seed % 628) as f64 / 100.0,
            (0.35, 0.35, height),
            0.0,
            Material::Bark,
            seed,
            false,
        );
        boxed(
            out,
            p,
            ((seed >> 8) % 628) as f64 / 100.0,
            (crown, crown, crown * 0.9),
            height,
            Material::Foliage,
            seed ^ 0x77,
            true,
        );
    }
}
