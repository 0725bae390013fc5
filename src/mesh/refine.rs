//! Coarse-to-fine search for the cells the surface passes through, as a state machine that asks
//! for explicit batches of field evaluations (so the same code serves a blocking native field
//! and an asynchronous browser one).
//!
//! The finest grid has `resolution³` cells over the domain; its corners are addressed by integer
//! coordinates `0..=resolution` per axis. The search:
//!
//! 1. evaluates every corner of the coarse grid (`coarse'³` cells, where `coarse'` is
//!    `resolution / 2^levels`, the smallest such value `>= ¾ coarse`, see [`Plan`]);
//! 2. marks the cells whose corners do not all have the same side (INSIDE: value `> 0`); on the
//!    coarse grid also every cell touching one of them (a one-cell dilation, so that a feature
//!    near the surface that slips between the coarse corners is still refined when it shows at
//!    the next level);
//! 3. splits each marked cell into 8 and evaluates the corners not known yet; repeats 2–3 until
//!    the finest level, where the cells with a sign change are the active cells. Below the
//!    coarse grid there is no dilation: what a level misses of a surface it found elsewhere, the
//!    closing step (4) recovers, and the refinement costs about half the evaluations (issue 27:
//!    the eval clouds' meshes came out bit for bit the same). What is lost is a separate
//!    component that first shows below the coarse level's first refinement: a bubble about a
//!    finest cell across;
//! 4. closes the surface: while an active cell has a face with corners on both sides whose
//!    neighbour across that face is not active, the neighbour is added (its missing corners
//!    evaluated). Marching cubes makes the same segments on both sides of a face, so after this
//!    every surface component that was found at all is complete: the result is watertight
//!    however the coarse levels sampled the field, and for a smooth field it equals the dense
//!    grid's.
//!
//! Outside the domain counts as outside: corner values on the domain's boundary are clamped to
//! at most 0, so the surface closes along the boundary where the field is positive there.
//! Non-finite values are made finite: NaN counts as outside (0), ±∞ as ±1e30.

use std::collections::HashMap;
use std::fmt;
use std::hash::{BuildHasherDefault, Hasher};

/// Why a field could not be evaluated.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldError(pub String);

impl fmt::Display for FieldError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "field evaluation failed: {}", self.0)
    }
}

impl std::error::Error for FieldError {}

impl From<String> for FieldError {
    fn from(s: String) -> Self {
        FieldError(s)
    }
}

impl From<&str> for FieldError {
    fn from(s: &str) -> Self {
        FieldError(s.to_string())
    }
}

impl From<crate::gpu::GpuError> for FieldError {
    fn from(e: crate::gpu::GpuError) -> Self {
        FieldError(e.to_string())
    }
}

/// An implicit surface, evaluated in batches: one logit-like value per point, INSIDE where the
/// value is `> 0`; the surface is the 0 level. Points are in the domain's coordinates.
///
/// A batch can be large (all `(coarse + 1)³` coarse corners at once, hundreds of thousands of
/// points at later levels): an implementation with a memory limit splits it itself.
/// Any `FnMut(&[[f32; 3]]) -> Result<Vec<f32>, FieldError>` closure is a field.
pub trait Field {
    fn eval(&mut self, points: &[[f32; 3]]) -> Result<Vec<f32>, FieldError>;
}

impl<F> Field for F
where
    F: FnMut(&[[f32; 3]]) -> Result<Vec<f32>, FieldError>,
{
    fn eval(&mut self, points: &[[f32; 3]]) -> Result<Vec<f32>, FieldError> {
        self(points)
    }
}

/// What to extract, and how finely.
#[derive(Clone, Debug, PartialEq)]
pub struct ExtractOptions {
    /// The finest grid has `resolution³` cells over the domain.
    pub resolution: u32,
    /// The coarsest grid has about `coarse³` cells (see [`Plan`] for the exact value); `coarse
    /// >= resolution` evaluates the dense finest grid.
    pub coarse: u32,
    /// The domain `(min, max)`: a padded box around the data, outside which everything is
    /// outside.
    pub domain: ([f32; 3], [f32; 3]),
    /// Drop connected components with fewer than this fraction of the largest component's
    /// triangles (`None`: keep all).
    pub remove_small_components: Option<f32>,
}

