//! Scenes: clouds larger than one object (rooms, facades, streets from LAS/LAZ/E57 scanners),
//! reconstructed tile by tile. The prior was trained on one object filling the unit cube; a
//! room squeezed into that cube comes back as a blob. So the cloud is cut into cubes of about an
//! object's worth of points at the scan's density ([`plan`]), each tile (with an overlap on
//! every side) goes through the network in its own unit cube, and the fields are blended on one
//! global grid with weights that sum to one across overlaps (a product of linear ramps per axis),
//! so the mesh extracted from the blend is one surface, without seams or doubled walls at tile
//! borders.
//!
//! Only grid nodes near the points (a band of [`BAND`] cells around each point's cell) are
//! evaluated: the surface is extracted where there are points, so an open scene (a room seen
//! from inside, a facade, terrain) is not closed over what was never scanned, and nothing is
//! invented at the scene's edge.
//!
//! Memory: the points once, each tile's points and field (one tile at a time), and the blended
//! values of the band's nodes, which grow with the scanned surface, not with the volume.

use std::collections::HashMap;

use crate::cloud::{subsample, PointCloud};
use crate::field::{Field, EVALUATION_CHUNK};
use crate::gpu::now;
use crate::mesh::{ActiveCells, ExtractError, ExtractStats, FieldError};
use crate::pipeline::{Engine, PipelineError, Reconstruction, Stage};
use crate::settings::{Method, Settings, Tiles};
use crate::units::Units;

/// A cloud whose longest side reaches this many metres is a scene: `tiles auto` cuts it. Objects
/// up to a car or a statue (a 4 m closed ellipsoid in the browser tests) keep the one-cube path;
/// a smaller room needs `--tiles on`.
pub const SCENE_EXTENT_M: f64 = 5.0;
/// About this many points in a tile's core, at the scan's density.
pub const TILE_POINTS: usize = 10_000;
/// Mesh cells along a tile's core: the grid's cell is the tile's size over this.
pub const TILE_CELLS: usize = 64;
/// The overlap on each side of a tile's core, as a share of its size.
pub const OVERLAP: f64 = 0.25;
/// Cells around each point's cell whose corners are evaluated.
pub const BAND: i64 = 2;
/// Fewer points than this in a tile's cube: nothing to reconstruct there.
const MIN_TILE_POINTS: usize = 30;

/// How a scene is cut.
#[derive(Clone, Debug, PartialEq)]
pub struct TilePlan {
    /// Edge of a tile's core, in the cloud's units.
    pub size: f64,
    /// Edge of a grid cell: `size / TILE_CELLS`.
    pub cell: f64,
    /// The grid's origin (the cloud's lowest corner), in the cloud's coordinates.
    pub origin: [f64; 3],
    /// Cells along each axis of the cubic grid.
    pub resolution: u32,
    /// The tiles holding points, in order (x fastest), and their core's point count.
    pub tiles: Vec<([i64; 3], usize)>,
    /// Why the cloud is tiled, and how, in a sentence.
    pub reason: String,
}

/// Whether `cloud` is reconstructed in tiles under `settings`: `on`, `off`, or (`auto`) when
/// its longest side in metres reaches [`SCENE_EXTENT_M`]; `units` is the cloud's length unit
/// as its file states or suggests it ([`crate::io::scan_file::ScanFile::units_guess`]), which
/// `--units` overrides; with neither, auto takes the numbers as metres. Returns the plan when
/// it tiles.
pub fn decide(cloud: &PointCloud, settings: &Settings, units: Option<Units>) -> Option<TilePlan> {
    let to_m = settings.units.or(units).map_or(1.0, |u| u.metres());
    let b = cloud.bounds()?;
    let extent = (0..3).map(|a| (b.max[a] - b.min[a]) as f64).fold(0.0, f64::max);
    let why = match settings.tiles {
        Tiles::Off => return None,
        Tiles::On => "tiles were asked for (--tiles on)".to_string(),
        Tiles::Auto if extent * to_m >= SCENE_EXTENT_M => {
            format!("it spans {:.1} m, more than one object ({SCENE_EXTENT_M} m or more is a scene; --tiles off for one object)", extent * to_m)
        }
        Tiles::Auto => return None,
    };
    let detail = settings.detail.map(|m| m as f64 / to_m);
    let mut plan = plan(&cloud.positions, detail);
    plan.reason = format!(
        "reconstruct the cloud as a scene in {} tiles of {:.2} m (cells of {:.1} cm): {why}",
        plan.tiles.len(),
        plan.size * to_m,
        100.0 * plan.cell * to_m
    );
    Some(plan)
}

