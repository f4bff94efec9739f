//! The named sequences: a world, a drive through it and the photometry.

use crate::noise::Rng;
use crate::path::{Path, PathBuilder};
use crate::scene::build::{boxed, car, tree, wall};
use crate::scene::{Material, Motion, Mover, Quad, RoadStyle, Scene, V2, V3};
use std::f64::consts::{FRAC_PI_2, PI};

/// The preset names, in the order `supermvo synth --help` lists them.
pub const PRESETS: [&str; 5] = [
    "urban-loop",
    "highway",
    "dynamic",
    "lighting",
    "stop-and-pan",
];

/// How the camera is driven through a scene.
#[derive(Debug, Clone, Copy)]
pub struct Drive {
    /// Arc length at the first frame, metres.
    pub s0: f64,
    /// Lateral offset from the centre line (left > 0), metres.
    pub lateral: f64,
    /// Speed, m/s.
    pub speed: f64,
    /// Camera height above the road, metres.
    pub height: f64,
    /// A stop during which the camera only turns (pure rotation), if any.
    pub pan: Option<Pan>,
}

/// The car stops and the camera pans about its own centre: yaw `degrees * sin(2 pi u)`
/// for `u` from 0 to 1 over the stop (left, back through straight ahead, right, back).
#[derive(Debug, Clone, Copy)]
pub struct Pan {
    /// Start of the stop, seconds.
    pub start: f64,
    /// Length of the stop, seconds.
    pub duration: f64,
    /// Largest yaw, degrees.
    pub degrees: f64,
}

impl Drive {
    /// Seconds spent moving by time `t`.
    pub fn moving_time(&self, t: f64) -> f64 {
        match self.pan {
            Some(p) if t > p.start => t - (t - p.start).min(p.duration),
            _ => t,
        }
    }

    /// Arc length along the path at time `t`.
    pub fn arc_length(&self, t: f64) -> f64 {
        self.s0 + self.speed * self.moving_time(t)
    }

    /// Extra yaw of the pan at time `t` (radians; zero outside the stop).
    pub fn pan_at(&self, t: f64) -> f64 {
        match self.pan {
            Some(p) if t >= p.start && t <= p.start + p.duration => {
                let u = (t - p.start) / p.duration.max(1e-9);
                p.degrees.to_radians() * (std::f64::consts::TAU * u).sin()
            }
            _ => 0.0,
        }
    }
}

/// Exposure over time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Photometry {
    /// Constant exposure.
    Steady,
    /// Slow auto-exposure drift plus abrupt jumps (passing into shade, a bright sky).
    Changing,
}

/// A preset instantiated for a seed.
#[derive(Debug, Clone)]
pub struct Preset {
    /// Preset name.
    pub name: &'static str,
    /// The world.
    pub scene: Scene,
    /// The camera's drive.
    pub drive: Drive,
    /// Frames rendered unless the user asks otherwise.
    pub default_frames: usize,
    /// Exposure behaviour.
    pub photometry: Photometry,
}

/// Length of the street presets' road (metres) unless more frames need a longer one.
const STREET_M: f64 = 500.0;

/// Road beyond the last frame's position on a lengthened street (metres), so that its end
/// is not in view.
const STREET_AHEAD_M: f64 = 150.0;

/// Builds preset `name` for `seed`, for `frames` frames when given: the straight streets
/// (`dynamic`, `lighting`, `stop-and-pan`) are 500 m long, or long enough for the frames
/// asked for (a long drive); the other roads are what they are. `None` for an unknown name.
pub fn preset_for(name: &str, seed: u64, frames: Option<usize>) -> Option<Preset> {
    let p = preset(name, seed, STREET_M)?;
    let needed = frames.map(|n| {
        p.drive
            .arc_length(n.saturating_sub(1) as f64 / crate::RATE_HZ)
            + STREET_AHEAD_M
    });
    match needed {
        // only the streets take the length; the other roads come back as they are
        Some(length) if length > STREET_M => preset(name, seed, length),
        _ => Some(p),
    }
}

/// Preset `name` for `seed`, a street preset's road `street_m` metres long.
fn preset(name: &str, seed: u64, street_m: f64) -> Option<Preset> {
    match name {
        "urban-loop" => Some(urban_loop(seed)),
        "highway" => Some(highway(seed)),
        "dynamic" => Some(street(seed, "dynamic", true, Photometry::Steady, street_m)),
        "lighting" => Some(street(
            seed,
            "lighting",
            false,
            Photometry::Changing,
            street_m,
        )),
        "stop-and-pan" => {
            // 5 s driving, a 5 s stop panning 35 degrees each way, then driving again.
            let mut p = street(seed, "stop-and-pan", false, Photometry::Steady, street_m);
            p.drive.pan = Some(Pan {
                start: 5.0,
                duration: 5.0,
                degrees: 35.0,
            });
            p.default_frames = 160;
            Some(p)
        }
        _ => None,
    }
}