impl Default for ExtractOptions {
    fn default() -> Self {
        ExtractOptions { resolution: 128, coarse: 32, domain: ([-0.55; 3], [0.55; 3]), remove_small_components: None }
    }
}

/// The largest supported `resolution` (corner coordinates must fit 32-bit keys on the GPU).
pub const MAX_RESOLUTION: u32 = 1024;

/// The most corners the coarse grid (evaluated densely, in one batch) may have: 257³.
pub const MAX_COARSE_CORNERS: u64 = 257 * 257 * 257;

/// How much work meshing at `resolution` takes, estimated from refine batches measured on a
/// sphere (about 19 R² evaluations in the largest batch), doubled: an estimate for the memory
/// plan, not a bound.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MeshingSize {
    /// Queries in the largest refine batch (the first is the coarse grid).
    pub batch: u64,
    /// Field evaluations in all.
    pub evaluated: u64,
    /// Active cells at the finest level.
    pub active: u64,
    pub triangles: u64,
    /// Field evaluations a closed surface typically takes: the dense 33³ coarse grid, then about
    /// 10 R² (the eval clouds at R = 128 took 4.3–11.2 R² once only the coarse level was dilated;
    /// 8–21 before). What progress is measured against (a typical count,
    /// where [`MeshingSize::evaluated`] is a bound for memory): the one copy of this rule.
    pub expected: u64,
}

impl MeshingSize {
    pub fn at(resolution: u32) -> MeshingSize {
        let r = resolution as u64;
        let coarse = 33u64.pow(3);
        let active = (r.pow(3)).min(7 * r * r);
        MeshingSize {
            batch: ((r + 1).pow(3)).min(coarse.max(40 * r * r)),
            evaluated: ((r + 1).pow(3)).min(coarse + 55 * r * r),
            active,
            triangles: 2 * active,
            expected: ((r + 1).pow(3)).min(coarse + 10 * r * r),
        }
    }

    /// Host bytes of the refinement and extraction themselves: a batch's corners and values,
    /// every evaluated corner's key and value, the active cells and the welded mesh.
    pub fn host_bytes(&self) -> u64 {
        40 * self.batch + 32 * self.evaluated + 92 * self.active + 108 * self.triangles
    }
}

/// Why extraction failed.
#[derive(Debug)]
pub enum ExtractError {
    /// The options make no sense (resolution 0, empty or non-finite domain, …).
    InvalidOptions(String),
    /// The field failed, or returned the wrong number of values.
    Field(FieldError),
    /// The GPU marching cubes failed.
    Gpu(crate::gpu::GpuError),
    /// The state machine was used out of order (a bug in the caller).
    Protocol(String),
}

impl fmt::Display for ExtractError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ExtractError::InvalidOptions(s) => write!(f, "invalid extraction options: {s}"),
            ExtractError::Field(e) => write!(f, "{e}"),
            ExtractError::Gpu(e) => write!(f, "{e}"),
            ExtractError::Protocol(s) => write!(f, "extraction protocol error: {s}"),
        }
    }
}

impl std::error::Error for ExtractError {}

impl From<FieldError> for ExtractError {
    fn from(e: FieldError) -> Self {
        ExtractError::Field(e)
    }
}

impl From<crate::gpu::GpuError> for ExtractError {
    fn from(e: crate::gpu::GpuError) -> Self {
        ExtractError::Gpu(e)
    }
}

/// The levels the search goes through.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Plan {
    /// Cells per axis of the finest grid (`ExtractOptions::resolution`).
    pub resolution: u32,
    /// Cells per axis of the coarsest grid: `resolution` halved while it stays even and the
    /// half is still at least ¾ of `ExtractOptions::coarse` (so 128 / 32 → 32, 96 / 32 → 24,
    /// 100 / 32 → 25, 96 / 20 → 24).
    pub coarse: u32,
    /// Number of refinements: `resolution = coarse << levels`.
    pub levels: u32,
}

