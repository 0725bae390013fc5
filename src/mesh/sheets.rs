//! One layer where a scene's sheet was scanned from one side.
//!
//! Why: the object prior reads a sheet of points (a wall, the floor, a facade) as a thin solid,
//! so the field's zero level has two faces, one either side of the sheet, and the last fit lays
//! both on the scanned points. The mesh then holds every wall twice, in coincident layers facing
//! away from each other: twice the triangles, and a mesh tool (or a renderer that draws back
//! faces) sees both fight. Two faces that close are not a thin part of the world: a real board
//! scanned from both sides keeps its thickness through the fit, which lays each face on its own
//! points.
//!
//! What is done: a triangle is *paired* with its *twin* when a triangle facing the other way lies
//! within `gap` of it along its normal and within about an edge of it across. Of the two, the
//! one facing away from the scan goes: the lower cosine between its normal and the direction to
//! m, the points' centroid. A room is scanned from inside and a street from the street, where
//! the points' centroid lies; which side a lone sheet was seen from is not in the points, and
//! either layer is the same surface within the fit's noise. The decision is taken per layer
//! (triangles joined without bending, see [`single_layer`]'s body) when most of the layer has a
//! twin, by the area of its pairs, so the layer goes whole with the triangles that found none;
//! elsewhere pair by pair, and what has no twin (closed objects, thick parts) stays.

use glam::DVec3;

use super::trim::retain_triangles;
use super::types::Mesh;
use crate::sample::PointIndex;

/// What [`single_layer`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SheetReport {
    /// Triangles with a coincident twin facing the other way.
    pub paired: usize,
    /// Triangles dropped (the layers facing away from the scan).
    pub removed: usize,
}

impl SheetReport {
    pub fn notice(&self) -> Option<String> {
        (self.removed > 0).then(|| {
            format!(
                "{} triangles dropped: sheets scanned from one side came out as two coincident layers, and the layer facing away from the scan went",
                self.removed
            )
        })
    }
}

/// Centroids closer than this many of them are looked at for a twin.
const NEIGHBOURS: usize = 24;
/// A twin faces the other way: the cosine between the normals is below this.
const OPPOSITE: f64 = -0.7;
/// Two neighbouring triangles are in one layer when the cosine between their normals is above
/// this (25°).
const SAME_LAYER: f64 = 0.9;

