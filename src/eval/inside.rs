//! Exact inside/outside of a closed triangle mesh by ray parity.
//!
//! From the query point, a ray along +x (+y, +z) crosses a closed surface an odd number of times
//! exactly when the point is inside. Per axis, the triangles are bucketed by their projected
//! bounding boxes in a uniform 2-D grid over the other two axes, so a ray visits only the
//! triangles of one cell; the crossing is an exact-sign point-in-triangle test in `f64` on the
//! projection plus the barycentric height of the crossing. A ray through a shared edge or vertex
//! is counted once by a rasteriser's tie rule ([`owns_edge`]); as a further guard against
//! rounding in such rare cases the answer is the majority of the three axes. For an open surface (a reconstruction with holes) parity is
//! not well defined; the vote then gives the answer of at least two of three directions.

pub(crate) struct InsideTest {
    tris: Vec<[[f64; 3]; 3]>,
    grids: [AxisGrid; 3],
}

struct AxisGrid {
    axis: usize,
    min: [f64; 2],
    inv_h: [f64; 2],
    dims: [usize; 2],
    start: Vec<u32>,
    items: Vec<u32>,
}

impl InsideTest {
    pub fn new(positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> InsideTest {
        let tris: Vec<[[f64; 3]; 3]> = triangles.iter().map(|t| t.map(|i| positions[i as usize])).collect();
        let grids = [0, 1, 2].map(|a| AxisGrid::new(&tris, a));
        InsideTest { tris, grids }
    }

    pub fn contains(&self, p: [f64; 3]) -> bool {
        (0..3).filter(|&a| self.odd(a, p)).count() >= 2
    }

    /// Whether the ray from `p` along +`axis` crosses the surface an odd number of times.
    pub fn odd(&self, axis: usize, p: [f64; 3]) -> bool {
        self.grids[axis].crossings(&self.tris, p) % 2 == 1
    }
}

impl AxisGrid {
    fn new(tris: &[[[f64; 3]; 3]], axis: usize) -> AxisGrid {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let mut min = [f64::INFINITY; 2];
        let mut max = [f64::NEG_INFINITY; 2];
        for t in tris {
            for p in t {
                for (k, c) in [u, v].into_iter().enumerate() {
                    min[k] = min[k].min(p[c]);
                    max[k] = max[k].max(p[c]);
                }
            }
        }
        let mut n = ((tris.len() as f64).sqrt().ceil() as usize).clamp(1, 1024);
        loop {
            let ext = [0, 1].map(|k| (max[k] - min[k]).max(1e-300));
            let grid = AxisGrid {
                axis,
                min,
                inv_h: [0, 1].map(|k| n as f64 / ext[k]),
                dims: [n, n],
                start: Vec::new(),
                items: Vec::new(),
            };
            let ranges: Vec<[usize; 4]> = tris.iter().map(|t| grid.cell_range(t)).collect();
            let total: usize = ranges.iter().map(|r| (r[1] - r[0] + 1) * (r[3] - r[2] + 1)).sum();
            // Long slivers across a fine grid would fill too many cells: coarsen instead.
            if total > 16 * tris.len() + (1 << 20) && n > 8 {
                n /= 2;
                continue;
            }
            return grid.fill(&ranges, total);
        }
    }

    /// Cell ranges `[u0, u1, v0, v1]` (inclusive) covered by the projected bounding box of `t`.
    fn cell_range(&self, t: &[[f64; 3]; 3]) -> [usize; 4] {
        let (u, v) = ((self.axis + 1) % 3, (self.axis + 2) % 3);
        let lo = [u, v].map(|c| t.iter().map(|p| p[c]).fold(f64::INFINITY, f64::min));
        let hi = [u, v].map(|c| t.iter().map(|p| p[c]).fold(f64::NEG_INFINITY, f64::max));
        let cell = |x: f64, k: usize| (((x - self.min[k]) * self.inv_h[k]).max(0.0) as usize).min(self.dims[k] - 1);
        [cell(lo[0], 0), cell(hi[0], 0), cell(lo[1], 1), cell(hi[1], 1)]
    }