impl Plan {
    pub fn new(opts: &ExtractOptions) -> Result<Plan, ExtractError> {
        let bad = |s: String| Err(ExtractError::InvalidOptions(s));
        if opts.resolution == 0 || opts.resolution > MAX_RESOLUTION {
            return bad(format!("resolution {} is not in 1..={MAX_RESOLUTION}", opts.resolution));
        }
        if opts.coarse == 0 {
            return bad("coarse is 0".into());
        }
        let (lo, hi) = opts.domain;
        for a in 0..3 {
            if !(lo[a].is_finite() && hi[a].is_finite() && lo[a] < hi[a]) {
                return bad(format!("domain {:?} .. {:?} is empty or not finite", lo, hi));
            }
        }
        if let Some(f) = opts.remove_small_components {
            if !(f.is_finite() && f >= 0.0) {
                return bad(format!("remove_small_components {f} is not a non-negative number"));
            }
        }
        let mut coarse = opts.resolution;
        let mut levels = 0;
        // Halved while the half is at least ¾ of `coarse`: 96 stops at 24, not at 48, whose
        // dense 49³ corners cost more than all of 128's refinement from 32 (96³ was slower than
        // 128³).
        while coarse.is_multiple_of(2) && 4 * (coarse / 2) >= 3 * opts.coarse {
            coarse /= 2;
            levels += 1;
        }
        if (coarse as u64 + 1).pow(3) > MAX_COARSE_CORNERS {
            return bad(format!(
                "the coarse grid would have {coarse}^3 cells, evaluated densely in one batch: too many \
                 (lower `coarse`)"
            ));
        }
        Ok(Plan { resolution: opts.resolution, coarse, levels })
    }
}

/// The finest-level cells the surface passes through, with their corner values: the input of
/// marching cubes (CPU: [`super::marching_cubes::polygonize`], GPU:
/// [`super::marching_cubes_gpu::polygonize_gpu`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ActiveCells {
    /// Cells per axis of the grid.
    pub resolution: u32,
    /// The domain `(min, max)`; corner `(i, j, k)` is at `min + (max - min) * (i, j, k) / resolution`.
    pub domain: ([f32; 3], [f32; 3]),
    /// Cell coordinates (its low corner), sorted by `x + R (y + R z)`.
    pub cells: Vec<[u32; 3]>,
    /// The 8 corner values of each cell, corner `c` at offset `(c & 1, c >> 1 & 1, c >> 2 & 1)`,
    /// already clamped at the domain boundary and made finite.
    pub values: Vec<[f32; 8]>,
}

impl ActiveCells {
    /// Every cell of a dense grid of values, `values[x + (R+1) (y + (R+1) z)]`, with a sign
    /// change (the values are sanitised and clamped at the boundary like the field's).
    pub fn from_dense(resolution: u32, domain: ([f32; 3], [f32; 3]), values: &[f32]) -> ActiveCells {
        let r = resolution as usize;
        let n = r + 1;
        assert_eq!(values.len(), n * n * n, "need (resolution + 1)^3 values");
        let mut out = ActiveCells { resolution, domain, cells: Vec::new(), values: Vec::new() };
        for z in 0..r {
            for y in 0..r {
                for x in 0..r {
                    let mut v = [0.0f32; 8];
                    for (c, vc) in v.iter_mut().enumerate() {
                        let (i, j, k) = (x + (c & 1), y + (c >> 1 & 1), z + (c >> 2 & 1));
                        let raw = values[i + n * (j + n * k)];
                        *vc = corner_value(raw, [i as u32, j as u32, k as u32], resolution);
                    }
                    if has_sign_change(&v) {
                        out.cells.push([x as u32, y as u32, z as u32]);
                        out.values.push(v);
                    }
                }
            }
        }
        out
    }

    pub fn len(&self) -> usize {
        self.cells.len()
    }

    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }
}

/// What the search did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RefineStats {
    pub plan_coarse: u32,
    pub levels: u32,
    /// Field evaluations made (each corner once).
    pub evaluations: u64,
    /// What a dense finest grid would have cost: `(resolution + 1)³`.
    pub dense_evaluations: u64,
    /// Batches handed to the field.
    pub batches: u32,
    /// Points per batch, in order.
    pub batch_sizes: Vec<usize>,
    /// Active cells at the finest level (after closing).
    pub active_cells: usize,
    /// Cells the closing step added (0 when the coarse levels found the whole surface).
    pub closure_cells: usize,
    /// Rounds of the closing step that needed evaluations.
    pub closure_rounds: u32,
    /// The largest raw field value met (NaN read as 0), before the boundary clamp: at or below 0
    /// everywhere means no inside anywhere, hence no surface.
    pub field_max: f32,
}