/// Tiles for `points`: of `detail · TILE_CELLS` when a detail (cell size) is given, else the
/// size at which the tiles holding points hold about [`TILE_POINTS`] each.
pub fn plan(points: &[[f32; 3]], detail: Option<f64>) -> TilePlan {
    let (lo, hi) = bounds(points);
    let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max).max(1e-9);
    let size = match detail {
        Some(d) if d > 0.0 => d * TILE_CELLS as f64,
        _ => {
            // From one tile down by factors of 1.25, the first size whose occupied tiles hold
            // TILE_POINTS or fewer on average.
            let mut s = extent * 1.0001;
            while s > extent / 256.0 {
                let counts = count_tiles(points, lo, s);
                if points.len() / counts.len().max(1) <= TILE_POINTS {
                    break;
                }
                s /= 1.25;
            }
            s
        }
    };
    let cell = size / TILE_CELLS as f64;
    // The grid starts a band (and a cell) before the lowest point, so that the band around the
    // outermost points is inside it too.
    let margin = (BAND + 1) as f64 * cell;
    let origin = lo.map(|c| c - margin);
    let resolution = (((extent + 2.0 * margin) / cell).ceil() as u32).max(1) + 1;
    let mut tiles: Vec<([i64; 3], usize)> = count_tiles(points, origin, size).into_iter().collect();
    tiles.sort_by_key(|(t, _)| (t[2], t[1], t[0]));
    TilePlan { size, cell, origin, resolution, tiles, reason: String::new() }
}

fn bounds(points: &[[f32; 3]]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a] as f64);
            hi[a] = hi[a].max(p[a] as f64);
        }
    }
    (lo, hi)
}

fn tile_of(p: &[f32; 3], lo: [f64; 3], size: f64) -> [i64; 3] {
    [0, 1, 2].map(|a| ((p[a] as f64 - lo[a]) / size).floor() as i64)
}

fn count_tiles(points: &[[f32; 3]], lo: [f64; 3], size: f64) -> HashMap<[i64; 3], usize> {
    let mut counts = HashMap::new();
    for p in points {
        *counts.entry(tile_of(p, lo, size)).or_insert(0) += 1;
    }
    counts
}

impl TilePlan {
    /// A tile's weight at `x` (the grid's coordinates, relative to the origin): 1 in its core
    /// away from the borders, falling linearly to 0 across the overlap, so that the weights
    /// of neighbouring tiles sum to one everywhere.
    pub fn weight(&self, tile: [i64; 3], x: [f64; 3]) -> f64 {
        let o = OVERLAP * self.size;
        (0..3)
            .map(|a| {
                let (c0, c1) = (tile[a] as f64 * self.size, (tile[a] + 1) as f64 * self.size);
                ((x[a] - (c0 - o)) / (2.0 * o)).clamp(0.0, 1.0) * (((c1 + o) - x[a]) / (2.0 * o)).clamp(0.0, 1.0)
            })
            .product()
    }

    fn node_key(&self, n: [i64; 3]) -> u64 {
        let r1 = self.resolution as u64 + 1;
        n[0] as u64 + r1 * (n[1] as u64 + r1 * n[2] as u64)
    }

    fn node_of_key(&self, k: u64) -> [i64; 3] {
        let r1 = self.resolution as u64 + 1;
        [(k % r1) as i64, (k / r1 % r1) as i64, (k / (r1 * r1)) as i64]
    }

