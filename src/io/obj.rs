//! Reading Wavefront OBJ meshes (the evaluation's ground truths, `tests/data/eval/*.obj`).
//!
//! Only geometry is kept: `v x y z [w | r g b]` gives a position (a fourth `w` or trailing
//! colour values are ignored), `f` a polygon, which is fan-triangulated (`a b c d` →
//! `a b c`, `a c d`). Face corners may be `v`, `v/vt`, `v//vn` or `v/vt/vn`; only `v` is used,
//! so a mesh whose corners share positions but not texture coordinates stays welded (what
//! [`Mesh::is_watertight`] needs). Indices are 1-based; negative ones count back from the last
//! vertex defined so far (`-1` is the latest). Positive indices are checked once the whole file
//! is read, so a face may name a vertex defined after it.
//!
//! Everything else (`vt`, `vn`, `vp`, `o`, `g`, `s`, `usemtl`, `mtllib`, `l`, `p`, comments,
//! unknown statements) is skipped. A line ending in `\` continues on the next one. Errors name
//! the line; nothing panics, and memory stays proportional to the input.

use std::fmt;

use crate::mesh::Mesh;

/// Why an OBJ file cannot be read, with the 1-based line it happened on.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjError {
    pub line: usize,
    pub kind: ObjErrorKind,
}

#[derive(Clone, Debug, PartialEq)]
pub enum ObjErrorKind {
    /// A `v` line with fewer than three numbers, or one that is not a finite number.
    BadVertex(String),
    /// A face corner that is not `v`, `v/vt`, `v//vn` or `v/vt/vn` with integer `v`.
    BadCorner(String),
    /// A face with fewer than three corners.
    TooFewCorners(usize),
    /// Index 0 (OBJ is 1-based).
    ZeroIndex,
    /// The index names no vertex: `index` as written, `vertices` defined (by the end of the
    /// file for positive indices, by that line for negative ones).
    IndexOutOfRange { index: i64, vertices: usize },
    /// More vertices than a `u32` index can name.
    TooManyVertices,
    /// No face at all (a point cloud or an empty file).
    NoFaces,
}

impl fmt::Display for ObjError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "line {}: ", self.line)?;
        match &self.kind {
            ObjErrorKind::BadVertex(s) => write!(f, "vertex needs three finite numbers, got '{s}'"),
            ObjErrorKind::BadCorner(s) => write!(f, "face corner '{s}' is not v, v/vt, v//vn or v/vt/vn"),
            ObjErrorKind::TooFewCorners(n) => write!(f, "face has {n} corners, needs at least 3"),
            ObjErrorKind::ZeroIndex => write!(f, "vertex index 0 (OBJ indices start at 1)"),
            ObjErrorKind::IndexOutOfRange { index, vertices } => {
                write!(f, "vertex index {index} out of range ({vertices} vertices)")
            }
            ObjErrorKind::TooManyVertices => write!(f, "more than 2^32 - 1 vertices"),
            ObjErrorKind::NoFaces => write!(f, "no faces in the file (end of file)"),
        }
    }
}

impl std::error::Error for ObjError {}

/// Reads the positions and triangles of an OBJ file (see the module documentation). The mesh
/// has no normals or colours.
pub fn read_obj(bytes: &[u8]) -> Result<Mesh, ObjError> {
    let text = String::from_utf8_lossy(bytes);
    let mut state = State::default();
    let mut logical = String::new();
    let mut start_line = 1;
    let mut lines = 0;
    for (n, raw) in text.lines().enumerate() {
        lines = n + 1;
        if logical.is_empty() {
            start_line = n + 1;
        }
        let raw = raw.strip_suffix('\r').unwrap_or(raw);
        match raw.strip_suffix('\\') {
            Some(head) => {
                logical.push_str(head);
                logical.push(' ');
            }
            None => {
                logical.push_str(raw);
                state.line(start_line, &logical)?;
                logical.clear();
            }
        }
    }
    if !logical.is_empty() {
        state.line(start_line, &logical)?; // a continuation at the very end: take it as is
    }
    let count = state.positions.len();
    if let Some(&(line, index)) = state.forward.iter().find(|&&(_, i)| i as usize > count) {
        return Err(ObjError { line, kind: ObjErrorKind::IndexOutOfRange { index: index as i64, vertices: count } });
    }
    if state.indices.is_empty() {
        return Err(ObjError { line: lines.max(1), kind: ObjErrorKind::NoFaces });
    }
    Ok(Mesh { positions: state.positions, normals: Vec::new(), colors: None, indices: state.indices })
}

#[derive(Default)]
struct State {
    positions: Vec<[f32; 3]>,
    indices: Vec<u32>,
    /// Faces that named a vertex not defined yet: (line, largest such 1-based index).
    forward: Vec<(usize, u32)>,
    corners: Vec<u32>,
}

impl State {
    fn line(&mut self, line: usize, text: &str) -> Result<(), ObjError> {
        let err = |kind| ObjError { line, kind };
        let content = text.split('#').next().unwrap_or("");
        let mut words = content.split_ascii_whitespace();
        match words.next() {
            Some("v") => {
                let rest: Vec<&str> = words.collect();
                let p: Vec<f32> = rest.iter().take(3).map_while(|w| w.parse::<f32>().ok().filter(|x| x.is_finite())).collect();
                if p.len() < 3 {
                    return Err(err(ObjErrorKind::BadVertex(rest.join(" "))));
                }
                if self.positions.len() >= u32::MAX as usize {
                    return Err(err(ObjErrorKind::TooManyVertices));
                }
                self.positions.push([p[0], p[1], p[2]]);
            }
            Some("f") => {
                self.corners.clear();
                let mut ahead = 0u32;
                for w in words {
                    let bad = || err(ObjErrorKind::BadCorner(w.to_string()));
                    let mut fields = w.split('/');
                    let v: i64 = fields.next().unwrap_or("").parse().map_err(|_| bad())?;
                    // The other fields must be empty or integers (v//vn, v/vt/vn); at most three.
                    let rest: Vec<&str> = fields.collect();
                    if rest.len() > 2 || rest.iter().any(|s| !s.is_empty() && s.parse::<i64>().is_err()) {
                        return Err(bad());
                    }
                    let count = self.positions.len() as i64;
                    let out_of_range = || err(ObjErrorKind::IndexOutOfRange { index: v, vertices: count as usize });
                    let zero_based = match v {
                        0 => return Err(err(ObjErrorKind::ZeroIndex)),
                        v if v < 0 => count.checked_add(v).filter(|&k| k >= 0).ok_or_else(out_of_range)?,
                        v if v > u32::MAX as i64 => return Err(out_of_range()),
                        v => {
                            if v > count {
                                ahead = ahead.max(v as u32);
                            }
                            v - 1
                        }
                    };
                    self.corners.push(zero_based as u32);
                }
                if self.corners.len() < 3 {
                    return Err(err(ObjErrorKind::TooFewCorners(self.corners.len())));
                }
                if ahead > 0 {
                    self.forward.push((line, ahead));
                }
                let c = &self.corners;
                for k in 1..c.len() - 1 {
                    self.indices.extend_from_slice(&[c[0], c[k], c[k + 1]]);
                }
            }
            _ => {}
        }
        Ok(())
    }
}
