//! The triangle mesh itself ([`Mesh`]) and its vertex normals, below every stage that builds or
//! edits one.

use crate::cloud::Bounds;

/// A triangle mesh in the user's coordinates.
///
/// `normals` is either empty (not computed yet) or one unit vector per position; `colors`, when
/// present, has one RGBA (0..=255) per position. `indices` lists triangles, three per triangle,
/// counter-clockwise seen from the front (the glTF convention), each below `positions.len()`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub colors: Option<Vec<[u8; 4]>>,
    pub indices: Vec<u32>,
}

/// The normal given to a vertex that has no well-defined one (unused, or only on zero-area
/// triangles), so that every normal is a unit vector.
pub const FALLBACK_NORMAL: [f32; 3] = [0.0, 0.0, 1.0];

impl Mesh {
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of whole triangles (`indices.len() / 3`).
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// True when there is no triangle to draw.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty() || self.indices.len() < 3
    }

    /// Bounds of all positions (used or not), or `None` without positions.
    pub fn bounds(&self) -> Option<Bounds> {
        Bounds::of(&self.positions)
    }

    /// Replaces `normals` with area-weighted vertex normals (see [`area_weighted_normals`]).
    pub fn compute_vertex_normals(&mut self) {
        self.normals = area_weighted_normals(&self.positions, &self.indices);
    }

    /// True when the mesh is a closed, consistently oriented surface: there is at least one
    /// triangle, no triangle repeats a vertex index or points past `positions`, and every
    /// undirected edge is shared by exactly two triangles that traverse it in opposite
    /// directions (so each directed edge occurs exactly once and so does its reverse).
    ///
    /// Edges are compared by vertex index, so an unwelded mesh (duplicated positions) is not
    /// watertight. Non-manifold vertices (two cones touching at a tip) are not detected.
    pub fn is_watertight(&self) -> bool {
        is_closed(&self.indices, self.positions.len())
    }
}

/// [`Mesh::is_watertight`] for triangles `indices` over `n` vertices.
pub(crate) fn is_closed(indices: &[u32], n: usize) -> bool {
    if indices.is_empty() || !indices.len().is_multiple_of(3) {
        return false;
    }
    if indices.chunks_exact(3).any(|t| t[0] == t[1] || t[1] == t[2] || t[0] == t[2] || t.iter().any(|&i| i as usize >= n)) {
        return false;
    }
    unpaired_edges(indices).is_empty()
}

/// The directed edges (a → b of some triangle) that do not pair up as a closed, consistently
/// oriented surface needs: used twice (inconsistent orientation, or more than two faces on the
/// edge), or without the reverse (a border). Sorted.
pub(crate) fn unpaired_edges(indices: &[u32]) -> Vec<(u32, u32)> {
    let mut edges: Vec<(u32, u32)> = indices.chunks_exact(3).flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])]).collect();
    edges.sort_unstable();
    edges
        .iter()
        .enumerate()
        .filter(|&(i, e)| edges.get(i + 1) == Some(e) || (i > 0 && edges[i - 1] == *e) || edges.binary_search(&(e.1, e.0)).is_err())
        .map(|(_, e)| *e)
        .collect()
}

/// Area-weighted vertex normals: each vertex gets the normalised sum of the (unnormalised)
/// cross products `(b - a) × (c - a)` of its triangles, so they point to the side from which
/// the triangles appear counter-clockwise. Vertices without a usable normal get
/// [`FALLBACK_NORMAL`]. Triangles with an index out of range are skipped (never a panic).
/// Accumulates in `f64`, so large coordinates (e.g. georeferenced) do not lose the direction.
pub fn area_weighted_normals(positions: &[[f32; 3]], indices: &[u32]) -> Vec<[f32; 3]> {
    let n = positions.len();
    let mut acc = vec![[0.0f64; 3]; n];
    for t in indices.chunks_exact(3) {
        let (ia, ib, ic) = (t[0] as usize, t[1] as usize, t[2] as usize);
        if ia >= n || ib >= n || ic >= n {
            continue;
        }
        let p = |i: usize| positions[i].map(f64::from);
        let (a, b, c) = (p(ia), p(ib), p(ic));
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let cr = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        if !cr.iter().all(|x| x.is_finite()) {
            continue;
        }
        for i in [ia, ib, ic] {
            for k in 0..3 {
                acc[i][k] += cr[k];
            }
        }
    }
    acc.iter().map(|s| normalize_f64(*s).unwrap_or(FALLBACK_NORMAL)).collect()
}

/// `v / |v|` as `f32`, or `None` when `v` is zero, tiny or not finite.
pub(crate) fn normalize_f64(v: [f64; 3]) -> Option<[f32; 3]> {
    if !v.iter().all(|x| x.is_finite()) {
        return None;
    }
    // Scale first so that squaring neither overflows nor underflows.
    let m = v[0].abs().max(v[1].abs()).max(v[2].abs());
    if m == 0.0 || !m.is_finite() {
        return None;
    }
    let s = [v[0] / m, v[1] / m, v[2] / m];
    let len = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
    let out = [(s[0] / len) as f32, (s[1] / len) as f32, (s[2] / len) as f32];
    let l2 = out.iter().map(|&x| f64::from(x) * f64::from(x)).sum::<f64>();
    ((l2 - 1.0).abs() < 1e-5).then_some(out)
}
