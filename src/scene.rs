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
//! Memory: the points once, each tile's points and field (one tile at a time), the blended
//! values of the band's nodes behind the sweep's front (a block's nodes are meshed and dropped
//! once the tiles that weigh them are done, see [`Sweep`]), and the mesh.

use std::collections::{HashMap, HashSet};

use crate::cloud::{subsample, PointCloud};
use crate::field::{Field, EVALUATION_CHUNK};
use crate::gpu::now;
use crate::mesh::refine::KeyMap;
use crate::mesh::{ActiveCells, ExtractError, ExtractStats, FieldError, Mesh};
use crate::pipeline::{Engine, PipelineError, Reconstruction, SceneReport, Stage};
use crate::settings::{Method, Settings, Tiles};
use crate::units::Units;

/// A cloud whose longest side reaches this many metres is a scene: `tiles auto` cuts it, when
/// its metres are known ([`Scale::stated`]: LAS, E57, a file that states its units, or
/// `--units`) or it has [`UNSTATED_SCENE_POINTS`]. Objects up to a car or a statue (a 4 m
/// closed ellipsoid in the browser tests) keep the one-cube path; a smaller room needs
/// `--tiles on`.
pub const SCENE_EXTENT_M: f64 = 5.0;
/// A cloud whose file does not state its units (PLY, text) is taken as a scene under `tiles
/// auto` only with this many points: objects in such files come in any units, and a 10-unit
/// cow of 10,000 points is one object (the eval clouds are), where a million points across
/// 10 units is a scan of a room or more.
pub const UNSTATED_SCENE_POINTS: usize = 500_000;
/// About this many points in a tile's core, at the scan's density. With 10k the 1M-point room's
/// cells were 1.7 cm, coarser than its points' spacing, and a 918-point sofa came out at 2.01
/// times its CD alone; with 6k (232 tiles of 0.86 m, 1.3 cm cells) every object is within 1.68
/// times, at about twice the tiles (chosen on that one generated room; the street's tiles are
/// set by the cap).
pub const TILE_POINTS: usize = 6_000;
/// Mesh cells along a tile's core: the grid's cell is the tile's size over this.
pub const TILE_CELLS: usize = 64;
/// The overlap on each side of a tile's core, as a share of its size.
pub const OVERLAP: f64 = 0.25;
/// Under `tiles auto`, a tile is at most this many metres per cell (1.6 m tiles) when its
/// points allow: a sparse scan (a street: 1M points over 800 m²) would otherwise get tiles of
/// 3.4 m, whose 5 cm cells lose benches and lamps (measured on the generated street: scanned
/// F at 2 cm 0.83 with 3.4 m tiles, 0.96 with 1.6 m, screened Poisson 0.93).
pub const MAX_AUTO_CELL_M: f64 = 0.025;
/// ... but not below this many points a tile on average: the prior needs points to read a shape
/// (it was trained on 500 to 10k), and a very sparse scan would otherwise make tiles by the
/// thousand.
pub const MIN_CAPPED_TILE_POINTS: usize = 1_500;
/// The overlap in grid cells: [`OVERLAP`] of a tile's [`TILE_CELLS`].
fn overlap_cells() -> i64 {
    (OVERLAP * TILE_CELLS as f64).round() as i64
}

/// Cells around each point's cell whose corners are evaluated.
pub const BAND: i64 = 2;
/// The most a tile's field is raised at a node to pass through the points near it (the
/// network's logit). A closed object in a tile comes out of the prior with its zero level inside
/// its points (the field at them about -1, the interior barely positive), so its surface breaks
/// up; sheets' points sit inside their slab (about +3) and are left alone. The cap keeps a stray
/// point in open air (about -8) from raising a blob around itself.
pub const LEVEL_CAP: f32 = 4.0;
/// Points whose field at them is averaged for a node's raise.
const LEVEL_NEAREST: usize = 8;
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
    /// The tiles holding points, in the sweep's order (along the longest side first), and
    /// their core's point count.
    pub tiles: Vec<([i64; 3], usize)>,
    /// Why the cloud is tiled, and how, in a sentence.
    pub reason: String,
}

/// What a file says of its scale, for [`decide`]: from [`crate::units::UnitsGuess`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Scale {
    /// The cloud's length unit as its file states or suggests it; `--units` overrides.
    pub units: Option<Units>,
    /// The file states its units (or its format fixes them): its size in metres is a fact.
    pub stated: bool,
}

impl From<&crate::units::UnitsGuess> for Scale {
    fn from(g: &crate::units::UnitsGuess) -> Self {
        Scale { units: g.units, stated: g.stated }
    }
}

/// Whether `cloud` is reconstructed in tiles under `settings`: `on`, `off`, or (`auto`) when
/// its longest side in metres reaches [`SCENE_EXTENT_M`] and its metres are known or it has
/// [`UNSTATED_SCENE_POINTS`] (see [`Scale`]; with no units at all, auto takes the numbers as
/// metres). Returns the plan when it tiles.
pub fn decide(cloud: &PointCloud, settings: &Settings, scale: Scale) -> Option<TilePlan> {
    decide_sample(&cloud.positions, 1.0, settings, scale)
}

/// [`decide`] from an even sample of a cloud in which each point stands for `weight` points
/// (the page's preflight keeps a sample of the cloud it has shown).
pub fn decide_sample(points: &[[f32; 3]], weight: f64, settings: &Settings, scale: Scale) -> Option<TilePlan> {
    if points.is_empty() {
        return None;
    }
    let to_m = settings.units.or(scale.units).map_or(1.0, |u| u.metres());
    let extent = span(points, settings);
    let known = scale.stated || settings.units.is_some();
    let many = (points.len() as f64 * weight) as usize >= UNSTATED_SCENE_POINTS;
    let why = match settings.tiles {
        Tiles::Off => return None,
        Tiles::On => "tiles were asked for (--tiles on)".to_string(),
        Tiles::Auto if extent * to_m >= SCENE_EXTENT_M && (known || many) => {
            format!("it spans {:.1} m, more than one object ({SCENE_EXTENT_M} m or more is a scene; --tiles off for one object)", extent * to_m)
        }
        Tiles::Auto => return None,
    };
    let detail = settings.detail.map(|m| m as f64 / to_m);
    let cap = MAX_AUTO_CELL_M * TILE_CELLS as f64 / to_m;
    let mut plan = plan_weighted(points, weight, detail, Some(cap));
    plan.reason = format!(
        "reconstruct the cloud as a scene in {} tiles of {:.2} m (cells of {:.1} cm): {why}",
        plan.tiles.len(),
        plan.size * to_m,
        100.0 * plan.cell * to_m
    );
    Some(plan)
}

