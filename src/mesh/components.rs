//! Connected components of a mesh (triangles sharing a vertex are connected), and removal of the
//! small ones.

use super::types::Mesh;

/// The root of `x` in the union-find forest `parent`, halving the path on the way (also the
/// stray-point filter's groups, `crate::outliers`).
pub(crate) fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[x as usize];
        parent[x as usize] = parent[p as usize]; // path halving
        x = parent[x as usize];
    }
    x
}

/// The component of each triangle, numbered `0..count` in order of first appearance, and the
/// triangle count of each component. Triangles with an index out of range are their own
/// component.
pub fn triangle_components(mesh: &Mesh) -> (Vec<u32>, Vec<usize>) {
    let n = mesh.positions.len();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    for t in mesh.indices.chunks_exact(3) {
        if t.iter().any(|&i| i as usize >= n) {
            continue;
        }
        let a = find(&mut parent, t[0]);
        for &i in &t[1..] {
            let b = find(&mut parent, i);
            if a != b {
                // Union by smaller index keeps the root deterministic.
                let (lo, hi) = if a < b { (a, b) } else { (b, a) };
                parent[hi as usize] = lo;
            }
        }
    }
    let mut label = vec![u32::MAX; n];
    let mut sizes: Vec<usize> = Vec::new();
    let mut out = Vec::with_capacity(mesh.indices.len() / 3);
    for t in mesh.indices.chunks_exact(3) {
        let c = if t.iter().any(|&i| i as usize >= n) {
            sizes.push(0);
            (sizes.len() - 1) as u32
        } else {
            let r = find(&mut parent, t[0]) as usize;
            if label[r] == u32::MAX {
                label[r] = sizes.len() as u32;
                sizes.push(0);
            }
            label[r]
        };
        sizes[c as usize] += 1;
        out.push(c);
    }
    (out, sizes)
}

/// What [`remove_small_components`] did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Removal {
    pub components: usize,
    pub components_removed: usize,
    pub triangles_removed: usize,
    /// Pieces no point supports that stayed: a one-sided scan's unseen sides.
    pub unseen_kept: usize,
}

impl Removal {
    /// What the reconstruction tells the user after [`remove_unsupported_components`] with
    /// `share` (nothing when no piece went).
    pub fn unsupported_notice(&self, share: f64) -> Option<String> {
        let dropped = (self.components_removed > 0).then(|| {
            format!(
                "dropped {} of {} pieces ({} triangles) that fewer than {} % of the points are nearest to",
                self.components_removed,
                self.components,
                self.triangles_removed,
                // Three decimals at most: a scene's share is a tile's worth of points, 1/12 of 1 %.
                (100_000.0 * share).round() / 1000.0
            )
        });
        let kept = (self.unseen_kept > 0).then(|| {
            let s = if self.unseen_kept == 1 { "piece" } else { "pieces" };
            format!("kept {} {s} that no point is nearest to: the network's guess of sides the scan did not see", self.unseen_kept)
        });
        match (dropped, kept) {
            (Some(d), Some(k)) => Some(format!("{d}; {k}")),
            (d, k) => d.or(k),
        }
    }
}

/// Drops the connected components that fewer than `share` of `points` support (a point
/// supports the component of its nearest vertex), keeping always the best-supported one: the
/// floating pieces that the field raises where no points are (stray points, a network that
/// never saw them) hold no surface the cloud asks for. `points` in the mesh's coordinates.
///
/// With `keep_unseen` (a scan of one side, where what the field closes beyond the points is the
/// prior's guess of the sides the scanner never saw), the pieces that no point at all supports
/// stay: there a leg or an ear behind the seen side comes out as a piece of its own, while a
/// stray point's blob is always supported by its stray point. (On the harder set's one-sided
/// scans, CD1 x100 4.24 -> 3.99; on clouds that saw every side such pieces are the network's
/// ghosts, bunny-500 0.88 -> 0.91 when kept: they go there.)
pub fn remove_unsupported_components(mesh: &mut Mesh, points: &[[f32; 3]], share: f32, keep_unseen: bool) -> Removal {
    let (comp, sizes) = triangle_components(mesh);
    if sizes.len() < 2 || points.is_empty() {
        return Removal { components: sizes.len(), ..Default::default() };
    }
    // Each vertex's component (through any triangle of it).
    let n = mesh.positions.len();
    let mut of_vertex = vec![u32::MAX; n];
    for (t, &c) in mesh.indices.chunks_exact(3).zip(&comp) {
        for &i in t.iter().filter(|&&i| (i as usize) < n) {
            of_vertex[i as usize] = c;
        }
    }
    let index = crate::sample::PointIndex::new(&mesh.positions);
    // Each point's component (the points split over the cores), then the counts.
    let supported: Vec<u32> = crate::par::map_ranges(points.len(), |range| {
        let mut near = Vec::with_capacity(1);
        points[range]
            .iter()
            .map(|&p| {
                index.k_nearest(p, 1, &mut near);
                near.first().map_or(u32::MAX, |&(_, v)| of_vertex[v as usize])
            })
            .collect()
    });
    let mut support = vec![0usize; sizes.len()];
    for c in supported {
        if let Some(s) = support.get_mut(c as usize) {
            *s += 1;
        }
    }
    let best = (0..sizes.len()).max_by_key(|&c| (support[c], sizes[c])).unwrap_or(0);
    let need = f64::from(share) * points.len() as f64;
    let unseen = |c: usize| keep_unseen && support[c] == 0;
    let keep: Vec<bool> = (0..sizes.len()).map(|c| c == best || support[c] as f64 >= need || unseen(c)).collect();
    let unseen_kept = (0..sizes.len()).filter(|&c| c != best && unseen(c)).count();
    Removal { unseen_kept, ..remove_components(mesh, &comp, &keep) }
}

