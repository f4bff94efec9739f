//! g2o pose graphs: `VERTEX_SE3:QUAT`, `EDGE_SE3:QUAT`, `VERTEX_SE2`, `EDGE_SE2`.
//!
//! As GTSAM's `readG2o` does, the 3D information matrices (g2o order: translation, then
//! rotation) are permuted into GTSAM's tangent order (rotation, then translation).

use crate::graph::{Between, GraphError, PoseGraph};
use crate::lie::{Se2, Se3};
use nalgebra::{Quaternion, SMatrix, UnitQuaternion, Vector3};
use std::collections::BTreeMap;
use std::io::{BufRead, Write};
use std::path::Path;

/// A pose graph read from g2o, 2D or 3D.
#[derive(Debug, Clone)]
pub enum G2oGraph {
    /// SE(2) graph.
    Planar(PoseGraph<Se2, 3>),
    /// SE(3) graph.
    Spatial(PoseGraph<Se3, 6>),
}

/// What a read skipped.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReadReport {
    /// Lines with tags this reader does not know, by tag.
    pub unknown_tags: BTreeMap<String, usize>,
}

fn parse_err(path: &Path, line: usize, msg: impl Into<String>) -> GraphError {
    GraphError::Parse {
        path: path.to_path_buf(),
        line,
        message: msg.into(),
    }
}

fn numbers(
    fields: &[&str],
    path: &Path,
    line: usize,
    want: usize,
    tag: &str,
) -> Result<Vec<f64>, GraphError> {
    if fields.len() != want {
        return Err(parse_err(
            path,
            line,
            format!(
                "{tag} needs {want} values after the tag, found {}",
                fields.len()
            ),
        ));
    }
    fields
        .iter()
        .enumerate()
        .map(|(i, f)| match f.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(parse_err(
                path,
                line,
                format!("{tag}: value {} ('{f}') is not a finite number", i + 1),
            )),
        })
        .collect()
}

fn id(v: f64, path: &Path, line: usize) -> Result<usize, GraphError> {
    if v < 0.0 || v.fract() != 0.0 || v > 1e12 {
        return Err(parse_err(
            path,
            line,
            format!("vertex id {v} is not a non-negative integer"),
        ));
    }
    Ok(v as usize)
}

fn upper_to_full<const D: usize>(vals: &[f64]) -> SMatrix<f64, D, D> {
    let mut m = SMatrix::<f64, D, D>::zeros();
    let mut k = 0;
    for r in 0..D {
        for c in r..D {
            m[(r, c)] = vals[k];
            m[(c, r)] = vals[k];
            k += 1;
        }
    }
    m
}