/// The longest side of what will be reconstructed of `points`, in file units: without the few
/// points lying apart that the stray-point filter drops ([`crate::outliers::bulk_bounds`]), when
/// it is on. A reflection metres from a part does not make the part a scene.
fn span(points: &[[f32; 3]], settings: &Settings) -> f64 {
    let bounds = if settings.outliers.is_some() { crate::outliers::bulk_bounds(points) } else { crate::cloud::Bounds::of(points) };
    bounds.map_or(0.0, |b| b.longest_side() as f64)
}

/// A sentence for a cloud that `tiles auto` keeps whole though it may be a scene: it spans
/// [`SCENE_EXTENT_M`] or more in units its file does not state, with enough points for several
/// tiles. None otherwise.
pub fn hint(cloud: &PointCloud, settings: &Settings, scale: Scale) -> Option<String> {
    if settings.tiles != Tiles::Auto || cloud.len() < 5 * TILE_POINTS || decide(cloud, settings, scale).is_some() {
        return None;
    }
    let to_m = settings.units.or(scale.units).map_or(1.0, |u| u.metres());
    let extent = span(&cloud.positions, settings) * to_m;
    (extent >= SCENE_EXTENT_M).then(|| {
        format!("the cloud spans {extent:.1} m if its units are metres, and is reconstructed as one object; if it is a room, a facade or a street, --tiles on reconstructs it in tiles")
    })
}

/// The scene settings a run as one object leaves unused, one sentence each (said, not silent).
fn scene_only(settings: &Settings) -> Vec<String> {
    let mut unused = Vec::new();
    if let Some(d) = settings.detail {
        unused.push(format!("--detail {d} is for scenes in tiles: one object's mesh cell follows --resolution"));
    }
    if !settings.one_layer {
        unused.push("--two-layers is for scenes in tiles: one object's mesh is left as it is either way".to_string());
    }
    if settings.tile_regression && settings.method == Method::Nkrr {
        unused.push("--tile-regression is for scenes in tiles: one object's regression is tuned on the whole cloud either way".to_string());
    }
    unused
}

/// Tiles for `points`: of `detail · TILE_CELLS` when a detail (cell size) is given, else the
/// size at which the tiles holding points hold about [`TILE_POINTS`] each.
pub fn plan(points: &[[f32; 3]], detail: Option<f64>) -> TilePlan {
    plan_weighted(points, 1.0, detail, None)
}