/// Value at a finest-grid corner as marching cubes sees it: finite, and `<= 0` on the boundary.
pub fn corner_value(raw: f32, at: [u32; 3], resolution: u32) -> f32 {
    let v = if raw.is_nan() { 0.0 } else { raw.clamp(-1e30, 1e30) };
    if at.iter().any(|&i| i == 0 || i == resolution) {
        v.min(0.0)
    } else {
        v
    }
}

fn has_sign_change(v: &[f32; 8]) -> bool {
    let inside = v.iter().filter(|&&x| x > 0.0).count();
    inside != 0 && inside != 8
}

/// A hasher for integer keys (SplitMix64's finaliser): the structured grid keys would collide
/// badly in the low bits under a plain multiply.
#[derive(Default)]
pub(crate) struct KeyHasher(u64);

impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        let mut z = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ b as u64).wrapping_mul(0x100_0000_01b3);
        }
    }
    fn write_u64(&mut self, i: u64) {
        self.0 = self.0.rotate_left(29) ^ i;
    }
    fn write_u32(&mut self, i: u32) {
        self.write_u64(i as u64)
    }
    fn write_usize(&mut self, i: usize) {
        self.write_u64(i as u64)
    }
}

pub(crate) type KeyMap<V> = HashMap<u64, V, BuildHasherDefault<KeyHasher>>;

#[derive(Debug)]
enum Stage {
    /// Waiting for the values of `pending`; then continue at refinement level `level`: the
    /// coarse grid (every cell) for 0, else the children of `parents` (marked cells of level
    /// `level - 1`, sorted and deduplicated).
    Level {
        level: u32,
        parents: Vec<u64>,
    },
    /// Waiting for the values of `pending` for the closing step; `cells` are the finest cells
    /// being added.
    Closure {
        cells: Vec<u64>,
    },
    Done,
}

/// Marker for a corner queued for evaluation (replaced by its value in `supply`).
const QUEUED: f32 = f32::NAN;

/// The coarse-to-fine search as a state machine: while [`Refiner::pending`] is `Some(points)`,
/// evaluate the field there and [`Refiner::supply`] the values (same order); then
/// [`Refiner::finish`] returns the active cells.
///
/// ```ignore
/// let mut r = Refiner::new(&opts)?;
/// while let Some(points) = r.pending() {
///     let values = field.eval(points)?;   // or `.await` an async evaluation
///     r.supply(&values)?;
/// }
/// let (cells, stats) = r.finish()?;
/// ```
pub struct Refiner {
    plan: Plan,
    domain: ([f32; 3], [f32; 3]),
    /// Known corner values by finest corner key `x + (R+1) (y + (R+1) z)`, already clamped
    /// ([`QUEUED`] while being evaluated).
    known: KeyMap<f32>,
    /// Keys and positions of the batch being asked for.
    pending_keys: Vec<u64>,
    pending_points: Vec<[f32; 3]>,
    stage: Stage,
    /// Active finest cells (key `x + R (y + R z)`) and their corner values.
    active: KeyMap<[f32; 8]>,
    /// The coarse lattice's values, `x + (n+1) (y + (n+1) z)`.
    coarse_values: Vec<f32>,
    stats: RefineStats,
}

impl Refiner {
    pub fn new(opts: &ExtractOptions) -> Result<Refiner, ExtractError> {
        let plan = Plan::new(opts)?;
        let r = plan.resolution as u64;
        let mut me = Refiner {
            plan,
            domain: opts.domain,
            known: KeyMap::default(),
            pending_keys: Vec::new(),
            pending_points: Vec::new(),
            stage: Stage::Level { level: 0, parents: Vec::new() },
            active: KeyMap::default(),
            coarse_values: vec![0.0; (plan.coarse as usize + 1).pow(3)],
            stats: RefineStats {
                plan_coarse: plan.coarse,
                levels: plan.levels,
                dense_evaluations: (r + 1).pow(3),
                field_max: f32::NEG_INFINITY,
                ..Default::default()
            },
        };
        // The coarse grid: every corner.
        let s = me.scale(0);
        let n = plan.coarse;
        me.known.reserve(((n + 1) as usize).pow(3) * 4);
        for z in 0..=n {
            for y in 0..=n {
                for x in 0..=n {
                    me.ask([x * s, y * s, z * s]);
                }
            }
        }
        Ok(me)
    }