    fn fill(mut self, ranges: &[[usize; 4]], total: usize) -> AxisGrid {
        let cells = self.dims[0] * self.dims[1];
        let mut start = vec![0u32; cells + 1];
        for r in ranges {
            for j in r[2]..=r[3] {
                for i in r[0]..=r[1] {
                    start[j * self.dims[0] + i + 1] += 1;
                }
            }
        }
        for c in 0..cells {
            start[c + 1] += start[c];
        }
        let mut next = start.clone();
        let mut items = vec![0u32; total];
        for (t, r) in ranges.iter().enumerate() {
            for j in r[2]..=r[3] {
                for i in r[0]..=r[1] {
                    let c = j * self.dims[0] + i;
                    items[next[c] as usize] = t as u32;
                    next[c] += 1;
                }
            }
        }
        self.start = start;
        self.items = items;
        self
    }

    fn crossings(&self, tris: &[[[f64; 3]; 3]], p: [f64; 3]) -> usize {
        let (a, u, v) = (self.axis, (self.axis + 1) % 3, (self.axis + 2) % 3);
        let q = [p[u], p[v]];
        let fu = (q[0] - self.min[0]) * self.inv_h[0];
        let fv = (q[1] - self.min[1]) * self.inv_h[1];
        if !(fu >= 0.0 && fv >= 0.0 && fu <= self.dims[0] as f64 && fv <= self.dims[1] as f64) {
            return 0; // outside the projected bounds of every triangle
        }
        let c = (fv as usize).min(self.dims[1] - 1) * self.dims[0] + (fu as usize).min(self.dims[0] - 1);
        let mut count = 0;
        for &t in &self.items[self.start[c] as usize..self.start[c + 1] as usize] {
            let [pa, mut pb, mut pc] = tris[t as usize];
            let mut d = cross([pa[u], pa[v]], [pb[u], pb[v]], [pc[u], pc[v]]);
            if d == 0.0 {
                continue; // seen edge-on: the ray does not cross it transversally
            }
            if d < 0.0 {
                std::mem::swap(&mut pb, &mut pc); // counter-clockwise in the projection
                d = -d;
            }
            let (a2, b2, c2) = ([pa[u], pa[v]], [pb[u], pb[v]], [pc[u], pc[v]]);
            let (wa, wb, wc) = (cross(b2, c2, q), cross(c2, a2, q), cross(a2, b2, q));
            let covers = |w: f64, from: [f64; 2], to: [f64; 2]| w > 0.0 || (w == 0.0 && owns_edge(from, to));
            if covers(wa, b2, c2) && covers(wb, c2, a2) && covers(wc, a2, b2) && (wa * pa[a] + wb * pb[a] + wc * pc[a]) / d > p[a] {
                count += 1;
            }
        }
        count
    }
}

/// Tie rule for a query exactly on a projected edge (as rasterisers use): of two triangles
/// sharing the edge from opposite sides, both counter-clockwise, which traverse it in opposite
/// directions, exactly one owns it; so a ray through a shared edge or vertex is counted once.
fn owns_edge(from: [f64; 2], to: [f64; 2]) -> bool {
    let e = [to[0] - from[0], to[1] - from[1]];
    e[1] < 0.0 || (e[1] == 0.0 && e[0] < 0.0)
}

/// Twice the signed area of the 2-D triangle `(a, b, c)`.
fn cross(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// The closed unit cube [0, 1]^3 as 12 triangles.
    fn cube() -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let p = (0..8).map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64]).collect();
        let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let t = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
        (p, t)
    }

    #[test]
    fn cube_inside_matches_coordinates_on_every_axis() {
        let (p, t) = cube();
        let test = InsideTest::new(&p, &t);
        let mut r = SplitMix64(2);
        for _ in 0..20000 {
            let q = [0, 1, 2].map(|_| 2.0 * r.unit() - 0.5);
            let truth = q.iter().all(|&x| (0.0..=1.0).contains(&x));
            for a in 0..3 {
                assert_eq!(test.odd(a, q), truth, "{q:?} axis {a}");
            }
            assert_eq!(test.contains(q), truth);
        }
        // Rays through the diagonals shared by two triangles of a face, and through vertices.
        for a in 0..3 {
            assert!(test.odd(a, [0.5, 0.5, 0.5]));
            assert!(test.odd(a, [0.25, 0.25, 0.25]));
            assert!(!test.odd(a, [-0.25, -0.25, -0.25]));
            assert!(!test.odd(a, [-1.0, 0.0, 0.0]));
        }
        assert!(!test.contains([0.0 - 1e-9, 0.5, 0.5]));
    }
}