/// [`plan`] for a sample in which each point stands for `weight` points; without a detail, the
/// size is brought down towards `cap` while the tiles keep [`MIN_CAPPED_TILE_POINTS`] on average.
fn plan_weighted(points: &[[f32; 3]], weight: f64, detail: Option<f64>, cap: Option<f64>) -> TilePlan {
    let (lo, hi) = bounds(points);
    let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max).max(1e-9);
    let stands_for = |n: usize| (n as f64 * weight).round() as usize;
    let size = match detail {
        Some(d) if d > 0.0 => d * TILE_CELLS as f64,
        _ => {
            // From one tile down by factors of 1.25, the first size whose occupied tiles hold
            // TILE_POINTS or fewer on average.
            let mut s = extent * 1.0001;
            while s > extent / 256.0 {
                let counts = count_tiles(points, lo, s);
                if stands_for(points.len()) / counts.len().max(1) <= TILE_POINTS {
                    break;
                }
                s /= 1.25;
            }
            if let Some(cap) = cap {
                while s > cap {
                    let next = (s / 1.25).max(cap);
                    if stands_for(points.len()) / count_tiles(points, lo, next).len().max(1) < MIN_CAPPED_TILE_POINTS {
                        break;
                    }
                    s = next;
                }
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
    let mut tiles: Vec<([i64; 3], usize)> = count_tiles(points, origin, size).into_iter().map(|(t, n)| (t, stands_for(n))).collect();
    // The sweep runs along the axis with the most tiles, then the next: the front of
    // unfinished blocks (what the blend holds, see [`Sweep`]) is then a slice across the
    // scene's shortest sides.
    let span = |a: usize| tiles.iter().map(|(t, _)| t[a]).max().unwrap_or(0) - tiles.iter().map(|(t, _)| t[a]).min().unwrap_or(0);
    let mut axes = [0, 1, 2];
    axes.sort_by_key(|&a| std::cmp::Reverse(span(a)));
    tiles.sort_by_key(|(t, _)| (t[axes[0]], t[axes[1]], t[axes[2]]));
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

    /// The points of each tile (in [`TilePlan::tiles`]' order): those in its cube with the
    /// overlap, so a point near a border goes to every tile that weighs it.
    pub fn members(&self, points: &[[f32; 3]]) -> Vec<Vec<u32>> {
        let o = OVERLAP * self.size;
        let index: HashMap<[i64; 3], usize> = self.tiles.iter().enumerate().map(|(i, (t, _))| (*t, i)).collect();
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); self.tiles.len()];
        for (i, p) in points.iter().enumerate() {
            let lo = [0, 1, 2].map(|a| ((p[a] as f64 - self.origin[a] - o) / self.size).floor() as i64);
            let hi = [0, 1, 2].map(|a| ((p[a] as f64 - self.origin[a] + o) / self.size).floor() as i64);
            for t in boxed(lo, hi) {
                if let Some(&t) = index.get(&t) {
                    members[t].push(i as u32);
                }
            }
        }
        members
    }

    /// The most points a tile takes in (its cube with the overlap), for `points` of which each
    /// stands for `weight` points.
    pub fn largest_tile(&self, points: &[[f32; 3]], weight: f64) -> usize {
        self.members(points).iter().map(|m| (m.len() as f64 * weight).round() as usize).max().unwrap_or(0)
    }

    /// Raises a tile's `values` (at its band `nodes`, ascending keys) where its field passes
    /// inside `points`: each node by the mean over its [`LEVEL_NEAREST`] points of the field
    /// there (trilinear in the tile's own nodes) where that is below zero, at most [`LEVEL_CAP`].
    /// So the zero level goes through the points of a closed object that the prior, seeing it in
    /// a room's tile, left barely inside (docs/scenes.md, "The level at the points").
    fn level_at_points(&self, tile: [i64; 3], nodes: &[u64], values: &mut [f32], points: &[[f32; 3]]) {
        let value = |n: [i64; 3]| nodes.binary_search(&self.node_key(n)).ok().map(|i| values[i]);
        let mut at = Vec::with_capacity(points.len());
        let mut level = Vec::with_capacity(points.len());
        for p in points {
            let x = [0, 1, 2].map(|a| (p[a] as f64 - self.origin[a]) / self.cell);
            let c = x.map(|v| v.floor() as i64);
            let t = [0, 1, 2].map(|a| x[a] - c[a] as f64);
            let mut f = 0.0;
            let mut whole = true;
            for corner in 0..8 {
                let d = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
                let Some(v) = value([0, 1, 2].map(|a| c[a] + d[a] as i64)) else {
                    whole = false;
                    break;
                };
                let w: f64 = (0..3).map(|a| if d[a] == 1 { t[a] } else { 1.0 - t[a] }).product();
                f += w * v as f64;
            }
            // A point at the tile's outer border has no cell of nodes around it.
            if whole {
                at.push(*p);
                level.push((f as f32).clamp(-LEVEL_CAP, 0.0));
            }
        }
        // A neighbour search per node, only for the band around the points below zero (the
        // rest would be raised by nothing, or by a point beyond that band among its nearest),
        // split over the cores: on a real GPU a scene's time is such CPU loops (docs/scenes.md,
        // "On a GPU"). The band of a subset of the points is a subset of the tile's nodes.
        let below: Vec<[f32; 3]> = at.iter().zip(&level).filter(|(_, &l)| l < 0.0).map(|(p, _)| *p).collect();
        if below.is_empty() {
            return;
        }
        let near_below = self.band_nodes(tile, &below);
        let mut searched = Vec::with_capacity(near_below.len());
        let mut i = 0;
        for k in near_below {
            while i < nodes.len() && nodes[i] < k {
                i += 1;
            }
            if i < nodes.len() && nodes[i] == k {
                searched.push(i);
            }
        }
        let index = crate::sample::PointIndex::new(&at);
        let raise = crate::par::map_ranges(searched.len(), |range| {
            let mut near = Vec::new();
            searched[range]
                .iter()
                .map(|&i| {
                    let n = self.node_of_key(nodes[i]);
                    let q = [0, 1, 2].map(|a| (self.origin[a] + n[a] as f64 * self.cell) as f32);
                    index.k_nearest(q, LEVEL_NEAREST, &mut near);
                    near.iter().map(|&(_, j)| level[j as usize]).sum::<f32>() / near.len().max(1) as f32
                })
                .collect()
        });
        for (&i, r) in searched.iter().zip(raise) {
            values[i] -= r;
        }
    }

    fn node_key(&self, n: [i64; 3]) -> u64 {
        let r1 = self.resolution as u64 + 1;
        n[0] as u64 + r1 * (n[1] as u64 + r1 * n[2] as u64)
    }

    fn node_of_key(&self, k: u64) -> [i64; 3] {
        let r1 = self.resolution as u64 + 1;
        [(k % r1) as i64, (k / r1 % r1) as i64, (k / (r1 * r1)) as i64]
    }

    /// The band's nodes near `points` that `tile` weighs (its cube with the overlap), as keys,
    /// ascending. Marked in a bitmap over the tile's nodes and read back in key order: sorting
    /// every point's 216 keys (two million for a tile of 10k points) was most of a scene's CPU
    /// time on a real GPU (docs/scenes.md, "On a GPU"). Points sharing a cell mark it once.
    fn band_nodes(&self, tile: [i64; 3], points: &[[f32; 3]]) -> Vec<u64> {
        let r = self.resolution as i64;
        let per = TILE_CELLS as i64;
        let o = overlap_cells();
        // Nodes strictly inside the overlap's outer border (weight above 0).
        let lo = tile.map(|t| (t * per - o + 1).max(0));
        let hi = tile.map(|t| ((t + 1) * per + o - 1).min(r));
        if (0..3).any(|a| lo[a] > hi[a]) {
            return Vec::new();
        }
        // Index of `n` in the box from `lo` to `hi` (inclusive), x fastest, and the box's size.
        let boxed_index = |lo: [i64; 3], hi: [i64; 3]| {
            let dims = [0, 1, 2].map(|a| (hi[a] - lo[a] + 1) as usize);
            (move |n: [i64; 3]| ((n[2] - lo[2]) as usize * dims[1] + (n[1] - lo[1]) as usize) * dims[0] + (n[0] - lo[0]) as usize, dims)
        };
        let (node, dims) = boxed_index(lo, hi);
        // The cells whose band reaches the box: BAND + 1 nodes below a cell's, BAND above.
        let (clo, chi) = (lo.map(|l| l - BAND - 1), hi.map(|h| h + BAND));
        let (cell, cdims) = boxed_index(clo, chi);
        let mut cell_seen = vec![false; cdims.iter().product()];
        let mut near = vec![false; dims.iter().product()];
        for p in points {
            let c = [0, 1, 2].map(|a| (((p[a] as f64 - self.origin[a]) / self.cell).floor() as i64).clamp(0, r - 1));
            if (0..3).any(|a| c[a] < clo[a] || c[a] > chi[a]) {
                continue;
            }
            if std::mem::replace(&mut cell_seen[cell(c)], true) {
                continue;
            }
            let from = [0, 1, 2].map(|a| (c[a] - BAND).max(lo[a]));
            let to = [0, 1, 2].map(|a| (c[a] + BAND + 1).min(hi[a]));
            for z in from[2]..=to[2] {
                for y in from[1]..=to[1] {
                    let row = node([from[0], y, z]);
                    near[row..=row + (to[0] - from[0]) as usize].fill(true);
                }
            }
        }
        let mut keys = Vec::new();
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                let row = node([lo[0], y, z]);
                for (i, _) in near[row..row + dims[0]].iter().enumerate().filter(|(_, &m)| m) {
                    keys.push(self.node_key([lo[0] + i as i64, y, z]));
                }
            }
        }
        keys
    }
}

/// What a tile runs, for the preflight's plan of the largest tile: the network, or, with
/// [`Settings::tile_regression`], the regression tuned on the tile's points; its field meshed as
/// it is (the scene's mesh is the level set of the blended field, not a Poisson surface).
pub fn tile_settings(settings: &Settings) -> Settings {
    let method = if settings.tile_regression { settings.method } else { Method::Network };
    Settings { method, surface: crate::settings::Surface::Field, ..settings.clone() }
}