    pub fn plan(&self) -> Plan {
        self.plan
    }

    /// The points whose values are needed next, or `None` when the search is done.
    pub fn pending(&self) -> Option<&[[f32; 3]]> {
        match self.stage {
            Stage::Done => None,
            _ => Some(&self.pending_points),
        }
    }

    /// Gives the values of the points [`Refiner::pending`] returned, in the same order, and
    /// runs the search up to the next batch it needs.
    pub fn supply(&mut self, values: &[f32]) -> Result<(), ExtractError> {
        if matches!(self.stage, Stage::Done) {
            return Err(ExtractError::Protocol("supply() after the search finished".into()));
        }
        if values.len() != self.pending_keys.len() {
            return Err(ExtractError::Field(FieldError(format!(
                "the field returned {} values for {} points",
                values.len(),
                self.pending_keys.len()
            ))));
        }
        let keys = std::mem::take(&mut self.pending_keys);
        self.pending_points.clear();
        let coarse = matches!(self.stage, Stage::Level { level: 0, .. });
        for (i, (&k, &v)) in keys.iter().zip(values).enumerate() {
            if !v.is_nan() {
                self.stats.field_max = self.stats.field_max.max(v);
            }
            let at = self.unkey_corner(k);
            let v = corner_value(v, at, self.plan.resolution);
            self.known.insert(k, v);
            if coarse {
                self.coarse_values[i] = v; // the coarse batch is the whole lattice, x fastest
            }
        }
        self.stats.evaluations += keys.len() as u64;
        self.stats.batches += 1;
        self.stats.batch_sizes.push(keys.len());
        self.advance();
        Ok(())
    }

    /// The active cells and statistics, once [`Refiner::pending`] is `None`.
    pub fn finish(self) -> Result<(ActiveCells, RefineStats), ExtractError> {
        if !matches!(self.stage, Stage::Done) {
            return Err(ExtractError::Protocol("finish() before the search is done".into()));
        }
        let r = self.plan.resolution as u64;
        let mut cells: Vec<(u64, [f32; 8])> = self.active.into_iter().collect();
        cells.sort_unstable_by_key(|c| c.0);
        let out = ActiveCells {
            resolution: self.plan.resolution,
            domain: self.domain,
            cells: cells.iter().map(|&(k, _)| [(k % r) as u32, (k / r % r) as u32, (k / (r * r)) as u32]).collect(),
            values: cells.into_iter().map(|(_, v)| v).collect(),
        };
        let mut stats = self.stats;
        stats.active_cells = out.cells.len();
        Ok((out, stats))
    }

    // -----------------------------------------------------------------------------------------

    /// Finest-grid units per cell at `level`.
    fn scale(&self, level: u32) -> u32 {
        1 << (self.plan.levels - level)
    }

    fn cells_at(&self, level: u32) -> u32 {
        self.plan.coarse << level
    }

    fn key_corner(&self, at: [u32; 3]) -> u64 {
        let n = self.plan.resolution as u64 + 1;
        at[0] as u64 + n * (at[1] as u64 + n * at[2] as u64)
    }

    fn unkey_corner(&self, k: u64) -> [u32; 3] {
        let n = self.plan.resolution as u64 + 1;
        [(k % n) as u32, (k / n % n) as u32, (k / (n * n)) as u32]
    }

    /// Position of a finest-grid corner (same formula as marching cubes uses).
    fn position(&self, at: [u32; 3]) -> [f32; 3] {
        let (lo, hi) = self.domain;
        let r = self.plan.resolution as f32;
        std::array::from_fn(|a| lo[a] + (hi[a] - lo[a]) * (at[a] as f32 / r))
    }

    /// Queues a corner (finest coordinates) for evaluation unless known or queued.
    fn ask(&mut self, at: [u32; 3]) {
        let k = self.key_corner(at);
        if let std::collections::hash_map::Entry::Vacant(e) = self.known.entry(k) {
            e.insert(QUEUED);
            self.pending_keys.push(k);
            let p = self.position(at);
            self.pending_points.push(p);
        }
    }

