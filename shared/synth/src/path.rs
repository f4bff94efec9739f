//! Road centre lines made of straight and circular pieces, with arc-length parametrisation
//! and closest-point projection (the ground texture and the camera both follow them).

use nalgebra::Vector2;
use std::f64::consts::{PI, TAU};

type V2 = Vector2<f64>;

/// One piece of a centre line.
#[derive(Debug, Clone, Copy)]
enum Piece {
    Line {
        start: V2,
        dir: V2,
        len: f64,
    },
    Arc {
        centre: V2,
        radius: f64,
        a0: f64,
        sweep: f64,
    },
}

impl Piece {
    fn len(&self) -> f64 {
        match *self {
            Piece::Line { len, .. } => len,
            Piece::Arc { radius, sweep, .. } => radius * sweep.abs(),
        }
    }

    /// Position and unit tangent at arc length `s` along the piece.
    fn at(&self, s: f64) -> (V2, V2) {
        match *self {
            Piece::Line { start, dir, .. } => (start + dir * s, dir),
            Piece::Arc {
                centre,
                radius,
                a0,
                sweep,
            } => {
                let sign = sweep.signum();
                let a = a0 + sign * s / radius;
                let p = centre + V2::new(a.cos(), a.sin()) * radius;
                (p, V2::new(-a.sin(), a.cos()) * sign)
            }
        }
    }

    /// Closest point: (arc length along the piece, distance, signed lateral offset, left > 0).
    fn project(&self, p: V2) -> (f64, f64, f64) {
        match *self {
            Piece::Line { start, dir, len } => {
                let d = p - start;
                let along = d.dot(&dir).clamp(0.0, len);
                let q = start + dir * along;
                let lateral = dir.x * d.y - dir.y * d.x;
                (along, (p - q).norm(), lateral)
            }
            Piece::Arc {
                centre,
                radius,
                a0,
                sweep,
            } => {
                let d = p - centre;
                let sign = sweep.signum();
                let ang = d.y.atan2(d.x);
                let rel = (sign * (ang - a0)).rem_euclid(TAU);
                let span = sweep.abs();
                let along_ang = if rel <= span {
                    rel
                } else if rel - span < TAU - rel {
                    span
                } else {
                    0.0
                };
                let s = along_ang * radius;
                let (q, t) = self.at(s);
                let w = p - q;
                let lateral = t.x * w.y - t.y * w.x;
                (s, w.norm(), lateral)
            }
        }
    }
}

/// A centre line: pieces joined end to end, optionally closed.
#[derive(Debug, Clone)]
pub struct Path {
    pieces: Vec<Piece>,
    starts: Vec<f64>,
    total: f64,
    closed: bool,
}

/// Builds a path piece by piece from a start point and heading.
#[derive(Debug, Clone)]
pub struct PathBuilder {
    pos: V2,
    heading: f64,
    pieces: Vec<Piece>,
}

impl PathBuilder {
    /// Starts at `pos` heading `heading` radians (counter-clockwise from +x).
    pub fn new(pos: V2, heading: f64) -> Self {
        Self {
            pos,
            heading,
            pieces: Vec::new(),
        }
    }

    /// Straight ahead for `len` metres.
    pub fn straight(mut self, len: f64) -> Self {
        let dir = V2::new(self.heading.cos(), self.heading.sin());
        self.pieces.push(Piece::Line {
            start: self.pos,
            dir,
            len,
        });
        self.pos += dir * len;
        self
    }

    /// A circular turn of `radius` through `angle` radians (positive: left).
    pub fn turn(mut self, radius: f64, angle: f64) -> Self {
        let sign = angle.signum();
        // Centre lies to the left for a left turn.
        let left = V2::new(-self.heading.sin(), self.heading.cos());
        let centre = self.pos + left * radius * sign;
        let a0 = self.heading - sign * PI / 2.0;
        let piece = Piece::Arc {
            centre,
            radius,
            a0,
            sweep: angle,
        };
        let (end, _) = piece.at(piece.len());
        self.pieces.push(piece);
        self.pos = end;
        self.heading += angle;
        self
    }

    /// Finishes an open path.
    pub fn open(self) -> Path {
        Path::new(self.pieces, false)
    }