/// Reconstructs `cloud` (whose file says `scale` of its size, see [`decide`]) the way [`decide`] picks: in tiles when it is a scene, else whole
/// ([`Engine::reconstruct`]). The CLI, the page and the JS API all come through here.
pub async fn reconstruct_auto(
    engine: &Engine,
    cloud: &PointCloud,
    settings: &Settings,
    scale: Scale,
    progress: &mut dyn FnMut(&Stage) -> bool,
) -> Result<Reconstruction, PipelineError> {
    match decide(cloud, settings, scale) {
        Some(tiles) => reconstruct(engine, cloud, settings, &tiles, progress).await,
        None => {
            let mut rec = engine.reconstruct(cloud, settings, progress).await?;
            rec.notices.extend(hint(cloud, settings, scale));
            rec.notices.extend(scene_only(settings));
            Ok(rec)
        }
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
    // What a tile runs ([`tile_settings`], which the preflight plans too).
    let per_tile = tile_settings(settings);
    if per_tile.method != settings.method {
        notices.push("the tiles use the network's field: --tile-regression tunes the kernel regression on each tile's points, several times slower (docs/scenes.md)".into());
    }
    if settings.surface == crate::settings::Surface::Poisson {
        notices.push("--surface poisson is for one object: a scene's mesh is the level set of its tiles' blended field".into());
    }
    let t_all = now();
    let o = OVERLAP * tiles.size;
    let mut members = tiles.members(&cloud.positions);

    // The blended field, meshed block by block behind the sweep (see [`Sweep`]).
    let mut sweep = Sweep::new(tiles);
    let mut evaluations = 0u64;
    // Where a tile's time goes: the network on the device (encoding, decoding, their
    // readbacks), the blend on the CPU (band nodes, the sweep, its meshing), and handing the
    // finished pieces over (in the page: to the viewer). The page runs tiles several times
    // slower than native; these say which part.
    let (mut t_network, mut t_blend, mut t_pieces, mut t_regression) = (0.0, 0.0, 0.0, 0.0);
    // The regression's inducing points and backend, planned once for the largest tile (a
    // tile with fewer points gets fewer, as one object would: crate::plan::inducing_points).
    let tile_plan = (per_tile.method == Method::Nkrr).then(|| engine.memory_plan(tiles.largest_tile(&cloud.positions, 1.0), false, &per_tile));
    if let Some(plan) = &tile_plan {
        // What the plan changes to fit is said, as for one object (it is the regression's m
        // that the tiles take from it).
        notices.extend(plan.actions.iter().map(|a| format!("to fit in memory, each tile's regression will {a}")));
    }
    let mut tuned = Tuned::default();
    let mut evaluator: Option<crate::field::Evaluator> = None;
    let of = tiles.tiles.len();
    for (done, ((tile, _), ids)) in tiles.tiles.iter().zip(&mut members).enumerate() {
        if !progress(&Stage::Tile { done, of }) {
            return Err(PipelineError::Cancelled);
        }
        let ids = std::mem::take(ids);
        let t_tile = now();
        if ids.len() >= MIN_TILE_POINTS {
            let points: Vec<[f32; 3]> = ids.iter().map(|&i| cloud.positions[i as usize]).collect();
            let seen = subsample(&points, settings.max_points, 1);
            // The tile's cube with its overlap fills the network's unit cube.
            let centre = [0, 1, 2].map(|a| tiles.origin[a] + (tile[a] as f64 + 0.5) * tiles.size);
            let scale = tiles.size + 2.0 * o;
            let local = |p: [f64; 3]| [0, 1, 2].map(|a| ((p[a] - centre[a]) / scale) as f32);
            let normalised: Vec<[f32; 3]> = seen.iter().map(|p| local(p.map(|v| v as f64))).collect();
            let t = now();
            let planes = engine.net.encode(&normalised).await?;
            t_network += now() - t;
            let nodes = tiles.band_nodes(*tile, &points);
            let queries: Vec<[f32; 3]> = nodes
                .iter()
                .map(|&k| {
                    let n = tiles.node_of_key(k);
                    local([0, 1, 2].map(|a| tiles.origin[a] + n[a] as f64 * tiles.cell))
                })
                .collect();
            // The regression tuned on this tile's points, as one object's would be on its own
            // (the pairs, the tuning, β): the tile's field is then g, or l + g.
            let field = match &tile_plan {
                Some(plan) => {
                    let t = now();
                    let pairs = crate::field::training_pairs(&engine.net, &planes, &normalised, settings).await?;
                    let (regression, _) = plan.regression(settings, normalised.len());
                    // Cancel reaches into the tuning's steps, not only between tiles.
                    let mut report = |_: usize, _: f64| progress(&Stage::Tile { done, of });
                    let (fit, summary) = crate::field::fit(&engine.gpu, &pairs, settings, regression, &mut report).await?;
                    tuned.add(&summary);
                    t_regression += now() - t;
                    Field::Krr(fit)
                }
                None => Field::Network,
            };
            let field_error = |e| PipelineError::Mesh(ExtractError::Field(FieldError(e)));
            // One evaluator for every tile: its decoder's buffers made at the first, rebound to
            // each tile's planes and field.
            let evaluator = match &mut evaluator {
                Some(ev) => {
                    ev.rebind(&planes, field).map_err(field_error)?;
                    ev
                }
                None => evaluator.insert(field.evaluator(&engine.net, &planes, EVALUATION_CHUNK).map_err(field_error)?),
            };
            let mut values = Vec::with_capacity(queries.len());
            let t = now();
            for chunk in queries.chunks(EVALUATION_CHUNK) {
                values.extend(evaluator.evaluate(chunk).await.map_err(field_error)?);
            }
            t_network += now() - t;
            evaluations += values.len() as u64;
            // The evaluator is rebound to the next tile's planes before it decodes again.
            engine.gpu.retire([planes.buffer]);
            tiles.level_at_points(*tile, &nodes, &mut values, &points);
            sweep.add_tile(*tile, &nodes, &values);
        }
        let new = sweep.tile_done(*tile);
        if !new.is_empty() {
            let mut piece = sweep.piece(new);
            crate::units::to_metres(settings.units, &mut piece.positions, cloud.origin);
            let t = now();
            if !progress(&Stage::Meshed { positions: piece.positions, indices: piece.indices }) {
                return Err(PipelineError::Cancelled);
            }
            t_pieces += now() - t;
        }
        t_blend += now() - t_tile;
    }
    progress(&Stage::Tile { done: of, of });
    // The evaluator's predictor goes before the mesh is finished.
    drop(evaluator);
    t_blend -= t_network + t_pieces + t_regression;
    let mut timings = vec![("tiles", now() - t_all), ("network in tiles", t_network), ("blend in tiles", t_blend), ("pieces shown", t_pieces)];
    if tile_plan.is_some() {
        timings.push(("regression in tiles", t_regression));
        notices.extend(tuned.notice());
    }

    let t = now();
    let report = sweep.report();
    let (mut mesh, active) = sweep.finish();
    let triangles_extracted = mesh.triangle_count();
    let opts = crate::mesh::ExtractOptions { remove_small_components: settings.remove_small_components, ..Default::default() };
    let removal;
    (mesh, removal) = crate::mesh::postprocess(mesh, &opts);
    timings.push(("mesh", now() - t));
    if mesh.indices.is_empty() {
        return Err(PipelineError::NoSurface { evaluations, field_max: 0.0, method: per_tile.method });
    }
    // The same finish as one object's (the last fit, the trim, the simplification), against
    // all the scene's points: its steps measure in point spacings, whatever the units.
    // A piece's support is measured against a tile's worth of points, not the scene's: a chair
    // is a small share of a street, and must stay.
    let share = |s: f64| s * (TILE_POINTS as f64 / cloud.len().max(1) as f64).min(1.0);
    let finish = Settings { min_support: settings.min_support.map(share), ..settings.clone() };
    // Two layers of a sheet closer than half a cell are one surface: the grid cannot mesh a
    // slab that thin as two.
    let sheet_gap = (0.5 * tiles.cell) as f32;
    // A scene's own fit (mesh::fit::Fitted::Scene): the tangent planes' noise gate is set in the
    // unit cube objects are fitted in, not in a scene's metres.
    let finished = crate::mesh::finish::finish(&mut mesh, &cloud.positions, &finish, crate::mesh::fit::Fitted::Scene, crate::mesh::finish::Closure::Keep, Some(sheet_gap), &mut notices, &mut timings);
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
        scene: Some(report),
    })
}

