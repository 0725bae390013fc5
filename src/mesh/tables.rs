//! The marching cubes case table, generated at first use instead of typed in.
//!
//! Conventions (shared with `shaders/marching_cubes.wgsl`):
//!
//! - corner `i` of a cell has offset `(i & 1, (i >> 1) & 1, (i >> 2) & 1)`; a corner is INSIDE
//!   when its value is `> 0`, and the case index has bit `i` set for an inside corner;
//! - edge `e` runs along axis `a = e / 4` from its low corner (bit `a` clear) to its high
//!   corner; with `u = (a + 1) % 3` and `v = (a + 2) % 3`, the low corner has bit `u` equal to
//!   `e & 1` and bit `v` equal to `(e >> 1) & 1`;
//!
//! How a case is built: on each of the 6 faces of the cube, walk the face boundary
//! counter-clockwise as seen from outside the cube and list the sign changes: `A` where the walk
//! goes from an outside to an inside corner, `B` from inside to outside. Each `A` is joined to a
//! `B` by a segment `A → B`, which leaves the inside corners on its right (seen from outside the
//! cube). A face with two crossings has one way to do this. A face with four (the ambiguous
//! face: inside corners on one diagonal, outside on the other) has two; we always join the
//! inside corners across the face ([`CONNECT_INSIDE`]), i.e. we cut off the two outside
//! corners. The choice depends only on the signs of the face's own four corners, so the two
//! cells that share a face make the same segments (in opposite directions): that is what makes
//! the global mesh watertight. Every crossed edge lies on two faces and is an `A` on one and a
//! `B` on the other, so the segments chain into closed loops; each loop is one polygon of the
//! surface, wound counter-clockwise seen from the outside (where the field is `<= 0`).
//!
//! Triangulating a loop: a fan from one of its vertices, except that a fan diagonal must not
//! join two crossings on the same cube face (only possible across an ambiguous face): the
//! neighbouring cell may have made the same diagonal, and then four triangles would share one
//! edge. The apex is the first loop vertex whose fan has no such diagonal. (With this face rule
//! every loop has such a vertex — the build asserts it — so no loop needs an extra centre
//! vertex, and a cell makes at most 5 triangles, like the classic table.)

use std::sync::OnceLock;

/// At an ambiguous face (inside corners on one diagonal), join the inside corners (`true`) or
/// separate them (`false`). Joining keeps thin walls of the object closed at the resolution
/// limit, at the price of sometimes bridging two parts that nearly touch.
pub const CONNECT_INSIDE: bool = true;

/// Words per case in [`CaseTable::gpu_words`] before the triangles: the triangle count.
pub const GPU_HEADER: usize = 1;

/// Endpoints `(low corner, high corner)` of edge `e`.
pub const fn edge_corners(e: usize) -> (usize, usize) {
    let a = e / 4;
    let u = (a + 1) % 3;
    let v = (a + 2) % 3;
    let lo = ((e & 1) << u) | (((e >> 1) & 1) << v);
    (lo, lo | (1 << a))
}

/// Axis of edge `e`.
pub const fn edge_axis(e: usize) -> usize {
    e / 4
}

/// The edge joining corners `c` and `d`, which must differ in exactly one bit.
fn edge_between(c: usize, d: usize) -> usize {
    let diff = c ^ d;
    debug_assert!(diff.is_power_of_two() && diff < 8);
    let a = diff.trailing_zeros() as usize;
    let lo = c & d;
    let u = (a + 1) % 3;
    let v = (a + 2) % 3;
    a * 4 + ((lo >> u) & 1) + 2 * ((lo >> v) & 1)
}

/// The corners of face `f` (axis `f / 2`, side `f % 2`), counter-clockwise seen from outside.
fn face_corners(f: usize) -> [usize; 4] {
    let a = f / 2;
    let s = f % 2;
    let u = (a + 1) % 3;
    let v = (a + 2) % 3;
    let c = |bu: usize, bv: usize| (s << a) | (bu << u) | (bv << v);
    // e_u × e_v = e_a, so (0,0) (1,0) (1,1) (0,1) in (u, v) is counter-clockwise about +e_a.
    if s == 1 {
        [c(0, 0), c(1, 0), c(1, 1), c(0, 1)]
    } else {
        [c(0, 0), c(0, 1), c(1, 1), c(1, 0)]
    }
}

/// Bit mask of the two faces edge `e` lies on.
fn edge_face_mask(e: usize) -> u8 {
    let (lo, _) = edge_corners(e);
    let mut m = 0u8;
    for f in 0..6 {
        let a = f / 2;
        let s = f % 2;
        if a != edge_axis(e) && ((lo >> a) & 1) == s {
            m |= 1 << f;
        }
    }
    m
}

