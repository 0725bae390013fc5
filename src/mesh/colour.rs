//! Vertex colours from a coloured cloud: each vertex takes the inverse-distance-weighted mean
//! colour of its nearest input points.

use super::types::Mesh;
use crate::cloud::PointCloud;
use crate::sample::PointIndex;

/// Neighbours averaged per vertex: enough to smooth the colour noise of a scan, few enough to
/// keep edges between colour regions within about one point spacing.
pub const DEFAULT_K: usize = 8;

/// Sets `mesh.colors` to one RGBA per vertex: the mean of the colours of the `k` input points
/// nearest to the vertex, weighted by 1/d² (Shepard's weights; a point at the vertex's exact
/// position gives its colour alone), rounded to 0..=255. Alpha is averaged like the rest.
/// `mesh` must be in the cloud's coordinates (as [`crate::pipeline::Engine::reconstruct`]
/// returns it). Returns false, leaving the mesh alone, when the cloud has no colours (or not
/// one per point) or no points.
pub fn transfer(mesh: &mut Mesh, cloud: &PointCloud, k: usize) -> bool {
    let Some(colors) = cloud.colors.as_ref() else { return false };
    if colors.len() != cloud.positions.len() || cloud.positions.is_empty() {
        return false;
    }
    let index = PointIndex::new(&cloud.positions);
    // The vertices split over the cores (a scene's mesh has millions).
    let out = crate::par::map_ranges(mesh.positions.len(), |range| {
        let mut near = Vec::with_capacity(k.max(1));
        mesh.positions[range]
            .iter()
            .map(|&p| {
                index.k_nearest(p, k.max(1), &mut near);
                let mut acc = [0.0f64; 4];
                let mut total = 0.0f64;
                for &(d2, j) in &near {
                    let c = colors[j as usize];
                    if d2 == 0.0 {
                        return c;
                    }
                    let w = 1.0 / d2 as f64;
                    for (a, &x) in acc.iter_mut().zip(&c) {
                        *a += w * x as f64;
                    }
                    total += w;
                }
                if !(total > 0.0 && total.is_finite()) {
                    // Only when distances underflow or the vertex is not finite: the nearest colour.
                    return near.first().map_or([255; 4], |&(_, j)| colors[j as usize]);
                }
                acc.map(|a| (a / total).round().clamp(0.0, 255.0) as u8)
            })
            .collect()
    });
    mesh.colors = Some(out);
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colours_are_idw_means_of_the_nearest_points() {
        let cloud = PointCloud {
            positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [5.0, 0.0, 0.0]],
            colors: Some(vec![[0, 0, 0, 255], [200, 100, 50, 255], [9, 9, 9, 9]]),
            ..Default::default()
        };
        let mut mesh = Mesh { positions: vec![[0.25, 0.0, 0.0], [1.0, 0.0, 0.0], [9.0, 0.0, 0.0]], ..Default::default() };
        assert!(transfer(&mut mesh, &cloud, 2));
        let c = mesh.colors.unwrap();
        // Weights 1/0.0625 = 16 and 1/0.5625 = 16/9: the second point has weight 1/10.
        assert_eq!(c[0], [20, 10, 5, 255]);
        assert_eq!(c[1], [200, 100, 50, 255], "exact hit");
        // Nearest two to x = 9: x = 5 (d² 16) and x = 1 (d² 64): (4·9 + 1·c1) / 5.
        assert_eq!(c[2], [47, 27, 17, 58]);
        let mut plain = Mesh { positions: vec![[0.0; 3]], ..Default::default() };
        assert!(!transfer(&mut plain, &PointCloud { positions: vec![[0.0; 3]], ..Default::default() }, 8));
        assert_eq!(plain.colors, None);
    }
}