/// What the regression's tuning did over a scene's tiles, said once for the scene (a tile's
/// own summary is one object's: [`crate::field::TuningSummary`]).
#[derive(Default)]
struct Tuned {
    tiles: usize,
    m: (usize, usize),
    steps: usize,
    /// Tiles whose kept iterate is the first (the tuning did not improve on the initial fit).
    kept_first: usize,
}

impl Tuned {
    fn add(&mut self, s: &crate::field::TuningSummary) {
        self.m = if self.tiles == 0 { (s.m, s.m) } else { (self.m.0.min(s.m), self.m.1.max(s.m)) };
        self.tiles += 1;
        self.steps += s.steps_run;
        self.kept_first += (s.best_step == 0) as usize;
    }

    fn notice(&self) -> Option<String> {
        let Tuned { tiles, m, steps, kept_first } = *self;
        let m = if m.0 == m.1 { format!("m = {}", m.0) } else { format!("m = {}-{} (fewer where a tile has fewer points)", m.0, m.1) };
        (tiles > 0).then(|| format!("the kernel regression was tuned on each of {tiles} tiles' points ({m}, {:.0} steps a tile; {kept_first} tiles kept their initial fit)", steps as f64 / tiles as f64))
    }
}

/// Cells along a block of the sweep: half a tile, so that a block's nodes (and the nodes one
/// cell above it, which its cells reach) are weighed by two tiles along each axis, not three
/// (the overlap is a quarter of a tile): the first blocks are final after the first tile.
const BLOCK: i64 = TILE_CELLS as i64 / 2;

/// The blended field on the band's nodes, grouped by the block (of [`BLOCK`] cells a side)
/// each node lies in. A block is meshed as soon as every tile that weighs its nodes, or the
/// nodes one cell above it, is done, and its nodes are dropped as soon as the blocks whose
/// cells reach into it (itself and the seven below it) are meshed.
/// So the field held follows the sweep's front, not the scene, and finished pieces of the
/// mesh are there to show while the rest is computed.
struct Sweep<'a> {
    plan: &'a TilePlan,
    planned: HashSet<[i64; 3]>,
    done: HashSet<[i64; 3]>,
    meshed: HashSet<[i64; 3]>,
    /// Σ w·f and Σ w per band node, by block.
    blocks: HashMap<[i64; 3], KeyMap<(f32, f32)>>,
    held: usize,
    report: SceneReport,
    /// The mesh so far, welded by the global edge key of each vertex.
    mesh: Mesh,
    vertex_of_edge: KeyMap<u32>,
    active: usize,
}

/// The tiles (per axis, first and last) that weigh a node of block `b` or one cell above it:
/// tile `t` weighs node `n` when `t·C − o < n < (t + 1)·C + o` (C cells a tile, o the overlap's).
fn tiles_of_block(b: i64) -> (i64, i64) {
    let (c, o) = (TILE_CELLS as i64, overlap_cells());
    let (lo, hi) = (b * BLOCK, (b + 1) * BLOCK);
    ((lo - o).div_euclid(c), (hi + o + c - 1).div_euclid(c) - 1)
}

/// Every combination of `lo..=hi` per axis.
fn boxed(lo: [i64; 3], hi: [i64; 3]) -> impl Iterator<Item = [i64; 3]> {
    (lo[2]..=hi[2]).flat_map(move |z| (lo[1]..=hi[1]).flat_map(move |y| (lo[0]..=hi[0]).map(move |x| [x, y, z])))
}

impl<'a> Sweep<'a> {
    fn new(plan: &'a TilePlan) -> Self {
        Sweep {
            plan,
            planned: plan.tiles.iter().map(|(t, _)| *t).collect(),
            done: HashSet::new(),
            meshed: HashSet::new(),
            blocks: HashMap::new(),
            held: 0,
            report: SceneReport { tiles: plan.tiles.len(), ..Default::default() },
            mesh: Mesh::default(),
            vertex_of_edge: KeyMap::default(),
            active: 0,
        }
    }

    fn block_of(n: [i64; 3]) -> [i64; 3] {
        n.map(|c| c.div_euclid(BLOCK))
    }