    /// The band's nodes near `points` that `tile` weighs (its cube with the overlap), as keys.
    fn band_nodes(&self, tile: [i64; 3], points: &[[f32; 3]]) -> Vec<u64> {
        let r = self.resolution as i64;
        let per = TILE_CELLS as i64;
        let o = (OVERLAP * TILE_CELLS as f64).round() as i64;
        // Nodes strictly inside the overlap's outer border (weight above 0).
        let lo = tile.map(|t| t * per - o + 1);
        let hi = tile.map(|t| (t + 1) * per + o - 1);
        let mut keys = Vec::new();
        for p in points {
            let c = [0, 1, 2].map(|a| (((p[a] as f64 - self.origin[a]) / self.cell).floor() as i64).clamp(0, r - 1));
            for dz in -BAND..=BAND + 1 {
                for dy in -BAND..=BAND + 1 {
                    for dx in -BAND..=BAND + 1 {
                        let n = [c[0] + dx, c[1] + dy, c[2] + dz];
                        if (0..3).all(|a| n[a] >= lo[a].max(0) && n[a] <= hi[a].min(r)) {
                            keys.push(self.node_key(n));
                        }
                    }
                }
            }
        }
        keys.sort_unstable();
        keys.dedup();
        keys
    }
}

/// Reconstructs `cloud` (whose length unit is `units`, see [`decide`]) the way [`decide`] picks: in tiles when it is a scene, else whole
/// ([`Engine::reconstruct`]). The CLI, the page and the JS API all come through here.
pub async fn reconstruct_auto(
    engine: &Engine,
    cloud: &PointCloud,
    settings: &Settings,
    units: Option<Units>,
    progress: &mut dyn FnMut(&Stage) -> bool,
) -> Result<Reconstruction, PipelineError> {
    match decide(cloud, settings, units) {
        Some(tiles) => reconstruct(engine, cloud, settings, &tiles, progress).await,
        None => engine.reconstruct(cloud, settings, progress).await,
    }
}

