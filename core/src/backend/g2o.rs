//! The g2o text format for 3-D pose graphs, the one public benchmarks ship in:
//! `VERTEX_SE3:QUAT id x y z qx qy qz qw`, `EDGE_SE3:QUAT from to x y z qx qy qz qw` followed by
//! the 21 entries of the upper triangle of the 6×6 information matrix (row by row, ordered
//! [translation, rotation] as in [`super::pose_graph`]), and `FIX id`. Vertex ids may be any
//! non-negative integers; they are kept so that a written file names the same vertices.
//! Numbers are written in Rust's shortest round-trip form, so read → write → read is exact.

use std::collections::HashMap;
use std::fmt::Write as _;

use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion};
use thiserror::Error;

use super::pose_graph::{Edge, PoseGraph};

/// A pose graph with the vertex ids of its file.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct G2oGraph {
    /// The file's id of each node, in node order.
    pub ids: Vec<u64>,
    /// Nodes and edges. Edges between non-consecutive ids are marked robust (loop closures).
    pub graph: PoseGraph,
}

/// Why a g2o file cannot be read.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum G2oError {
    /// A line has too few fields or a field is not a number.
    #[error("line {line}: malformed {tag}: {reason}")]
    Malformed {
        /// 1-based line number.
        line: usize,
        /// The record's tag.
        tag: String,
        /// What is wrong.
        reason: String,
    },
    /// A record type we do not read (2-D poses, landmarks, …).
    #[error(
        "line {line}: unsupported record {tag:?} (only VERTEX_SE3:QUAT, EDGE_SE3:QUAT and FIX)"
    )]
    Unsupported {
        /// 1-based line number.
        line: usize,
        /// The record's tag.
        tag: String,
    },
    /// An id is defined twice.
    #[error("line {line}: vertex {id} defined twice")]
    DuplicateVertex {
        /// 1-based line number.
        line: usize,
        /// The id.
        id: u64,
    },
    /// An edge or FIX names a vertex never defined.
    #[error("line {line}: vertex {id} is not defined")]
    UnknownVertex {
        /// 1-based line number.
        line: usize,
        /// The id.
        id: u64,
    },
}

fn pose_from(fields: &[f64]) -> Isometry3<f64> {
    let q = Quaternion::new(fields[6], fields[3], fields[4], fields[5]);
    // Files written with few digits hold quaternions a little off unit length: normalise
    // those, but keep one already unit to rounding as it is, so that writing it back is exact.
    let rotation = if (q.norm() - 1.0).abs() <= 4.0 * f64::EPSILON {
        UnitQuaternion::new_unchecked(q)
    } else {
        UnitQuaternion::from_quaternion(q)
    };
    Isometry3::from_parts(Translation3::new(fields[0], fields[1], fields[2]), rotation)
}

/// Reads a g2o file's text. Edges are resolved after all vertices, so their order in the file
/// does not matter.
pub fn parse(text: &str) -> Result<G2oGraph, G2oError> {
    let mut out = G2oGraph::default();
    let mut index: HashMap<u64, usize> = HashMap::new();
    let mut pending_edges = Vec::new();
    let mut pending_fix = Vec::new();
    for (k, raw) in text.lines().enumerate() {
        let line = k + 1;
        let mut tokens = raw.split_whitespace();
        let Some(tag) = tokens.next() else { continue };
        if tag.starts_with('#') {
            continue;
        }
        let malformed = |reason: String| G2oError::Malformed {
            line,
            tag: tag.to_string(),
            reason,
        };
        let rest: Vec<&str> = tokens.collect();
        let id = |s: &str| {
            s.parse::<u64>()
                .map_err(|e| malformed(format!("id {s:?}: {e}")))
        };
        let numbers = |s: &[&str], n: usize| -> Result<Vec<f64>, G2oError> {
            if s.len() < n {
                return Err(malformed(format!("{} numbers, expected {n}", s.len())));
            }
            s[..n]
                .iter()
                .map(|v| {
                    v.parse::<f64>()
                        .ok()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| malformed(format!("{v:?} is not a finite number")))
                })
                .collect()
        };
        match tag {
            "VERTEX_SE3:QUAT" => {
                let v = id(rest.first().copied().unwrap_or(""))?;
                let f = numbers(rest.get(1..).unwrap_or(&[]), 7)?;
                if index.insert(v, out.ids.len()).is_some() {
                    return Err(G2oError::DuplicateVertex { line, id: v });
                }
                out.ids.push(v);
                out.graph.add_node(pose_from(&f), false);
            }
            "EDGE_SE3:QUAT" => {
                if rest.len() < 2 {
                    return Err(malformed("missing vertex ids".into()));
                }
                let (a, b) = (id(rest[0])?, id(rest[1])?);
                let f = numbers(&rest[2..], 7 + 21)?;
                let mut information = Matrix6::zeros();
                let mut upper = f[7..].iter();
                for r in 0..6 {
                    for c in r..6 {
                        let v = *upper.next().expect("21 entries were read");
                        information[(r, c)] = v;
                        information[(c, r)] = v;
                    }
                }
                pending_edges.push((line, a, b, pose_from(&f), information));
            }
            "FIX" => {
                for s in &rest {
                    pending_fix.push((line, id(s)?));
                }
            }
            _ => {
                return Err(G2oError::Unsupported {
                    line,
                    tag: tag.to_string(),
                })
            }
        }
    }
    let find = |line: usize, id: u64| {
        index
            .get(&id)
            .copied()
            .ok_or(G2oError::UnknownVertex { line, id })
    };
    for (line, a, b, measurement, information) in pending_edges {
        let (from, to) = (find(line, a)?, find(line, b)?);
        out.graph.edges.push(Edge {
            from,
            to,
            measurement,
            information,
            robust: a.abs_diff(b) != 1,
        });
    }
    for (line, v) in pending_fix {
        let node = find(line, v)?;
        out.graph.fixed[node] = true;
    }
    Ok(out)
}