    /// Fills `out` with the values at the `m³` corners `origin + step * (i, j, k)`, `i, j, k`
    /// in `0..m` (index `i + m (j + m k)`), in finest coordinates; false if one is unknown.
    fn lattice(&self, origin: [u32; 3], step: u32, m: u32, out: &mut [f32]) -> bool {
        let mut idx = 0;
        for k in 0..m {
            for j in 0..m {
                for i in 0..m {
                    let at = [origin[0] + i * step, origin[1] + j * step, origin[2] + k * step];
                    match self.known.get(&self.key_corner(at)) {
                        Some(&v) => out[idx] = v,
                        None => return false,
                    }
                    idx += 1;
                }
            }
        }
        true
    }

    fn cell_values(&self, level: u32, c: [u32; 3]) -> Option<[f32; 8]> {
        let s = self.scale(level);
        let mut v = [0.0f32; 8];
        self.lattice(c.map(|x| x * s), s, 2, &mut v).then_some(v)
    }

    fn key_cell(&self, level: u32, c: [u32; 3]) -> u64 {
        let n = self.cells_at(level) as u64;
        c[0] as u64 + n * (c[1] as u64 + n * c[2] as u64)
    }

    fn unkey_cell(&self, level: u32, k: u64) -> [u32; 3] {
        let n = self.cells_at(level) as u64;
        [(k % n) as u32, (k / n % n) as u32, (k / (n * n)) as u32]
    }

    /// Runs the search after a batch arrived, until it needs another batch or is done.
    fn advance(&mut self) {
        loop {
            match std::mem::replace(&mut self.stage, Stage::Done) {
                Stage::Done => return,
                Stage::Level { level, parents } => {
                    // The cells of this level with a sign change, and their values.
                    let mut changing: Vec<(u64, [f32; 8])> = Vec::new();
                    if level == 0 {
                        let n = self.plan.coarse;
                        let m = n as usize + 1;
                        let lat = std::mem::take(&mut self.coarse_values);
                        for z in 0..n {
                            for y in 0..n {
                                for x in 0..n {
                                    let v: [f32; 8] = std::array::from_fn(|c| {
                                        let (i, j, k) = (
                                            x as usize + (c & 1),
                                            y as usize + (c >> 1 & 1),
                                            z as usize + (c >> 2 & 1),
                                        );
                                        lat[i + m * (j + m * k)]
                                    });
                                    if has_sign_change(&v) {
                                        changing.push((self.key_cell(0, [x, y, z]), v));
                                    }
                                }
                            }
                        }
                    } else {
                        // Each parent's 3x3x3 corners at this level's spacing cover its children.
                        let s = self.scale(level);
                        let mut lat = [0.0f32; 27];
                        for &pk in &parents {
                            let p = self.unkey_cell(level - 1, pk);
                            let known = self.lattice(p.map(|x| x * 2 * s), s, 3, &mut lat);
                            assert!(known, "the children's corners were asked for");
                            for i in 0..8u32 {
                                let (dx, dy, dz) = (i & 1, i >> 1 & 1, i >> 2 & 1);
                                let v: [f32; 8] = std::array::from_fn(|c| {
                                    let c = c as u32;
                                    let (x, y, z) = (dx + (c & 1), dy + (c >> 1 & 1), dz + (c >> 2 & 1));
                                    lat[(x + 3 * (y + 3 * z)) as usize]
                                });
                                if has_sign_change(&v) {
                                    let child = [2 * p[0] + dx, 2 * p[1] + dy, 2 * p[2] + dz];
                                    changing.push((self.key_cell(level, child), v));
                                }
                            }
                        }
                    }
                    if level == self.plan.levels {
                        let frontier: Vec<u64> = changing.iter().map(|c| c.0).collect();
                        self.active.extend(changing);
                        self.start_closure(frontier);
                    } else {
                        let keys: Vec<u64> = changing.iter().map(|c| c.0).collect();
                        // The coarse level's cells are dilated (see the module's step 2); later
                        // levels refine only their own sign changes: the closing step completes
                        // every component they touch, at half the evaluations (issue 27).
                        let marked = if level == 0 {
                            self.dilate(level, &keys)
                        } else {
                            let mut k = keys;
                            k.sort_unstable();
                            k
                        };
                        // The children's corners: each marked cell's 3x3x3 lattice one level down.
                        let s = self.scale(level + 1);
                        for &k in &marked {
                            let c = self.unkey_cell(level, k);
                            for z in 0..3 {
                                for y in 0..3 {
                                    for x in 0..3 {
                                        self.ask([(2 * c[0] + x) * s, (2 * c[1] + y) * s, (2 * c[2] + z) * s]);
                                    }
                                }
                            }
                        }
                        self.stage = Stage::Level { level: level + 1, parents: marked };
                    }
                }
                Stage::Closure { cells } => {
                    // The added cells have a face with a sign change, so they are active.
                    let mut added = Vec::with_capacity(cells.len());
                    for k in cells {
                        let c = self.unkey_cell(self.plan.levels, k);
                        let v = self.cell_values(self.plan.levels, c).expect("closing cells are known");
                        debug_assert!(has_sign_change(&v));
                        if self.active.insert(k, v).is_none() {
                            added.push(k);
                        }
                    }
                    self.stats.closure_cells += added.len();
                    self.start_closure(added);
                }
            }
            if !self.pending_keys.is_empty() || matches!(self.stage, Stage::Done) {
                return;
            }
        }
    }
    /// The cells of `level` within one cell (26-neighbourhood) of `cells`, sorted.
    fn dilate(&self, level: u32, cells: &[u64]) -> Vec<u64> {
        let n = self.cells_at(level) as i64;
        let mut out = Vec::with_capacity(cells.len() * 8);
        for &k in cells {
            let c = self.unkey_cell(level, k);
            for dz in -1i64..=1 {
                for dy in -1i64..=1 {
                    for dx in -1i64..=1 {
                        let q = [c[0] as i64 + dx, c[1] as i64 + dy, c[2] as i64 + dz];
                        if q.iter().all(|&x| (0..n).contains(&x)) {
                            out.push(self.key_cell(level, [q[0] as u32, q[1] as u32, q[2] as u32]));
                        }
                    }
                }
            }
        }
        out.sort_unstable();
        out.dedup();
        out
    }