/// The triangulation of one case.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Case {
    /// Triangles as edge ids, counter-clockwise seen from outside.
    pub triangles: Vec<[u8; 3]>,
    /// The loops, as edge ids in order (for tests and documentation).
    pub loops: Vec<Vec<u8>>,
}

/// All 256 cases.
#[derive(Debug)]
pub struct CaseTable {
    pub cases: Vec<Case>,
    /// The most triangles any case has.
    pub max_triangles: usize,
}

impl CaseTable {
    /// The table, built on first use.
    pub fn get() -> &'static CaseTable {
        static TABLE: OnceLock<CaseTable> = OnceLock::new();
        TABLE.get_or_init(CaseTable::build)
    }

    fn build() -> CaseTable {
        let cases: Vec<Case> = (0..256).map(build_case).collect();
        let max_triangles = cases.iter().map(|c| c.triangles.len()).max().unwrap_or(0);
        CaseTable { cases, max_triangles }
    }

    /// `u32` words per case in [`Self::gpu_words`].
    pub fn gpu_stride(&self) -> usize {
        GPU_HEADER + 3 * self.max_triangles
    }

    /// The table as the GPU kernel reads it: per case, `[triangle count, edge ids × 3 ×
    /// max_triangles]` (unused slots zero).
    pub fn gpu_words(&self) -> Vec<u32> {
        let stride = self.gpu_stride();
        let mut w = vec![0u32; 256 * stride];
        for (i, c) in self.cases.iter().enumerate() {
            let base = i * stride;
            w[base] = c.triangles.len() as u32;
            for (t, tri) in c.triangles.iter().enumerate() {
                for k in 0..3 {
                    w[base + GPU_HEADER + 3 * t + k] = tri[k] as u32;
                }
            }
        }
        w
    }
}

fn build_case(case: usize) -> Case {
    let inside = |c: usize| (case >> c) & 1 == 1;
    // next[e]: the edge the loop goes to from crossing e.
    let mut next = [usize::MAX; 12];
    for f in 0..6 {
        let q = face_corners(f);
        // (edge, is_A) in counter-clockwise order.
        let mut cross: Vec<(usize, bool)> = Vec::with_capacity(4);
        for i in 0..4 {
            let (c, d) = (q[i], q[(i + 1) % 4]);
            if inside(c) != inside(d) {
                cross.push((edge_between(c, d), inside(d)));
            }
        }
        let n = cross.len();
        for (j, &(e, is_a)) in cross.iter().enumerate() {
            if !is_a {
                continue;
            }
            // Crossings alternate A, B, so the neighbours of an A are Bs.
            let k = if CONNECT_INSIDE { (j + n - 1) % n } else { (j + 1) % n };
            debug_assert!(!cross[k].1);
            debug_assert_eq!(next[e], usize::MAX, "edge {e} is an A on two faces");
            next[e] = cross[k].0;
        }
    }
    let mut loops: Vec<Vec<u8>> = Vec::new();
    let mut seen = [false; 12];
    for start in 0..12 {
        if next[start] == usize::MAX || seen[start] {
            continue;
        }
        let mut lp = Vec::new();
        let mut e = start;
        while !seen[e] {
            seen[e] = true;
            lp.push(e as u8);
            e = next[e];
            assert!(e != usize::MAX, "case {case}: open loop");
        }
        assert_eq!(e, start, "case {case}: loop does not close");
        loops.push(lp);
    }
    let faces: Vec<u8> = (0..12).map(edge_face_mask).collect();
    let mut triangles = Vec::new();
    for lp in &loops {
        let n = lp.len();
        assert!(n >= 3, "case {case}: loop of {n}");
        let a = (0..n)
            .find(|&a| (2..n - 1).all(|i| faces[lp[a] as usize] & faces[lp[(a + i) % n] as usize] == 0))
            .unwrap_or_else(|| panic!("case {case}: loop {lp:?} has no fan without a diagonal on a face"));
        for i in 1..n - 1 {
            triangles.push([lp[a], lp[(a + i) % n], lp[(a + i + 1) % n]]);
        }
    }
    Case { triangles, loops }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edges_and_faces_are_consistent() {
        for e in 0..12 {
            let (lo, hi) = edge_corners(e);
            assert_eq!(edge_between(lo, hi), e);
            assert_eq!(edge_face_mask(e).count_ones(), 2);
        }
    }
}