    /// Adds `tile`'s values at its band's nodes (`nodes` ascending, as
    /// [`TilePlan::band_nodes`] gives them), each weighed by the tile's blend weight there.
    /// Consecutive nodes mostly fall in one block, whose map is then looked up once for the run.
    fn add_tile(&mut self, tile: [i64; 3], nodes: &[u64], values: &[f32]) {
        let mut open: Option<([i64; 3], KeyMap<(f32, f32)>)> = None;
        for (&key, &v) in nodes.iter().zip(values) {
            let n = self.plan.node_of_key(key);
            let w = self.plan.weight(tile, n.map(|c| c as f64 * self.plan.cell)) as f32;
            if !(w > 0.0 && v.is_finite()) {
                continue;
            }
            let b = Self::block_of(n);
            if open.as_ref().map(|(ob, _)| *ob) != Some(b) {
                if let Some((ob, map)) = open.take() {
                    self.blocks.insert(ob, map);
                }
                open = Some((b, self.blocks.remove(&b).unwrap_or_default()));
            }
            let map = open.as_mut().map(|(_, m)| m).expect("opened above");
            let e = map.entry(key).or_insert_with(|| {
                self.held += 1;
                self.report.nodes += 1;
                (0.0, 0.0)
            });
            e.0 += w * v;
            e.1 += w;
        }
        if let Some((ob, map)) = open {
            self.blocks.insert(ob, map);
        }
        self.report.peak_nodes = self.report.peak_nodes.max(self.held);
    }

    /// Every tile that can weigh a node of block `b` (or one cell above it) is done, or holds
    /// no points.
    fn complete(&self, b: [i64; 3]) -> bool {
        let r = b.map(tiles_of_block);
        boxed(r.map(|r| r.0), r.map(|r| r.1)).all(|t| !self.planned.contains(&t) || self.done.contains(&t))
    }

    /// Marks `tile` done, meshes the blocks that this completes and drops the nodes no block
    /// needs any more. Returns the range of the mesh's indices that are new.
    fn tile_done(&mut self, tile: [i64; 3]) -> std::ops::Range<usize> {
        self.done.insert(tile);
        let start = self.mesh.indices.len();
        // Only the blocks this tile weighs can have been completed by it: those within its
        // cube with the overlap, and one more below.
        let o = overlap_cells();
        let c = TILE_CELLS as i64;
        let lo = tile.map(|t| (t * c - o).div_euclid(BLOCK) - 1);
        let hi = tile.map(|t| ((t + 1) * c + o).div_euclid(BLOCK));
        let mut newly: Vec<[i64; 3]> = boxed(lo, hi).filter(|&b| self.blocks.contains_key(&b) && self.complete(b)).collect();
        newly.retain(|b| !self.meshed.contains(b));
        for &b in &newly {
            self.mesh_block(b);
            self.meshed.insert(b);
        }
        for &c in &newly {
            for d in 0..8 {
                let up = [c[0] + (d & 1), c[1] + (d >> 1 & 1), c[2] + (d >> 2 & 1)];
                let below_done = (0..8).all(|e| self.complete([up[0] - (e & 1), up[1] - (e >> 1 & 1), up[2] - (e >> 2 & 1)]));
                if below_done {
                    if let Some(nodes) = self.blocks.remove(&up) {
                        self.held -= nodes.len();
                    }
                }
            }
        }
        start..self.mesh.indices.len()
    }

    fn value(&self, n: [i64; 3]) -> Option<f32> {
        if n.iter().any(|&c| c > self.plan.resolution as i64) {
            return None;
        }
        self.blended(self.blocks.get(&Self::block_of(n))?, n)
    }

    /// The blended value Σ w·f / Σ w at node `n` of `block` (the block's map), if it has one.
    fn blended(&self, block: &KeyMap<(f32, f32)>, n: [i64; 3]) -> Option<f32> {
        block.get(&self.plan.node_key(n)).map(|(wf, w)| wf / w)
    }

    /// Marching cubes over block `c`'s cells (those whose low corner is in it) with all eight
    /// corners blended and a sign change among them, welded onto the mesh so far.
    fn mesh_block(&mut self, c: [i64; 3]) {
        let r = self.plan.resolution;
        let mut found: Vec<([u32; 3], [f32; 8])> = Vec::new();
        let own = &self.blocks[&c];
        for &k in own.keys() {
            let n = self.plan.node_of_key(k);
            if n.iter().any(|&x| x >= r as i64) {
                continue;
            }
            let mut v = [0.0f32; 8];
            let all = (0..8).all(|corner| {
                let at = [n[0] + (corner & 1) as i64, n[1] + (corner >> 1 & 1) as i64, n[2] + (corner >> 2 & 1) as i64];
                // Most corners are in this block: its map is at hand, the others' are looked up.
                let value = if Self::block_of(at) == c { self.blended(own, at) } else { self.value(at) };
                value.map(|x| v[corner] = x).is_some()
            });
            let inside = v.iter().filter(|&&x| x > 0.0).count();
            if all && inside > 0 && inside < 8 {
                found.push((n.map(|x| x as u32), v));
            }
        }
        found.sort_by_key(|(c, _)| (c[2], c[1], c[0]));
        self.active += found.len();
        let side = r as f64 * self.plan.cell;
        let lo = self.plan.origin.map(|c| c as f32);
        let hi = self.plan.origin.map(|c| (c + side) as f32);
        let cells = ActiveCells { resolution: r, domain: (lo, hi), cells: found.iter().map(|(c, _)| *c).collect(), values: found.into_iter().map(|(_, v)| v).collect() };
        let (keys, positions) = crate::mesh::marching_cubes::soup(&cells);
        for (k, p) in keys.into_iter().zip(positions) {
            let next = self.mesh.positions.len() as u32;
            let i = *self.vertex_of_edge.entry(k).or_insert(next);
            if i == next {
                self.mesh.positions.push(p);
            }
            self.mesh.indices.push(i);
        }
    }

    /// The triangles `indices[range]` as a mesh of their own.
    fn piece(&self, range: std::ops::Range<usize>) -> Mesh {
        let mut local: HashMap<u32, u32> = HashMap::new();
        let mut piece = Mesh::default();
        for &i in &self.mesh.indices[range] {
            let j = *local.entry(i).or_insert_with(|| {
                piece.positions.push(self.mesh.positions[i as usize]);
                piece.positions.len() as u32 - 1
            });
            piece.indices.push(j);
        }
        piece
    }