    /// From `frontier` (newly active finest cells), finds the neighbours across faces with a
    /// sign change that are not active yet, and queues their unknown corners; the stage
    /// becomes `Closure` with those cells, or `Done` when there are none.
    fn start_closure(&mut self, frontier: Vec<u64>) {
        let level = self.plan.levels;
        let r = self.plan.resolution as i64;
        let mut next: Vec<u64> = Vec::new();
        for k in frontier {
            let c = self.unkey_cell(level, k);
            let v = self.active[&k];
            for a in 0..3usize {
                for side in 0..2usize {
                    // Corners of the face: bit a == side.
                    let mut inside = 0;
                    for (i, &x) in v.iter().enumerate() {
                        if (i >> a) & 1 == side && x > 0.0 {
                            inside += 1;
                        }
                    }
                    if inside == 0 || inside == 4 {
                        continue;
                    }
                    let mut q = [c[0] as i64, c[1] as i64, c[2] as i64];
                    q[a] += if side == 1 { 1 } else { -1 };
                    if !(0..r).contains(&q[a]) {
                        continue; // cannot happen: boundary faces are all outside
                    }
                    let qk = self.key_cell(level, [q[0] as u32, q[1] as u32, q[2] as u32]);
                    if !self.active.contains_key(&qk) {
                        next.push(qk);
                    }
                }
            }
        }
        next.sort_unstable();
        next.dedup();
        if next.is_empty() {
            self.stage = Stage::Done;
            return;
        }
        let s = self.scale(level);
        for &k in &next {
            let c = self.unkey_cell(level, k);
            for i in 0..8u32 {
                self.ask([(c[0] + (i & 1)) * s, (c[1] + (i >> 1 & 1)) * s, (c[2] + (i >> 2 & 1)) * s]);
            }
        }
        if !self.pending_keys.is_empty() {
            self.stats.closure_rounds += 1;
        }
        self.stage = Stage::Closure { cells: next };
    }
}