/// Reads a g2o file. Unknown tags are skipped and counted; malformed lines, edges to
/// missing vertices and information matrices that are not positive definite are errors
/// naming the line. A file mixing 2D and 3D elements is an error.
pub fn read_g2o(path: &Path) -> Result<(G2oGraph, ReadReport), GraphError> {
    let f = std::fs::File::open(path).map_err(|e| GraphError::Io {
        path: path.to_path_buf(),
        source: e,
    })?;
    let mut report = ReadReport::default();
    let mut v2: BTreeMap<usize, Se2> = BTreeMap::new();
    let mut v3: BTreeMap<usize, Se3> = BTreeMap::new();
    let mut e2: Vec<(usize, usize, Se2, SMatrix<f64, 3, 3>, usize)> = Vec::new();
    let mut e3: Vec<(usize, usize, Se3, SMatrix<f64, 6, 6>, usize)> = Vec::new();
    for (n, line) in std::io::BufReader::new(f).lines().enumerate() {
        let ln = n + 1;
        let line = line.map_err(|e| GraphError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        let mut it = line.split_whitespace();
        let Some(tag) = it.next() else { continue };
        if tag.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = it.collect();
        match tag {
            "VERTEX_SE2" => {
                let v = numbers(&fields, path, ln, 4, tag)?;
                v2.insert(id(v[0], path, ln)?, Se2::new(v[1], v[2], v[3]));
            }
            "EDGE_SE2" => {
                let v = numbers(&fields, path, ln, 11, tag)?;
                let info = upper_to_full::<3>(&v[5..11]);
                e2.push((
                    id(v[0], path, ln)?,
                    id(v[1], path, ln)?,
                    Se2::new(v[2], v[3], v[4]),
                    info,
                    ln,
                ));
            }
            "VERTEX_SE3:QUAT" => {
                let v = numbers(&fields, path, ln, 8, tag)?;
                let q = quaternion(v[7], v[4], v[5], v[6])
                    .ok_or_else(|| parse_err(path, ln, "zero quaternion"))?;
                v3.insert(
                    id(v[0], path, ln)?,
                    Se3::from_quaternion(&q, Vector3::new(v[1], v[2], v[3])),
                );
            }
            "EDGE_SE3:QUAT" => {
                let v = numbers(&fields, path, ln, 30, tag)?;
                let q = quaternion(v[8], v[5], v[6], v[7])
                    .ok_or_else(|| parse_err(path, ln, "zero quaternion"))?;
                let g = upper_to_full::<6>(&v[9..30]);
                // g2o (t, r) -> GTSAM (r, t)
                let perm = [3usize, 4, 5, 0, 1, 2];
                let info = SMatrix::<f64, 6, 6>::from_fn(|r, c| g[(perm[r], perm[c])]);
                e3.push((
                    id(v[0], path, ln)?,
                    id(v[1], path, ln)?,
                    Se3::from_quaternion(&q, Vector3::new(v[2], v[3], v[4])),
                    info,
                    ln,
                ));
            }
            other => *report.unknown_tags.entry(other.to_string()).or_default() += 1,
        }
    }
    let is3d = !v3.is_empty() || !e3.is_empty();
    if is3d && (!v2.is_empty() || !e2.is_empty()) {
        return Err(GraphError::Invalid {
            path: path.to_path_buf(),
            message: "file mixes SE2 and SE3 elements".into(),
        });
    }
    if v2.is_empty() && v3.is_empty() {
        return Err(GraphError::Invalid {
            path: path.to_path_buf(),
            message: "no VERTEX_SE2 or VERTEX_SE3:QUAT lines".into(),
        });
    }
    let graph = if is3d {
        G2oGraph::Spatial(build(path, v3, e3)?)
    } else {
        G2oGraph::Planar(build(path, v2, e2)?)
    };
    Ok((graph, report))
}

fn quaternion(w: f64, x: f64, y: f64, z: f64) -> Option<UnitQuaternion<f64>> {
    let q = Quaternion::new(w, x, y, z);
    (q.norm() > 1e-12).then(|| UnitQuaternion::from_quaternion(q))
}

type RawEdge<G, const D: usize> = (usize, usize, G, SMatrix<f64, D, D>, usize);

fn build<G: crate::lie::LieGroup<D>, const D: usize>(
    path: &Path,
    vertices: BTreeMap<usize, G>,
    edges: Vec<RawEdge<G, D>>,
) -> Result<PoseGraph<G, D>, GraphError> {
    let keys: Vec<usize> = vertices.keys().copied().collect();
    let index: BTreeMap<usize, usize> = keys.iter().enumerate().map(|(i, &k)| (k, i)).collect();
    let mut graph = PoseGraph::new(keys, vertices.into_values().collect());
    for (a, b, z, info, ln) in edges {
        let (Some(&i), Some(&j)) = (index.get(&a), index.get(&b)) else {
            let missing = if index.contains_key(&a) { b } else { a };
            return Err(parse_err(
                path,
                ln,
                format!("edge {a} -> {b} refers to vertex {missing}, which is not defined"),
            ));
        };
        let factor = Between::new(i, j, z, &info).map_err(|m| parse_err(path, ln, m))?;
        graph.between.push(factor);
    }
    Ok(graph)
}

/// Writes a graph (vertices with their current values, edges with their measurements).
pub fn write_g2o(path: &Path, graph: &G2oGraph) -> Result<(), GraphError> {
    let io = |e| GraphError::Io {
        path: path.to_path_buf(),
        source: e,
    };
    let mut w = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    match graph {
        G2oGraph::Planar(g) => {
            for (k, p) in g.keys.iter().zip(&g.values) {
                writeln!(w, "VERTEX_SE2 {k} {} {} {}", p.x, p.y, p.theta).map_err(io)?;
            }
            for f in &g.between {
                let m = f.information();
                let z = f.measured;
                writeln!(
                    w,
                    "EDGE_SE2 {} {} {} {} {} {} {} {} {} {} {}",
                    g.keys[f.i],
                    g.keys[f.j],
                    z.x,
                    z.y,
                    z.theta,
                    m[(0, 0)],
                    m[(0, 1)],
                    m[(0, 2)],
                    m[(1, 1)],
                    m[(1, 2)],
                    m[(2, 2)]
                )
                .map_err(io)?;
            }
        }
        G2oGraph::Spatial(g) => {
            let q = |p: &Se3| UnitQuaternion::from_matrix(&p.r);
            for (k, p) in g.keys.iter().zip(&g.values) {
                let r = q(p);
                writeln!(
                    w,
                    "VERTEX_SE3:QUAT {k} {} {} {} {} {} {} {}",
                    p.t.x, p.t.y, p.t.z, r.i, r.j, r.k, r.w
                )
                .map_err(io)?;
            }
            let perm = [3usize, 4, 5, 0, 1, 2];
            for f in &g.between {
                let m = f.information();
                let z = f.measured;
                let r = q(&z);
                write!(
                    w,
                    "EDGE_SE3:QUAT {} {} {} {} {} {} {} {} {}",
                    g.keys[f.i], g.keys[f.j], z.t.x, z.t.y, z.t.z, r.i, r.j, r.k, r.w
                )
                .map_err(io)?;
                for a in 0..6 {
                    for b in a..6 {
                        // back to g2o order (t, r): g2o index a maps to our perm-inverse
                        let (ia, ib) = (perm[a], perm[b]);
                        write!(w, " {}", m[(ia, ib)]).map_err(io)?;
                    }
                }
                writeln!(w).map_err(io)?;
            }
        }
    }
    w.flush().map_err(io)
}