/// Reconstructs `cloud` as a scene cut by `tiles`: the network per tile, the fields blended,
/// one mesh. `progress` sees [`Stage::Tile`] before each tile and can cancel there.
pub async fn reconstruct(
    engine: &Engine,
    cloud: &PointCloud,
    settings: &Settings,
    tiles: &TilePlan,
    progress: &mut dyn FnMut(&Stage) -> bool,
) -> Result<Reconstruction, PipelineError> {
    let mut notices = vec![format!("nkrr will {}", tiles.reason)];
    if settings.resolution != Settings::default().resolution {
        notices.push(format!("--resolution {} is for one object: a scene's mesh cell follows its tiles ({:.3} of the cloud's units; --detail sets it)", settings.resolution, tiles.cell));
    }
    if settings.method == Method::Nkrr {
        notices.push("the tiles use the network's field: the kernel regression per tile is not built yet (--method network says so)".into());
    }
    let t_all = now();
    // Each point goes to every tile whose cube (with its overlap) holds it.
    let o = OVERLAP * tiles.size;
    let index: HashMap<[i64; 3], usize> = tiles.tiles.iter().enumerate().map(|(i, (t, _))| (*t, i)).collect();
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); tiles.tiles.len()];
    for (i, p) in cloud.positions.iter().enumerate() {
        let lo = [0, 1, 2].map(|a| ((p[a] as f64 - tiles.origin[a] - o) / tiles.size).floor() as i64);
        let hi = [0, 1, 2].map(|a| ((p[a] as f64 - tiles.origin[a] + o) / tiles.size).floor() as i64);
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    if let Some(&t) = index.get(&[x, y, z]) {
                        members[t].push(i as u32);
                    }
                }
            }
        }
    }

    // Σ w·f and Σ w per band node.
    let mut blend: HashMap<u64, (f32, f32)> = HashMap::new();
    let mut evaluations = 0u64;
    // The tiles evaluate the network's field (the regression per tile is not built yet).
    let network = Field::Network;
    let mut evaluator: Option<crate::field::Evaluator> = None;
    let of = tiles.tiles.len();
    for (done, ((tile, _), ids)) in tiles.tiles.iter().zip(&mut members).enumerate() {
        if !progress(&Stage::Tile { done, of }) {
            return Err(PipelineError::Cancelled);
        }
        let ids = std::mem::take(ids);
        if ids.len() < MIN_TILE_POINTS {
            continue;
        }
        let points: Vec<[f32; 3]> = ids.iter().map(|&i| cloud.positions[i as usize]).collect();
        let seen = subsample(&points, settings.max_points, 1);
        // The tile's cube with its overlap fills the network's unit cube.
        let centre = [0, 1, 2].map(|a| tiles.origin[a] + (tile[a] as f64 + 0.5) * tiles.size);
        let scale = tiles.size + 2.0 * o;
        let local = |p: [f64; 3]| [0, 1, 2].map(|a| ((p[a] - centre[a]) / scale) as f32);
        let normalised: Vec<[f32; 3]> = seen.iter().map(|p| local(p.map(|v| v as f64))).collect();
        let planes = engine.net.encode(&normalised).await?;
        let nodes = tiles.band_nodes(*tile, &points);
        let queries: Vec<[f32; 3]> = nodes
            .iter()
            .map(|&k| {
                let n = tiles.node_of_key(k);
                local([0, 1, 2].map(|a| tiles.origin[a] + n[a] as f64 * tiles.cell))
            })
            .collect();
        let field_error = |e| PipelineError::Mesh(ExtractError::Field(FieldError(e)));
        // One evaluator for every tile: its buffers made at the first, rebound to each tile's planes.
        let evaluator = match &mut evaluator {
            Some(ev) => {
                ev.rebind(&planes).map_err(field_error)?;
                ev
            }
            None => evaluator.insert(network.evaluator(&engine.net, &planes, EVALUATION_CHUNK).map_err(field_error)?),
        };
        let mut values = Vec::with_capacity(queries.len());
        for chunk in queries.chunks(EVALUATION_CHUNK) {
            values.extend(evaluator.evaluate(chunk).await.map_err(field_error)?);
        }
        evaluations += values.len() as u64;
        for (&k, &v) in nodes.iter().zip(&values) {
            let n = tiles.node_of_key(k);
            let w = tiles.weight(*tile, n.map(|c| c as f64 * tiles.cell)) as f32;
            if w > 0.0 && v.is_finite() {
                let e = blend.entry(k).or_insert((0.0, 0.0));
                e.0 += w * v;
                e.1 += w;
            }
        }
    }
    progress(&Stage::Tile { done: of, of });
    let mut timings = vec![("tiles", now() - t_all)];

    // Marching cubes over the cells whose eight corners were all evaluated.
    let t = now();
    let cells = active_cells(tiles, &blend);
    drop(blend);
    let active = cells.cells.len();
    let mut mesh = crate::mesh::polygonize(&cells);
    drop(cells);
    let triangles_extracted = mesh.triangle_count();
    let opts = crate::mesh::ExtractOptions { remove_small_components: settings.remove_small_components, ..Default::default() };
    let removal;
    (mesh, removal) = crate::mesh::postprocess(mesh, &opts);
    timings.push(("mesh", now() - t));
    if mesh.indices.is_empty() {
        return Err(PipelineError::NoSurface { evaluations, field_max: 0.0, method: Method::Network });
    }
    // The same finish as one object's (the last fit, the trim, the simplification), against
    // all the scene's points: its steps measure in point spacings, whatever the units.
    // A piece's support is measured against a tile's worth of points, not the scene's: a chair
    // is a small share of a street, and must stay.
    let share = |s: f64| s * (TILE_POINTS as f64 / cloud.len().max(1) as f64).min(1.0);
    let finish = Settings { min_support: settings.min_support.map(share), ..settings.clone() };
    let finished = crate::mesh::finish::finish(&mut mesh, &cloud.positions, &finish, &mut notices, &mut timings);
    if settings.colors && cloud.colors.is_some() {
        crate::mesh::colour::transfer(&mut mesh, cloud, crate::mesh::colour::DEFAULT_K);
    }
    let origin = crate::units::to_metres(settings.units, &mut mesh.positions, cloud.origin);
    progress(&Stage::Done);
    let refine = crate::mesh::RefineStats { evaluations, active_cells: active, ..Default::default() };
    Ok(Reconstruction {
        mesh,
        origin,
        fit: finished.fit,
        trim: finished.trim,
        simplify: finished.simplify,
        notices,
        warnings: Vec::new(),
        extract: ExtractStats { refine, triangles_extracted, removal, gpu: false },
        tuning: None,
        timings,
        gpu_peaks: Vec::new(),
    })
}