    /// Finishes a closed path (the caller makes the end meet the start).
    pub fn closed(self) -> Path {
        Path::new(self.pieces, true)
    }
}

impl Path {
    fn new(pieces: Vec<Piece>, closed: bool) -> Self {
        let mut starts = Vec::with_capacity(pieces.len());
        let mut total = 0.0;
        for p in &pieces {
            starts.push(total);
            total += p.len();
        }
        Self {
            pieces,
            starts,
            total,
            closed,
        }
    }

    /// Length in metres.
    pub fn length(&self) -> f64 {
        self.total
    }

    /// Whether the path is a loop.
    pub fn is_closed(&self) -> bool {
        self.closed
    }

    fn wrap(&self, s: f64) -> f64 {
        if self.closed {
            s.rem_euclid(self.total)
        } else {
            s.clamp(0.0, self.total)
        }
    }

    /// Position and unit tangent at arc length `s` (wrapped on a loop, clamped otherwise).
    pub fn at(&self, s: f64) -> (V2, V2) {
        let s = self.wrap(s);
        let i = self.starts.partition_point(|&a| a <= s).saturating_sub(1);
        match self.pieces.get(i) {
            Some(p) => p.at(s - self.starts[i]),
            None => (V2::zeros(), V2::x()),
        }
    }

    /// Point at arc length `s` and signed lateral offset `lateral` (left > 0), with the tangent.
    pub fn offset(&self, s: f64, lateral: f64) -> (V2, V2) {
        let (p, t) = self.at(s);
        (p + V2::new(-t.y, t.x) * lateral, t)
    }

    /// Closest point of the path to `p`: (arc length, signed lateral offset, left > 0).
    pub fn project(&self, p: V2) -> (f64, f64) {
        let mut best = (0.0, f64::INFINITY, 0.0);
        for (piece, start) in self.pieces.iter().zip(&self.starts) {
            let (s, dist, lateral) = piece.project(p);
            if dist < best.1 {
                best = (start + s, dist, lateral);
            }
        }
        (best.0, best.2)
    }

    /// Arc-length ranges `(start, end)` of the straight pieces.
    pub fn straights(&self) -> Vec<(f64, f64)> {
        self.pieces
            .iter()
            .zip(&self.starts)
            .filter(|(p, _)| matches!(p, Piece::Line { .. }))
            .map(|(p, &s0)| (s0, s0 + p.len()))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn loop_path() -> Path {
        PathBuilder::new(V2::zeros(), 0.0)
            .straight(50.0)
            .turn(10.0, PI / 2.0)
            .straight(30.0)
            .turn(10.0, PI / 2.0)
            .straight(50.0)
            .turn(10.0, PI / 2.0)
            .straight(30.0)
            .turn(10.0, PI / 2.0)
            .closed()
    }

    #[test]
    fn loop_closes_and_projection_inverts_offset() {
        let path = loop_path();
        let (end, t_end) = path.at(path.length() - 1e-9);
        assert!(end.norm() < 1e-6, "{end}");
        assert!((t_end - V2::x()).norm() < 1e-6);
        for i in 0..200 {
            let s = i as f64 * path.length() / 200.0;
            for lateral in [-4.0, -1.0, 0.0, 2.5] {
                let (p, _) = path.offset(s, lateral);
                let (s2, l2) = path.project(p);
                assert!(
                    (l2 - lateral).abs() < 1e-6,
                    "s {s} lateral {lateral} -> {l2}"
                );
                let ds = (s2 - s).abs();
                assert!(
                    ds < 1e-6 || (ds - path.length()).abs() < 1e-6,
                    "{s} -> {s2}"
                );
            }
        }
    }

    #[test]
    fn right_turns_have_the_centre_on_the_right() {
        let path = PathBuilder::new(V2::zeros(), 0.0)
            .turn(20.0, -PI / 2.0)
            .open();
        let (end, t) = path.at(path.length());
        assert!((end - V2::new(20.0, -20.0)).norm() < 1e-9, "{end}");
        assert!((t - V2::new(0.0, -1.0)).norm() < 1e-9);
        let (_, lateral) = path.project(V2::new(10.0, -3.0));
        assert!(lateral < 0.0);
    }
}
