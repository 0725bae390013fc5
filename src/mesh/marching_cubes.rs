//! Marching cubes over a sparse list of active cells: the CPU reference. The GPU version
//! (`shaders/marching_cubes.wgsl`, [`super::marching_cubes_gpu`]) computes exactly the same
//! triangle soup, in the same order, and shares [`weld`].
//!
//! Each cell emits its case's triangles (see [`super::tables`]) as a soup of
//! `(key, position)` vertices. The key of an edge crossing is its global edge id
//! `3 * (x + (R+1) (y + (R+1) z)) + axis` (the edge's low corner and axis), so the cells
//! around an edge give its crossing the same key; the position is computed from the edge's own
//! two corner values, low to high, so it is the same for all of them too. Welding by key then
//! joins the cells into one indexed mesh.

use super::refine::{ActiveCells, KeyMap};
use super::tables::{edge_axis, edge_corners, CaseTable};
use super::types::Mesh;

/// Marching cubes case index of 8 corner values: bit `c` set when corner `c` is inside (`> 0`).
pub fn case_index(v: &[f32; 8]) -> usize {
    v.iter().enumerate().fold(0, |acc, (c, &x)| acc | (((x > 0.0) as usize) << c))
}

/// Where edge `e` of a cell with corner values `v` is crossed: `(key, position)`.
fn crossing(cell: [u32; 3], v: &[f32; 8], e: usize, resolution: u32, domain: &([f32; 3], [f32; 3])) -> (u64, [f32; 3]) {
    let (lo_c, hi_c) = edge_corners(e);
    let a = edge_axis(e);
    let (v0, v1) = (v[lo_c], v[hi_c]);
    // One is > 0 and the other <= 0, so the denominator is not 0; both are finite.
    let t = v0 / (v0 - v1);
    let g = [cell[0] + (lo_c as u32 & 1), cell[1] + (lo_c as u32 >> 1 & 1), cell[2] + (lo_c as u32 >> 2 & 1)];
    let r = resolution as f32;
    let (lo, hi) = domain;
    let mut p: [f32; 3] = std::array::from_fn(|b| lo[b] + (hi[b] - lo[b]) * (g[b] as f32 / r));
    p[a] = lo[a] + (hi[a] - lo[a]) * ((g[a] as f32 + t) / r);
    let n = resolution as u64 + 1;
    let key = 3 * (g[0] as u64 + n * (g[1] as u64 + n * g[2] as u64)) + a as u64;
    (key, p)
}

/// The triangle soup of one cell, appended to `keys` / `positions` (three entries per
/// triangle).
pub fn emit_cell(
    cell: [u32; 3],
    v: &[f32; 8],
    resolution: u32,
    domain: &([f32; 3], [f32; 3]),
    keys: &mut Vec<u64>,
    positions: &mut Vec<[f32; 3]>,
) {
    let case = &CaseTable::get().cases[case_index(v)];
    if case.triangles.is_empty() {
        return;
    }
    let mut local = [(0u64, [0.0f32; 3]); 12];
    for (e, slot) in local.iter_mut().enumerate() {
        let (a, b) = edge_corners(e);
        if (v[a] > 0.0) != (v[b] > 0.0) {
            *slot = crossing(cell, v, e, resolution, domain);
        }
    }
    for tri in &case.triangles {
        for &lv in tri {
            let (k, p) = local[lv as usize];
            keys.push(k);
            positions.push(p);
        }
    }
}

/// Joins a triangle soup into an indexed mesh: vertices in order of first use, each taking the
/// position of its first occurrence. No normals.
pub fn weld(keys: &[u64], positions: &[[f32; 3]]) -> Mesh {
    assert_eq!(keys.len(), positions.len());
    let mut index: KeyMap<u32> = KeyMap::default();
    index.reserve(keys.len() / 4);
    let mut mesh = Mesh::default();
    mesh.indices.reserve(keys.len());
    for (&k, p) in keys.iter().zip(positions) {
        let next = mesh.positions.len() as u32;
        let i = *index.entry(k).or_insert(next);
        if i == next {
            mesh.positions.push(*p);
        }
        mesh.indices.push(i);
    }
    mesh
}

/// The triangle soup of all active cells, in cell order.
pub fn soup(cells: &ActiveCells) -> (Vec<u64>, Vec<[f32; 3]>) {
    let mut keys = Vec::new();
    let mut positions = Vec::new();
    for (c, v) in cells.cells.iter().zip(&cells.values) {
        emit_cell(*c, v, cells.resolution, &cells.domain, &mut keys, &mut positions);
    }
    (keys, positions)
}

/// Marching cubes on the CPU: the welded mesh of the active cells (no normals), in the domain's
/// coordinates, triangles counter-clockwise seen from outside (where the field is `<= 0`).
pub fn polygonize(cells: &ActiveCells) -> Mesh {
    let (keys, positions) = soup(cells);
    weld(&keys, &positions)
}