fn write_pose(out: &mut String, p: &Isometry3<f64>) {
    let t = p.translation.vector;
    let q = p.rotation.quaternion();
    let _ = write!(
        out,
        "{} {} {} {} {} {} {}",
        t.x, t.y, t.z, q.i, q.j, q.k, q.w
    );
}

/// Writes the graph as g2o text: vertices, then edges, then `FIX` lines.
pub fn write(g: &G2oGraph) -> String {
    let mut out = String::new();
    for (id, pose) in g.ids.iter().zip(&g.graph.poses) {
        let _ = write!(out, "VERTEX_SE3:QUAT {id} ");
        write_pose(&mut out, pose);
        out.push('\n');
    }
    for e in &g.graph.edges {
        let _ = write!(out, "EDGE_SE3:QUAT {} {} ", g.ids[e.from], g.ids[e.to]);
        write_pose(&mut out, &e.measurement);
        for r in 0..6 {
            for c in r..6 {
                let _ = write!(out, " {}", e.information[(r, c)]);
            }
        }
        out.push('\n');
    }
    for (id, fixed) in g.ids.iter().zip(&g.graph.fixed) {
        if *fixed {
            let _ = writeln!(out, "FIX {id}");
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const SAMPLE: &str = "\
# a comment
VERTEX_SE3:QUAT 10 0 0 0 0 0 0 1
VERTEX_SE3:QUAT 11 1.5 -0.25 0.125 0.0106 -0.0087 0.0019 0.99990
VERTEX_SE3:QUAT 13 3 0.1 0 0 0 0.7071067811865476 0.7071067811865476
EDGE_SE3:QUAT 10 11 1.5 -0.25 0.125 0 0 0 1 100 0 0 0 0 0 100 0 0 0 0 100 0 0 0 400 0 0 400 0 400
EDGE_SE3:QUAT 11 13 1.5 0.3 0 0 0 0.7 0.714 10 1 0 0 0 0 10 0 0 0 0 10 0 0 0 40 0 0 40 0 40
EDGE_SE3:QUAT 10 13 3 0.1 0 0 0 0.7071067811865476 0.7071067811865476 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1
FIX 10
";

    #[test]
    fn reads_vertices_edges_and_fix() {
        let g = parse(SAMPLE).expect("valid");
        assert_eq!(g.ids, vec![10, 11, 13]);
        assert_eq!(g.graph.edges.len(), 3);
        assert_eq!(g.graph.fixed, vec![true, false, false]);
        let e = &g.graph.edges[1];
        assert_eq!((e.from, e.to), (1, 2));
        assert_eq!(e.information[(0, 1)], 1.0);
        assert_eq!(e.information[(1, 0)], 1.0);
        assert_eq!(e.information[(5, 5)], 40.0);
        // 10 → 11 is consecutive (odometry); 11 → 13 and 10 → 13 are not.
        let robust: Vec<bool> = g.graph.edges.iter().map(|e| e.robust).collect();
        assert_eq!(robust, vec![false, true, true]);
        // Quaternions are normalised on reading.
        assert!((e.measurement.rotation.norm() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn write_then_read_is_exact() {
        let g = parse(SAMPLE).expect("valid");
        let text = write(&g);
        let back = parse(&text).expect("own output is valid");
        assert_eq!(back, g);
        assert_eq!(write(&back), text);
    }

    #[test]
    fn errors_name_the_line() {
        assert!(matches!(
            parse("VERTEX_SE3:QUAT 0 1 2 3\n"),
            Err(G2oError::Malformed { line: 1, .. })
        ));
        assert!(matches!(
            parse("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE2 1 0 0 0\n"),
            Err(G2oError::Unsupported { line: 2, .. })
        ));
        assert!(matches!(
            parse("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nFIX 4\n"),
            Err(G2oError::UnknownVertex { line: 2, id: 4 })
        ));
        assert!(matches!(
            parse("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n"),
            Err(G2oError::DuplicateVertex { line: 2, id: 0 })
        ));
        assert!(matches!(
            parse("VERTEX_SE3:QUAT 0 0 0 nan 0 0 0 1\n"),
            Err(G2oError::Malformed { line: 1, .. })
        ));
    }
}