/// Drops the connected components with fewer than `fraction` times the largest component's
/// triangles, and the vertices only they used (the rest keep their order). Normals and colours,
/// when present, follow their vertices. (Triangles with an index out of range are dropped too
/// when anything is removed.)
pub fn remove_small_components(mesh: &mut Mesh, fraction: f32) -> Removal {
    let (comp, sizes) = triangle_components(mesh);
    let largest = sizes.iter().copied().max().unwrap_or(0);
    let keep: Vec<bool> = sizes.iter().map(|&s| (s as f64) >= fraction as f64 * largest as f64).collect();
    remove_components(mesh, &comp, &keep)
}

/// Drops the triangles of the components `c` (`comp`: each triangle's) with `keep[c]` false,
/// and the vertices only they used (the rest keep their order; normals and colours follow).
/// Triangles with an index out of range are dropped too when anything is removed.
fn remove_components(mesh: &mut Mesh, comp: &[u32], keep: &[bool]) -> Removal {
    let mut r = Removal { components: keep.len(), ..Default::default() };
    r.components_removed = keep.iter().filter(|&&k| !k).count();
    if r.components_removed == 0 {
        return r;
    }
    let n = mesh.positions.len();
    let keep_triangle: Vec<bool> = mesh
        .indices
        .chunks_exact(3)
        .zip(comp)
        .map(|(t, &c)| keep[c as usize] && t.iter().all(|&i| (i as usize) < n))
        .collect();
    r.triangles_removed = keep_triangle.iter().filter(|&&k| !k).count();
    super::trim::retain_triangles(mesh, &keep_triangle);
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An octahedron of radius `r` around `c`.
    fn octahedron(c: [f32; 3], r: f32, base: u32) -> (Vec<[f32; 3]>, Vec<u32>) {
        let p = vec![[r, 0.0, 0.0], [-r, 0.0, 0.0], [0.0, r, 0.0], [0.0, -r, 0.0], [0.0, 0.0, r], [0.0, 0.0, -r]]
            .into_iter()
            .map(|v| [0, 1, 2].map(|a| c[a] + v[a]))
            .collect();
        let f = [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]];
        (p, f.iter().flatten().map(|&i| i + base).collect())
    }

    #[test]
    fn pieces_without_points_go_and_supported_ones_stay() {
        let (mut positions, mut indices) = octahedron([0.0; 3], 1.0, 0);
        let (p2, i2) = octahedron([5.0, 0.0, 0.0], 0.2, 6);
        positions.extend(p2);
        indices.extend(i2);
        let mesh = Mesh { positions, normals: vec![], colors: None, indices };
        // 1000 points on the big piece, 3 near the small one: 0.3 % < 0.5 %.
        let mut points: Vec<[f32; 3]> = (0..1000).map(|i| [(i as f32 * 0.37).sin(), (i as f32 * 0.11).cos(), 0.0]).collect();
        points.extend([[5.0, 0.0, 0.2]; 3]);
        let mut m = mesh.clone();
        let r = remove_unsupported_components(&mut m, &points, 0.005, false);
        assert_eq!((r.components, r.components_removed, r.triangles_removed), (2, 1, 8));
        assert_eq!(m.positions.len(), 6);
        assert!(m.is_watertight());
        // 10 points (1 %) hold it.
        points.extend([[5.0, 0.2, 0.0]; 7]);
        let mut m = mesh.clone();
        assert_eq!(remove_unsupported_components(&mut m, &points, 0.005, false).components_removed, 0);
        // The best-supported piece stays even when it is below the share.
        let mut m = mesh.clone();
        let r = remove_unsupported_components(&mut m, &[[5.0, 0.0, 0.0]], 0.9, false);
        assert_eq!(r.components_removed, 1);
        assert!(m.positions.iter().all(|p| p[0] > 4.0));
    }

    #[test]
    fn a_one_sided_scan_keeps_the_pieces_no_point_is_near() {
        // Three pieces: the seen one (1000 points), one with a stray point's support (1 point,
        // under 0.5 %) and one with none at all (a part the scan never saw).
        let (mut positions, mut indices) = octahedron([0.0; 3], 1.0, 0);
        for (k, c) in [[5.0, 0.0, 0.0], [-5.0, 0.0, 0.0]].into_iter().enumerate() {
            let (p, i) = octahedron(c, 0.2, 6 * (k as u32 + 1));
            positions.extend(p);
            indices.extend(i);
        }
        let mesh = Mesh { positions, normals: vec![], colors: None, indices };
        let mut points: Vec<[f32; 3]> = (0..1000).map(|i| [(i as f32 * 0.37).sin(), (i as f32 * 0.11).cos(), 0.0]).collect();
        points.push([5.0, 0.0, 0.2]);
        let mut all_sides = mesh.clone();
        let r = remove_unsupported_components(&mut all_sides, &points, 0.005, false);
        assert_eq!((r.components_removed, r.unseen_kept), (2, 0));
        let mut one_side = mesh.clone();
        let r = remove_unsupported_components(&mut one_side, &points, 0.005, true);
        assert_eq!((r.components, r.components_removed, r.unseen_kept), (3, 1, 1));
        // The stray point's piece went, the unseen one stayed.
        assert!(one_side.positions.iter().all(|p| p[0] < 4.0));
        assert!(one_side.positions.iter().any(|p| p[0] < -4.0));
        let notice = r.unsupported_notice(0.005).unwrap();
        assert!(notice.contains("dropped 1 of 3 pieces") && notice.contains("kept 1 piece that no point is nearest to"), "{notice}");
    }
}