/// Drops one of each pair of coincident, opposite layers of `mesh` (see the module's comment):
/// `gap` is the most two layers may lie apart along the normal to count as one sheet, in the
/// mesh's units; `points` the cloud the mesh was fitted to.
pub fn single_layer(mesh: &mut Mesh, points: &[[f32; 3]], gap: f32) -> SheetReport {
    let tris: Vec<[u32; 3]> = mesh.indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
    let nt = tris.len();
    if nt == 0 || points.is_empty() {
        return SheetReport::default();
    }
    let p = |i: u32| DVec3::from(mesh.positions[i as usize].map(|x| x as f64));
    let mut centroids = Vec::with_capacity(nt);
    let mut normals = Vec::with_capacity(nt);
    let mut areas = Vec::with_capacity(nt);
    let mut edge_sum = 0.0;
    for t in &tris {
        let [a, b, c] = t.map(p);
        let n = (b - a).cross(c - a);
        let len = n.length();
        edge_sum += (b - a).length();
        centroids.push(((a + b + c) / 3.0).as_vec3().to_array());
        normals.push(if len > 0.0 { n / len } else { DVec3::ZERO });
        areas.push(0.5 * len);
    }
    // Across, a twin's centroid is within about an edge: the two layers were meshed separately.
    let reach = (edge_sum / nt as f64).max(gap as f64);
    let index = PointIndex::new(&centroids);
    let at = |t: usize| DVec3::from(centroids[t].map(|x| x as f64));
    // Each triangle's twin, the triangles split over the cores.
    let mut twin = vec![u32::MAX; nt];
    crate::par::fill(&mut twin, |start, chunk| {
        let mut near = Vec::new();
        for (t, twin) in (start..).zip(chunk.iter_mut()) {
            let n = normals[t];
            if n == DVec3::ZERO {
                continue;
            }
            index.k_nearest(centroids[t], NEIGHBOURS, &mut near);
            let c = at(t);
            let mut best = f64::INFINITY;
            for &(_, u) in &near {
                if normals[u as usize].dot(n) > OPPOSITE {
                    continue;
                }
                let d = at(u as usize) - c;
                let along = d.dot(n);
                let across2 = (d.length_squared() - along * along).max(0.0);
                if along.abs() <= gap as f64 && across2 <= reach * reach && d.length_squared() < best {
                    best = d.length_squared();
                    *twin = u;
                }
            }
        }
    });
    let paired = twin.iter().filter(|&&u| u != u32::MAX).count();
    if paired == 0 {
        return SheetReport::default();
    }

    // Layers: triangles joined through shared vertices where the surface bends little. A rim,
    // which turns one layer into its twin within a cell or two, and a room's corners split them.
    let (offsets, around) = triangles_around_vertices(&tris, mesh.positions.len());
    let mut layer = vec![u32::MAX; nt];
    let mut layers = 0u32;
    let mut stack = Vec::new();
    for seed in 0..nt {
        if layer[seed] != u32::MAX {
            continue;
        }
        layer[seed] = layers;
        stack.push(seed as u32);
        while let Some(t) = stack.pop() {
            let t = t as usize;
            for &v in &tris[t] {
                for &u in &around[offsets[v as usize] as usize..offsets[v as usize + 1] as usize] {
                    if layer[u as usize] == u32::MAX && normals[u as usize].dot(normals[t]) > SAME_LAYER {
                        layer[u as usize] = layers;
                        stack.push(u);
                    }
                }
            }
        }
        layers += 1;
    }
    drop((offsets, around));

    // Of a pair, the triangle facing the points' centroid less is the one to go; a layer goes
    // whole when most of its area so votes, so that a curved shell (an object scanned from one
    // side) keeps one layer throughout, not the half facing the centroid from each.
    let m = centroid(points);
    let towards = |t: usize| {
        let d = m - at(t);
        let len = d.length();
        if len > 0.0 {
            d.dot(normals[t]) / len
        } else {
            0.0
        }
    };
    let drops = |t: usize| towards(t) < towards(twin[t] as usize);
    // Per layer: the vote (area dropping minus area keeping), and pairs within it and across.
    let mut vote = vec![0.0f64; layers as usize];
    let (mut paired_area, mut area) = (vec![0.0f64; layers as usize], vec![0.0f64; layers as usize]);
    for t in 0..nt {
        area[layer[t] as usize] += areas[t];
    }
    let mut within = vec![0u32; layers as usize];
    let mut across = vec![0u32; layers as usize];
    for t in 0..nt {
        if twin[t] == u32::MAX {
            continue;
        }
        let l = layer[t] as usize;
        vote[l] += if drops(t) { areas[t] } else { -areas[t] };
        paired_area[l] += areas[t];
        if layer[twin[t] as usize] as usize == l {
            within[l] += 1;
        } else {
            across[l] += 1;
        }
    }
    // A layer goes whole only when it is mostly a sheet's: most of its area has a twin in
    // another layer. Otherwise only its pairs are decided, one by one, and its triangles without
    // a twin stay: a closed object touches a sheet only in part (a blob's underside on the
    // floor), and two layers joined somewhere in gentle steps have their twins within.
    let fate: Vec<u8> = (0..nt)
        .map(|t| {
            let l = layer[t] as usize;
            let sheet = across[l] > within[l] && paired_area[l] >= 0.5 * area[l];
            let goes = if sheet { vote[l] > 0.0 } else { twin[t] != u32::MAX && drops(t) };
            if goes {
                2
            } else {
                1
            }
        })
        .collect();
    let keep: Vec<bool> = fate.iter().map(|&f| f != 2).collect();
    let removed = keep.iter().filter(|&&k| !k).count();
    if removed > 0 {
        retain_triangles(mesh, &keep);
        if !mesh.normals.is_empty() {
            mesh.compute_vertex_normals();
        }
    }
    SheetReport { paired, removed }
}

/// For each vertex, the triangles that use it: `around[offsets[v]..offsets[v + 1]]`.
fn triangles_around_vertices(tris: &[[u32; 3]], vertices: usize) -> (Vec<u32>, Vec<u32>) {
    let mut offsets = vec![0u32; vertices + 1];
    for t in tris {
        for &v in t {
            offsets[v as usize + 1] += 1;
        }
    }
    for i in 0..vertices {
        offsets[i + 1] += offsets[i];
    }
    let mut fill = offsets.clone();
    let mut around = vec![0u32; 3 * tris.len()];
    for (i, t) in tris.iter().enumerate() {
        for &v in t {
            around[fill[v as usize] as usize] = i as u32;
            fill[v as usize] += 1;
        }
    }
    (offsets, around)
}

fn centroid(points: &[[f32; 3]]) -> DVec3 {
    points.iter().map(|p| DVec3::from(p.map(|x| x as f64))).sum::<DVec3>() / points.len() as f64
}