fn ground_quad(half: f64) -> Quad {
    Quad {
        origin: V3::new(-half, -half, 0.0),
        u: V3::x(),
        v: V3::y(),
        size: (2.0 * half, 2.0 * half),
        material: Material::Ground,
        seed: 0,
    }
}

fn facade(rng: &mut Rng) -> Material {
    let floor = rng.range(2.8, 3.6);
    let pitch = rng.range(2.0, 3.6);
    Material::Facade {
        base: rng.range(90.0, 190.0) as f32,
        floor,
        pitch,
        window: (rng.range(0.8, pitch - 0.6), rng.range(1.1, floor - 1.2)),
    }
}

/// Buildings along the straight parts of `path` on side `side` (+1 left, -1 right), their
/// fronts `offset` metres from the centre line, leaving `margin` metres at each end.
fn buildings(
    out: &mut Vec<Quad>,
    path: &Path,
    side: f64,
    offset: f64,
    margin: f64,
    depth: (f64, f64),
    rng: &mut Rng,
) {
    for (s_start, s_end) in path.straights() {
        let mut s = s_start + margin;
        while s < s_end - margin - 6.0 {
            let len = rng.range(8.0, 22.0).min(s_end - margin - s);
            let setback = rng.range(0.0, 2.5);
            let d = rng.range(depth.0, depth.1);
            let height = rng.range(7.0, 22.0);
            let (p, t) = path.offset(s + len / 2.0, side * (offset + setback + d / 2.0));
            let yaw = t.y.atan2(t.x);
            boxed(
                out,
                p,
                yaw,
                (len, d, height),
                0.0,
                facade(rng),
                rng.seed(),
                false,
            );
            // A shop sign on some fronts.
            if rng.chance(0.35) {
                let (q, _) = path.offset(
                    s + len * rng.range(0.2, 0.6),
                    side * (offset + setback - 0.05),
                );
                let dir = if side > 0.0 { t } else { -t };
                out.push(wall(
                    q,
                    dir,
                    rng.range(1.5, 3.0),
                    2.6,
                    0.8,
                    Material::Sign,
                    rng.seed(),
                ));
            }
            s += len
                + if rng.chance(0.3) {
                    rng.range(2.0, 8.0)
                } else {
                    0.0
                };
        }
    }
}

/// Trees, lamp posts and parked cars along the whole path on both sides.
fn street_furniture(
    out: &mut Vec<Quad>,
    path: &Path,
    road: &RoadStyle,
    parked: bool,
    rng: &mut Rng,
) {
    let len = path.length();
    for side in [-1.0, 1.0] {
        let mut s = rng.range(0.0, 10.0);
        while s < len {
            let (p, _) = path.offset(s, side * (road.half_width + road.pavement - 0.8));
            if rng.chance(0.6) {
                tree(out, p, rng.range(2.2, 3.2), rng.range(2.5, 4.0), rng.seed());
            } else {
                boxed(
                    out,
                    p,
                    0.0,
                    (0.18, 0.18, 6.0),
                    0.0,
                    Material::Plain {
                        base: 120.0,
                        contrast: 20.0,
                    },
                    rng.seed(),
                    false,
                );
            }
            s += rng.range(8.0, 18.0);
        }
        if parked {
            let mut s = rng.range(0.0, 20.0);
            while s < len {
                if rng.chance(0.55) {
                    let (p, t) = path.offset(s, side * (road.half_width - 1.1));
                    let yaw = t.y.atan2(t.x) + if side > 0.0 { PI } else { 0.0 };
                    for q in car(
                        rng.range(40.0, 220.0) as f32,
                        rng.seed(),
                        (rng.range(3.9, 4.8), 1.8),
                    ) {
                        out.push(q.moved(yaw, V3::new(p.x, p.y, 0.0)));
                    }
                }
                s += rng.range(5.5, 9.0);
            }
        }
    }
}