    fn report(&self) -> SceneReport {
        self.report.clone()
    }

    /// The whole mesh and its count of active cells, once every tile is done.
    fn finish(self) -> (Mesh, usize) {
        debug_assert!(self.blocks.is_empty(), "{} blocks left", self.blocks.len());
        (self.mesh, self.active)
    }
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

    /// [`TilePlan::band_nodes`] against its definition: every node within the band of a
    /// point's cell (BAND below, BAND + 1 above) that the tile weighs, sorted and unique; for
    /// tiles inside the grid, at its low and high borders, and points straying past the tile.
    #[test]
    fn band_nodes_are_the_nodes_around_each_points_cell_that_the_tile_weighs() {
        let plan = TilePlan { size: 1.0, cell: 1.0 / 64.0, origin: [0.0; 3], resolution: 192, tiles: Vec::new(), reason: String::new() };
        let reference = |tile: [i64; 3], points: &[[f32; 3]]| {
            let (r, per, o) = (plan.resolution as i64, TILE_CELLS as i64, overlap_cells());
            let lo = tile.map(|t| t * per - o + 1);
            let hi = tile.map(|t| (t + 1) * per + o - 1);
            let mut keys = Vec::new();
            for p in points {
                let c = [0, 1, 2].map(|a| (((p[a] as f64 - plan.origin[a]) / plan.cell).floor() as i64).clamp(0, r - 1));
                for d in boxed([-BAND; 3], [BAND + 1; 3]) {
                    let n = [0, 1, 2].map(|a| c[a] + d[a]);
                    if (0..3).all(|a| n[a] >= lo[a].max(0) && n[a] <= hi[a].min(r)) {
                        keys.push(plan.node_key(n));
                    }
                }
            }
            keys.sort_unstable();
            keys.dedup();
            keys
        };
        let mut rng = crate::rng::SplitMix64(7);
        for tile in [[1, 1, 1], [0, 0, 0], [2, 2, 2], [0, 2, 1]] {
            // Points in the tile's cube with its overlap and a little past it, some sharing cells.
            let mut pts: Vec<[f32; 3]> = (0..3000).map(|_| tile.map(|t| (t as f64 - 0.4 + 1.8 * rng.unit()) as f32)).collect();
            pts.extend(pts[..500].to_vec());
            let got = plan.band_nodes(tile, &pts);
            assert!(!got.is_empty());
            assert_eq!(got, reference(tile, &pts), "tile {tile:?}");
        }
        assert!(plan.band_nodes([1, 1, 1], &[]).is_empty());
    }