/// The cells of the grid with all eight corners blended and a sign change among them.
fn active_cells(tiles: &TilePlan, blend: &HashMap<u64, (f32, f32)>) -> ActiveCells {
    let r = tiles.resolution;
    let value = |n: [i64; 3]| -> Option<f32> {
        if n.iter().any(|&c| c > r as i64) {
            return None;
        }
        blend.get(&tiles.node_key(n)).map(|(wf, w)| wf / w)
    };
    let mut found: Vec<([u32; 3], [f32; 8])> = Vec::new();
    for &k in blend.keys() {
        let n = tiles.node_of_key(k);
        if n.iter().any(|&c| c >= r as i64) {
            continue;
        }
        let mut v = [0.0f32; 8];
        let mut ok = true;
        for (c, vc) in v.iter_mut().enumerate() {
            match value([n[0] + (c & 1) as i64, n[1] + (c >> 1 & 1) as i64, n[2] + (c >> 2 & 1) as i64]) {
                Some(x) => *vc = x,
                None => {
                    ok = false;
                    break;
                }
            }
        }
        let inside = v.iter().filter(|&&x| x > 0.0).count();
        if ok && inside > 0 && inside < 8 {
            found.push((n.map(|c| c as u32), v));
        }
    }
    found.sort_by_key(|(c, _)| (c[2], c[1], c[0]));
    let side = r as f64 * tiles.cell;
    let lo = tiles.origin.map(|c| c as f32);
    let hi = tiles.origin.map(|c| (c + side) as f32);
    ActiveCells { resolution: r, domain: (lo, hi), cells: found.iter().map(|(c, _)| *c).collect(), values: found.into_iter().map(|(_, v)| v).collect() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_weights_of_neighbouring_tiles_sum_to_one() {
        let plan = TilePlan { size: 1.0, cell: 1.0 / 64.0, origin: [0.0; 3], resolution: 256, tiles: Vec::new(), reason: String::new() };
        let mut rng = crate::rng::SplitMix64(3);
        for _ in 0..1000 {
            let x = [rng.unit() * 3.0 + 0.5, rng.unit() * 3.0 + 0.5, rng.unit() * 3.0 + 0.5];
            let mut sum = 0.0;
            for z in -1..5 {
                for y in -1..5 {
                    for t in -1..5 {
                        sum += plan.weight([t, y, z], x);
                    }
                }
            }
            assert!((sum - 1.0).abs() < 1e-9, "{x:?}: {sum}");
        }
    }

    #[test]
    fn tiles_follow_the_density() {
        // A 4 x 4 m floor of 160,000 points: 10,000 a square metre, so a tile of about a metre.
        let mut pts = Vec::new();
        for i in 0..400 {
            for j in 0..400 {
                pts.push([i as f32 * 0.01, j as f32 * 0.01, 0.0]);
            }
        }
        let p = plan(&pts, None);
        let per_tile = pts.len() / p.tiles.len();
        assert!(per_tile <= TILE_POINTS && per_tile > TILE_POINTS / 3, "{} tiles of {:.2}", p.tiles.len(), p.size);
        let p = plan(&pts, Some(0.02));
        assert!((p.size - 1.28).abs() < 1e-9 && (p.cell - 0.02).abs() < 1e-12);
    }
}