fn urban_loop(seed: u64) -> Preset {
    let mut rng = Rng::new(seed, 1);
    // A rounded block, driven counter-clockwise: 80 m and 40 m straights, 10 m corners.
    let r = 10.0;
    let path = PathBuilder::new(V2::zeros(), 0.0)
        .straight(80.0)
        .turn(r, FRAC_PI_2)
        .straight(40.0)
        .turn(r, FRAC_PI_2)
        .straight(80.0)
        .turn(r, FRAC_PI_2)
        .straight(40.0)
        .turn(r, FRAC_PI_2)
        .closed();
    let road = RoadStyle {
        half_width: 6.0,
        pavement: 3.0,
        dashed: vec![0.0],
        solid: vec![-5.7, 5.7],
        dash: (3.0, 5.0),
        asphalt: (85.0, 40.0),
        verge: (110.0, 50.0),
    };
    let mut statics = vec![ground_quad(400.0)];
    buildings(&mut statics, &path, 1.0, 9.5, 4.0, (8.0, 11.0), &mut rng);
    buildings(&mut statics, &path, -1.0, 9.5, -6.0, (8.0, 14.0), &mut rng);
    street_furniture(&mut statics, &path, &road, true, &mut rng);
    let len = path.length();
    let movers = (0..3)
        .map(|i| Mover {
            quads: car(rng.range(40.0, 220.0) as f32, rng.seed(), (4.4, 1.8)),
            motion: Motion::Road {
                s0: len * (0.2 + 0.3 * i as f64),
                lateral: 1.75,
                speed: -rng.range(7.0, 10.0),
            },
        })
        .collect();
    Preset {
        name: "urban-loop",
        scene: Scene {
            path,
            road,
            statics,
            movers,
            sun: V3::new(0.4, 0.3, 0.866).normalize(),
            seed,
        },
        drive: Drive {
            s0: 5.0,
            lateral: -1.75,
            speed: 8.0,
            height: 1.65,
            pan: None,
        },
        // 1.15 laps of the 303 m block at 0.8 m per frame: the start is seen again.
        default_frames: (1.15 * len / 0.8) as usize,
        photometry: Photometry::Steady,
    }
}

fn highway(seed: u64) -> Preset {
    let mut rng = Rng::new(seed, 2);
    let path = PathBuilder::new(V2::zeros(), 0.0)
        .straight(350.0)
        .turn(1200.0, 0.3)
        .straight(700.0)
        .open();
    let road = RoadStyle {
        half_width: 9.0,
        pavement: 1.0,
        dashed: vec![-4.6, 4.6],
        solid: vec![-8.4, -0.9, 0.9, 8.4],
        dash: (4.0, 10.0),
        asphalt: (95.0, 10.0),
        verge: (105.0, 25.0),
    };
    let mut statics = vec![ground_quad(1500.0)];
    let len = path.length();
    // Central barrier and guard rails: long, nearly textureless.
    let step = 20.0;
    let mut s = 0.0;
    while s < len {
        for lateral in [-0.25, 9.6, -9.6] {
            let (p, t) = path.offset(s, lateral);
            statics.push(wall(
                p,
                t,
                step + 0.05,
                0.0,
                if lateral == -0.25 { 0.9 } else { 0.75 },
                Material::Plain {
                    base: 150.0,
                    contrast: 8.0,
                },
                rng.seed(),
            ));
        }
        s += step;
    }
    // Sparse trees and a few signs beyond the verge; hills far away.
    let mut s = 0.0;
    while s < len {
        let side = if rng.chance(0.5) { 1.0 } else { -1.0 };
        let (p, _) = path.offset(s, side * rng.range(14.0, 45.0));
        tree(
            &mut statics,
            p,
            rng.range(2.5, 4.0),
            rng.range(3.0, 6.0),
            rng.seed(),
        );
        s += rng.range(15.0, 45.0);
    }
    let mut s = 80.0;
    while s < len {
        let (p, t) = path.offset(s, -11.0);
        boxed(
            &mut statics,
            p,
            0.0,
            (0.25, 0.25, 3.0),
            0.0,
            Material::Plain {
                base: 110.0,
                contrast: 10.0,
            },
            rng.seed(),
            false,
        );
        statics.push(wall(
            p - t * 1.5,
            V2::new(-t.y, t.x),
            3.0,
            3.0,
            1.8,
            Material::Sign,
            rng.seed(),
        ));
        s += rng.range(150.0, 300.0);
    }
    for i in 0..12 {
        let s = i as f64 * len / 12.0;
        for side in [-1.0, 1.0] {
            let (p, t) = path.offset(s, side * rng.range(250.0, 400.0));
            statics.push(wall(
                p,
                t,
                len / 10.0,
                0.0,
                rng.range(20.0, 60.0),
                Material::Hill,
                rng.seed(),
            ));
        }
    }
    let movers = (0..6)
        .map(|i| {
            let same_way = i % 2 == 0;
            Mover {
                quads: car(rng.range(40.0, 220.0) as f32, rng.seed(), (4.6, 1.9)),
                motion: Motion::Road {
                    s0: 60.0 + i as f64 * 90.0,
                    lateral: if same_way { -2.7 } else { rng.range(2.5, 6.5) },
                    speed: if same_way {
                        rng.range(27.0, 33.0)
                    } else {
                        -rng.range(22.0, 30.0)
                    },
                },
            }
        })
        .collect();
    Preset {
        name: "highway",
        scene: Scene {
            path,
            road,
            statics,
            movers,
            sun: V3::new(-0.3, 0.5, 0.81).normalize(),
            seed,
        },
        drive: Drive {
            s0: 20.0,
            lateral: -6.5,
            speed: 25.0,
            height: 1.65,
            pan: None,
        },
        default_frames: 200,
        photometry: Photometry::Steady,
    }
}

