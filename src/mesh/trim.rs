//! Opening the closed surface where there are no input points ("trim"): the level set of an
//! occupancy field is always closed, so a scan of one side of an object comes back with a
//! bubble over the unscanned side. Trimming drops the triangles far from every input point.

use super::types::Mesh;
use crate::sample::{mean_spacing, PointIndex};

/// Default trim factor (multiples of the cloud's mean nearest-neighbour spacing), used by the
/// CLI's `--trim` without a number.
pub const DEFAULT_TRIM: f32 = 3.0;

/// What [`trim`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrimReport {
    /// The points' mean nearest-neighbour spacing (see [`mean_spacing`]).
    pub spacing: f32,
    /// `factor × spacing`: triangles whose centroid is farther than this from every point went.
    pub threshold: f32,
    pub triangles_removed: usize,
    pub vertices_removed: usize,
}

impl TrimReport {
    /// What the reconstruction tells the user after a trim by `factor`.
    pub fn notice(&self, factor: f32) -> String {
        format!("trimmed {} triangles farther than {factor} x the mean point spacing from the input", self.triangles_removed)
    }
}

/// Drops every triangle whose centroid is farther than `factor` × the mean nearest-neighbour
/// spacing of `points` from the nearest of them, then the vertices no triangle uses any more
/// (the rest keep their order; normals and colours follow). `mesh` and `points` must be in the
/// same coordinates. A `factor` that is not positive and finite, or fewer than two distinct
/// points, removes nothing.
pub fn trim(mesh: &mut Mesh, points: &[[f32; 3]], factor: f32) -> TrimReport {
    let near = near_triangles(&mesh.positions, &mesh.indices, points, factor);
    let mut report = TrimReport { spacing: near.spacing, threshold: near.threshold, ..Default::default() };
    if let Some(keep) = near.keep {
        report.triangles_removed = keep.iter().filter(|&&k| !k).count();
        report.vertices_removed = retain_triangles(mesh, &keep);
    }
    report
}

/// Which triangles [`trim`] keeps, without changing the mesh (the page's live trim uses it too).
pub struct NearTriangles {
    pub spacing: f32,
    pub threshold: f32,
    /// Per triangle: its centroid is within `threshold` of a point (and its indices are in
    /// range). None when the threshold is not positive and finite: nothing is to be removed.
    pub keep: Option<Vec<bool>>,
}

/// The triangles (`indices` into `positions`) whose centroid lies within `factor` × the mean
/// nearest-neighbour spacing of `points` from the nearest of them.
pub fn near_triangles(positions: &[[f32; 3]], indices: &[u32], points: &[[f32; 3]], factor: f32) -> NearTriangles {
    let spacing = mean_spacing(points);
    let threshold = factor * spacing;
    if !(threshold > 0.0 && threshold.is_finite()) {
        return NearTriangles { spacing, threshold, keep: None };
    }
    let index = PointIndex::new(points);
    let n = positions.len();
    let mut scratch = Vec::new();
    let keep = indices
        .chunks_exact(3)
        .map(|t| {
            if t.iter().any(|&i| i as usize >= n) {
                return false;
            }
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| positions[i as usize]);
            let centroid = [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0);
            index.nearest_distance(centroid, &mut scratch) <= threshold
        })
        .collect();
    NearTriangles { spacing, threshold, keep: Some(keep) }
}

/// Keeps the triangles `t` with `keep[t]` (and drops any whose index is out of range), then
/// removes the vertices that no kept triangle uses and re-indexes; normals (when one per vertex)
/// and colours follow their vertices. Returns the number of vertices removed.
pub fn retain_triangles(mesh: &mut Mesh, keep: &[bool]) -> usize {
    let n = mesh.positions.len();
    let mut used = vec![false; n];
    let mut indices = Vec::with_capacity(mesh.indices.len());
    for (t, &k) in mesh.indices.chunks_exact(3).zip(keep) {
        if k && t.iter().all(|&i| (i as usize) < n) {
            indices.extend_from_slice(t);
            for &i in t {
                used[i as usize] = true;
            }
        }
    }
    let mut remap = vec![u32::MAX; n];
    let mut next = 0u32;
    for (i, &u) in used.iter().enumerate() {
        if u {
            remap[i] = next;
            next += 1;
        }
    }
    fn pick<T: Copy>(v: &[T], used: &[bool]) -> Vec<T> {
        v.iter().zip(used).filter(|(_, &u)| u).map(|(x, _)| *x).collect()
    }
    mesh.positions = pick(&mesh.positions, &used);
    if mesh.normals.len() == n {
        mesh.normals = pick(&mesh.normals, &used);
    }
    if let Some(c) = mesh.colors.as_mut() {
        if c.len() == n {
            *c = pick(c, &used);
        }
    }
    mesh.indices = indices.iter().map(|&i| remap[i as usize]).collect();
    n - next as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat grid of points on z = 0 over [0,1]² and a mesh of two squares: one on the grid,
    /// one lifted far above it.
    #[test]
    fn trims_faces_far_from_the_points_and_drops_their_vertices() {
        let points: Vec<[f32; 3]> =
            (0..=10).flat_map(|i| (0..=10).map(move |j| [i as f32 * 0.1, j as f32 * 0.1, 0.0])).collect();
        let square = |z: f32| [[0.2, 0.2, z], [0.8, 0.2, z], [0.8, 0.8, z], [0.2, 0.8, z]];
        let mut positions = square(0.01).to_vec();
        positions.extend_from_slice(&square(1.0));
        let mut mesh = Mesh {
            normals: vec![[0.0, 0.0, 1.0]; 8],
            colors: Some((0..8).map(|i| [i as u8; 4]).collect()),
            indices: vec![4, 5, 6, 0, 1, 2, 0, 2, 3, 4, 6, 7],
            positions,
        };
        let r = trim(&mut mesh, &points, 3.0);
        assert!((r.spacing - 0.1).abs() < 1e-6, "{r:?}");
        assert_eq!((r.triangles_removed, r.vertices_removed), (2, 4));
        assert_eq!(mesh.indices, vec![0, 1, 2, 0, 2, 3]);
        assert_eq!(mesh.positions, square(0.01).to_vec());
        assert_eq!(mesh.colors.as_ref().unwrap()[3], [3; 4]);
        assert_eq!(mesh.normals.len(), 4);
        // No threshold, nothing removed.
        let before = mesh.clone();
        assert_eq!(trim(&mut mesh, &points, 0.0).triangles_removed, 0);
        assert_eq!(trim(&mut mesh, &points[..1], 3.0).triangles_removed, 0);
        assert_eq!(mesh, before);
    }
}