    /// A closed object whose field crosses zero inside its points is raised to cross at them; a
    /// sheet inside its slab is left as it is; a stray point in open air stays below zero.
    #[test]
    fn a_tiles_field_is_raised_to_pass_through_its_points() {
        let plan = TilePlan { size: 1.0, cell: 1.0 / 64.0, origin: [0.0; 3], resolution: 192, tiles: Vec::new(), reason: String::new() };
        let tile = [1, 1, 1];
        let node_at = |k: u64| plan.node_of_key(k).map(|n| n as f64 * plan.cell);
        let at_points = |nodes: &[u64], values: &[f32], pts: &[[f32; 3]]| -> Vec<f64> {
            // The field at each point, trilinear in the nodes around it.
            pts.iter()
                .map(|p| {
                    let x = p.map(|v| v as f64 / plan.cell);
                    let c = x.map(|v| v.floor() as i64);
                    (0..8)
                        .map(|corner| {
                            let d = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1].map(|b| b as i64);
                            let i = nodes.binary_search(&plan.node_key([0, 1, 2].map(|a| c[a] + d[a]))).unwrap();
                            let w: f64 = (0..3).map(|a| if d[a] == 1 { x[a] - c[a] as f64 } else { 1.0 - x[a] + c[a] as f64 }).product();
                            w * values[i] as f64
                        })
                        .sum()
                })
                .collect()
        };
        // A ball of radius 0.3 whose field is zero 1.6 cells inside its points (-1 at them).
        let centre = [1.5; 3];
        let mut rng = crate::rng::SplitMix64(5);
        let ball: Vec<[f32; 3]> = (0..3000)
            .map(|_| {
                let d = [0; 3].map(|_| rng.unit() * 2.0 - 1.0);
                let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-9);
                [0, 1, 2].map(|a| (centre[a] + 0.3 * d[a] / n) as f32)
            })
            .collect();
        let radius = |x: [f64; 3]| (0..3).map(|a| (x[a] - centre[a]).powi(2)).sum::<f64>().sqrt();
        let nodes = plan.band_nodes(tile, &ball);
        let mut values: Vec<f32> = nodes.iter().map(|&k| (40.0 * (0.3 - radius(node_at(k))) - 1.0) as f32).collect();
        let before = at_points(&nodes, &values, &ball);
        assert!(before.iter().all(|&f| (f + 1.0).abs() < 0.1));
        plan.level_at_points(tile, &nodes, &mut values, &ball);
        let after = at_points(&nodes, &values, &ball);
        let mean = after.iter().sum::<f64>() / after.len() as f64;
        assert!(mean.abs() < 0.05 && after.iter().all(|&f| f.abs() < 0.2), "mean {mean}");
        // Inside the points by more than a cell is inside now (it was outside down to 1.6 cells).
        for (&k, &v) in nodes.iter().zip(&values) {
            let r = radius(node_at(k));
            if r < 0.3 - plan.cell {
                assert!(v > 0.0, "r {r} v {v}");
            } else if r > 0.3 + plan.cell {
                assert!(v < 0.0, "r {r} v {v}");
            }
        }

        // A floor: its points at the middle of the field's slab (+3) are left alone.
        let floor: Vec<[f32; 3]> = (0..2000).map(|_| [(1.0 + rng.unit()) as f32, (1.0 + rng.unit()) as f32, 1.5]).collect();
        let nodes = plan.band_nodes(tile, &floor);
        let slab: Vec<f32> = nodes.iter().map(|&k| (3.0 - 200.0 * (node_at(k)[2] - 1.5).abs()) as f32).collect();
        let mut values = slab.clone();
        plan.level_at_points(tile, &nodes, &mut values, &floor);
        assert_eq!(values, slab);

        // A few stray points in open air (-8): raised by the cap at most, so still outside.
        let stray: Vec<[f32; 3]> = (0..5).map(|i| [1.5 + 0.001 * i as f32, 1.5, 1.5]).collect();
        let nodes = plan.band_nodes(tile, &stray);
        let mut values = vec![-8.0f32; nodes.len()];
        plan.level_at_points(tile, &nodes, &mut values, &stray);
        assert!(values.iter().all(|&v| v == -8.0 + LEVEL_CAP), "{values:?}");
    }

    /// A wavy strip of floor 6 m long through [`Sweep`] against meshing the whole blend at once
    /// (the blend accumulated the same way, marching cubes over every cell): the same
    /// triangles, while the sweep holds only a few slices of the strip's nodes at a time.
    #[test]
    fn the_sweep_meshes_what_the_whole_blend_would_and_holds_a_front() {
        let height = |x: f64, y: f64| 0.3 + 0.05 * (3.0 * x).sin() + 0.02 * (5.0 * y).cos();
        let mut pts = Vec::new();
        for i in 0..200 {
            for j in 0..34 {
                let (x, y) = (i as f64 * 0.03, j as f64 * 0.03);
                pts.push([x as f32, y as f32, height(x, y) as f32]);
            }
        }
        let plan = plan(&pts, Some(0.01));
        let field = |n: [i64; 3]| {
            let p = [0, 1, 2].map(|a| plan.origin[a] + n[a] as f64 * plan.cell);
            (height(p[0], p[1]) - p[2]) as f32
        };
        let mut sweep = Sweep::new(&plan);
        let mut whole: HashMap<u64, (f32, f32)> = HashMap::new();
        let mut pieces = 0;
        for ((t, _), ids) in plan.tiles.iter().zip(plan.members(&pts)) {
            let mine: Vec<[f32; 3]> = ids.iter().map(|&i| pts[i as usize]).collect();
            let nodes = plan.band_nodes(*t, &mine);
            sweep.add_tile(*t, &nodes, &nodes.iter().map(|&k| field(plan.node_of_key(k))).collect::<Vec<_>>());
            for k in nodes {
                let n = plan.node_of_key(k);
                let w = plan.weight(*t, n.map(|c| c as f64 * plan.cell)) as f32;
                if w > 0.0 {
                    let e = whole.entry(k).or_insert((0.0, 0.0));
                    e.0 += w * field(n);
                    e.1 += w;
                }
            }
            pieces += !sweep.tile_done(*t).is_empty() as usize;
        }
        let report = sweep.report();
        let (mesh, _) = sweep.finish();

        // The whole blend at once.
        let r = plan.resolution as i64;
        let value = |n: [i64; 3]| whole.get(&plan.node_key(n)).map(|(wf, w)| wf / w);
        let mut cells = Vec::new();
        for &k in whole.keys() {
            let n = plan.node_of_key(k);
            if n.iter().any(|&c| c >= r) {
                continue;
            }
            let v: Option<Vec<f32>> = (0..8).map(|c| value([n[0] + (c & 1), n[1] + (c >> 1 & 1), n[2] + (c >> 2 & 1)])).collect();
            if let Some(v) = v {
                let inside = v.iter().filter(|&&x| x > 0.0).count();
                if inside > 0 && inside < 8 {
                    cells.push((n.map(|c| c as u32), <[f32; 8]>::try_from(v).unwrap()));
                }
            }
        }
        cells.sort_by_key(|(c, _)| (c[2], c[1], c[0]));
        let side = plan.resolution as f64 * plan.cell;
        let all = ActiveCells {
            resolution: plan.resolution,
            domain: (plan.origin.map(|c| c as f32), plan.origin.map(|c| (c + side) as f32)),
            cells: cells.iter().map(|(c, _)| *c).collect(),
            values: cells.iter().map(|(_, v)| *v).collect(),
        };
        let reference = crate::mesh::polygonize(&all);
        let triangles = |m: &Mesh| {
            let mut t: Vec<[[u32; 3]; 3]> = m
                .indices
                .chunks_exact(3)
                .map(|t| [0, 1, 2].map(|i| m.positions[t[i] as usize].map(f32::to_bits)))
                .collect();
            t.sort_unstable();
            t
        };
        eprintln!("{} tiles, {pieces} pieces, {} triangles; nodes {} held at most {}", plan.tiles.len(), mesh.triangle_count(), report.nodes, report.peak_nodes);
        assert!(mesh.triangle_count() > 10_000);
        assert_eq!(mesh.vertex_count(), reference.vertex_count());
        assert!(triangles(&mesh) == triangles(&reference), "the sweep's mesh differs from the whole blend's");
        assert_eq!(report.nodes, whole.len());
        // A piece after (nearly) every tile, and the blend held a front of about three half-tile
        // slices of the strip's twenty (measured: 16 % of the nodes).
        assert!(pieces * 4 >= plan.tiles.len() * 3, "{pieces} pieces for {} tiles", plan.tiles.len());
        assert!(report.peak_nodes * 4 < report.nodes, "held {} of {} nodes", report.peak_nodes, report.nodes);
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

    #[test]
    fn sparse_scans_get_tiles_of_at_most_the_cap_while_they_hold_points() {
        // A 16 x 8 m ground at 816 points a square metre: tiles of about 3 m by the density
        // (TILE_POINTS each), 1.6 m under the cap; at 400 a square metre the cap is not reached
        // (about 1000 points a tile would be too few at 1.6 m: it stops where tiles still hold
        // 1500).
        let floor = |step: f32| -> Vec<[f32; 3]> {
            let (nx, ny) = ((16.0 / step) as usize, (8.0 / step) as usize);
            (0..nx * ny).map(|i| [(i % nx) as f32 * step, (i / nx) as f32 * step, 0.0]).collect()
        };
        let dense = floor(0.035); // 816 a square metre
        let free = plan_weighted(&dense, 1.0, None, None);
        let capped = plan_weighted(&dense, 1.0, None, Some(1.6));
        assert!(free.size > 2.5 && (capped.size - 1.6).abs() < 1e-9, "{} {}", free.size, capped.size);
        let sparse = floor(0.05); // 400 a square metre
        let capped = plan_weighted(&sparse, 1.0, None, Some(1.6));
        let per_tile = sparse.len() / capped.tiles.len();
        assert!(capped.size > 1.6 && per_tile >= MIN_CAPPED_TILE_POINTS, "{} m, {per_tile} a tile", capped.size);
        // A detail given is taken as it is.
        assert!((plan_weighted(&sparse, 1.0, Some(0.01), Some(1.6)).size - 0.64).abs() < 1e-9);
    }
}