/// A straight city street `length` metres long, with busy traffic (`dynamic`) or with
/// changing exposure.
fn street(
    seed: u64,
    name: &'static str,
    traffic: bool,
    photometry: Photometry,
    length: f64,
) -> Preset {
    let mut rng = Rng::new(seed, if traffic { 3 } else { 4 });
    let path = PathBuilder::new(V2::zeros(), 0.0).straight(length).open();
    let road = RoadStyle {
        half_width: 7.0,
        pavement: 3.5,
        dashed: vec![-3.5, 3.5],
        solid: vec![-0.1, 0.1, -6.8, 6.8],
        dash: (3.0, 6.0),
        asphalt: (85.0, 35.0),
        verge: (120.0, 40.0),
    };
    let mut statics = vec![ground_quad(length + 100.0)];
    buildings(&mut statics, &path, 1.0, 10.5, 0.0, (10.0, 16.0), &mut rng);
    buildings(&mut statics, &path, -1.0, 10.5, 0.0, (10.0, 16.0), &mut rng);
    street_furniture(&mut statics, &path, &road, !traffic, &mut rng);
    let mut movers = Vec::new();
    let car_at = |rng: &mut Rng, s0: f64, lateral: f64, speed: f64| Mover {
        quads: car(
            rng.range(40.0, 220.0) as f32,
            rng.seed(),
            (rng.range(4.0, 4.8), 1.8),
        ),
        motion: Motion::Road { s0, lateral, speed },
    };
    if traffic {
        // A lead car in the camera's lane at the camera's speed, traffic in every lane.
        movers.push(car_at(&mut rng, 40.0 + 14.0, -1.75, 8.0));
        for i in 0..10 {
            let s0 = 30.0 + i as f64 * 35.0 + rng.range(0.0, 10.0);
            let speed = rng.range(9.0, 13.0);
            movers.push(car_at(&mut rng, s0, -5.25, speed));
        }
        for i in 0..16 {
            let lateral = if i % 2 == 0 { 1.75 } else { 5.25 };
            let s0 = 60.0 + i as f64 * 25.0 + rng.range(0.0, 10.0);
            let speed = -rng.range(7.0, 12.0);
            movers.push(car_at(&mut rng, s0, lateral, speed));
        }
        // Pedestrians on the pavements and crossing.
        for i in 0..24 {
            let s = 40.0 + i as f64 * 8.0 + rng.range(0.0, 5.0);
            let side = if i % 2 == 0 { 1.0 } else { -1.0 };
            let crossing = i % 6 == 0;
            let (a, b) = if crossing {
                (V2::new(s, -9.0), V2::new(s, 9.0))
            } else {
                (V2::new(s, side * 8.5), V2::new(s + 30.0, side * 8.5))
            };
            let mut quads = Vec::new();
            boxed(
                &mut quads,
                V2::zeros(),
                0.0,
                (0.35, 0.5, 1.75),
                0.0,
                Material::Plain {
                    base: rng.range(30.0, 200.0) as f32,
                    contrast: 40.0,
                },
                rng.seed(),
                false,
            );
            movers.push(Mover {
                quads,
                motion: Motion::Shuttle {
                    a,
                    b,
                    speed: rng.range(1.0, 1.8),
                    phase: rng.range(0.0, 20.0),
                },
            });
        }
    } else {
        for i in 0..4 {
            movers.push(car_at(&mut rng, 80.0 + 60.0 * i as f64, 3.5, -9.0));
        }
    }
    Preset {
        name,
        scene: Scene {
            path,
            road,
            statics,
            movers,
            sun: V3::new(0.2, -0.6, 0.77).normalize(),
            seed,
        },
        drive: Drive {
            s0: 40.0,
            lateral: -1.75,
            speed: 8.0,
            height: 1.65,
            pan: None,
        },
        default_frames: 200,
        photometry,
    }
}
