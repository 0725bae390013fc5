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
    /// The share of the mesh's area removed, where [`trim_between_sheets`] computed it (else 0).
    pub area_share: f32,
}

impl TrimReport {
    /// What the reconstruction tells the user after a trim by `factor`.
    pub fn notice(&self, factor: f32) -> String {
        format!(
            "trimmed {} triangles farther than {factor} x the point spacing from the input (the cloud's mean, wider where the points are sparser)",
            self.triangles_removed
        )
    }

    /// What the reconstruction tells the user after [`open_kept`].
    pub fn opened_notice(&self) -> String {
        format!(
            "opened the Poisson surface: {} triangles farther than {DEFAULT_TRIM} x the point spacing from the input (wider where the points are sparser) \
             or over {OUTSIDE_HULL} mean spacings outside the points' hull",
            self.triangles_removed
        )
    }

    /// What the reconstruction tells the user after [`trim_between_sheets`] (nothing when
    /// nothing went).
    pub fn between_sheets_notice(&self, factor: f32, depth: f32) -> Option<String> {
        (self.triangles_removed > 0).then(|| {
            format!(
                "opened {} triangles ({:.1} % of the area) farther than {factor} x the point spacing from the input and over {depth} mean spacings inside the points' hull: \
                 the fill the prior put between sheets of points (an open shell: a bowl, a car body), not a side the scan missed; the mesh is not \
                 watertight (--trim opens every part far from the points; --surface poisson meshes the Poisson surface)",
                self.triangles_removed,
                100.0 * self.area_share
            )
        })
    }
}

/// Drops every triangle whose centroid is farther than `factor` × the point spacing of `points`
/// ([`LocalSpacing`]: the mean nearest-neighbour spacing, wider where they are sparser) from the
/// nearest of them, then the vertices no triangle uses any more
/// (the rest keep their order; normals and colours follow). `mesh` and `points` must be in the
/// same coordinates. A `factor` that is not positive and finite, or fewer than two distinct
/// points, removes nothing.
pub fn trim(mesh: &mut Mesh, points: &[[f32; 3]], factor: f32) -> TrimReport {
    let near = near_triangles(&mesh.positions, &mesh.indices, points, factor);
    drop_far(mesh, near)
}

fn drop_far(mesh: &mut Mesh, near: NearTriangles) -> TrimReport {
    let mut report = TrimReport { spacing: near.spacing, threshold: near.threshold, ..Default::default() };
    if let Some(keep) = near.keep {
        report.triangles_removed = keep.iter().filter(|&&k| !k).count();
        report.vertices_removed = retain_triangles(mesh, &keep);
    }
    report
}

/// How deep inside the points' convex hull, in mean point spacings, a triangle far from every
/// point must lie for [`trim_between_sheets`] to drop it. A scanner sees the outside of an
/// object, so the sides a one-sided scan missed lie behind what it saw, at the rim of the
/// points' hull or beyond it: the prior's guess of them stays (it lowers the error there,
/// docs/poisson.md "Open shells"). Deep inside the hull and far from every point lies what the
/// prior, trained on solids, put between sheets of points: the fill of a bowl, of an open box,
/// of a shell's arches. Chosen on the tuning shapes' one-sided clouds (cow, fandisk, suzanne)
/// and open shells made for it (`scripts/thin_clouds.py`: bowl, open box, shell with windows,
/// half tube; 3k and 10k), by the mean CD1 x100 one-sided / shells, on the finished meshes (a
/// 2000-plane hull):
///
/// | rule | one-sided | shells |
/// |---|---|---|
/// | nothing opened (before) | 4.167 | 0.763 |
/// | every far part (`--trim 3`) | 4.381 | 0.384 |
/// | deeper than 0, 1, 2 spacings | 4.318, 4.325, 4.326 | 0.386, 0.385, 0.386 |
/// | **deeper than 3 spacings** | **4.160** | **0.388** |
/// | deeper than 4, 5, 6 spacings | 4.161, 4.163, 4.135 | 0.392, 0.407, 0.432 |
///
/// (The one-sided scans' closures that a shallower rule takes lie just behind the rim of the
/// scanned sheet, where the hull is thin.)
pub const BETWEEN_SHEETS_DEPTH: f32 = 3.0;

/// Directions of the support planes that stand for the points' convex hull ([`Hull`]).
const HULL_DIRECTIONS: usize = 2048;

/// The convex hull of points as the support planes of [`HULL_DIRECTIONS`] directions spread
/// evenly over the sphere (a Fibonacci lattice): a polytope around the hull, which stands out
/// from a flat face of the hull by up to about sin 2.3° (the farthest a face's normal is from a
/// lattice direction) times the face's extent: 1-2 % of the points' extent, what
/// [`BETWEEN_SHEETS_DEPTH`] was chosen with.
struct Hull {
    directions: Vec<[f32; 3]>,
    support: Vec<f32>,
}

impl Hull {
    fn of(points: &[[f32; 3]]) -> Hull {
        let golden = (1.0 + 5f64.sqrt()) / 2.0;
        let directions: Vec<[f32; 3]> = (0..HULL_DIRECTIONS)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / HULL_DIRECTIONS as f64;
                let r = (1.0 - z * z).sqrt();
                let t = std::f64::consts::TAU * i as f64 / golden;
                [r * t.cos(), r * t.sin(), z].map(|c| c as f32)
            })
            .collect();
        let support = crate::par::map_ranges(HULL_DIRECTIONS, |range| {
            range.map(|k| points.iter().map(|p| dot(*p, directions[k])).fold(f32::NEG_INFINITY, f32::max)).collect()
        });
        Hull { directions, support }
    }

    /// How far inside the hull `p` lies (negative: outside).
    fn depth(&self, p: [f32; 3]) -> f32 {
        self.directions.iter().zip(&self.support).map(|(d, s)| s - dot(p, *d)).fold(f32::INFINITY, f32::min)
    }
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The least share of a small cloud's mesh area that the fill between sheets must have for
/// [`trim_between_sheets`] to open it, where the field's level set is the surface because the
/// cloud is under [`crate::plan::POISSON_POINTS`] (no Poisson surface ballooned to say the scan
/// is open; measured when that was 2,000). A closed
/// object's mesh there has a few triangles far from its sparse points and deep inside their hull
/// (9 of the 18 eval clouds at 500, 1k and 1,500 points, at most 1.0 % of the area: opening them
/// would only make the mesh not watertight), an open shell's fill is a large part of it (bowl
/// 10-13 %, open box 14-16 %, `scripts/thin_clouds.py`; the beetle of
/// common-3d-test-models at 500 points 8.9 %). Chosen between the two on those shells and the
/// eval clouds (docs/poisson.md, "Below 2,000 points too").
pub const SPARSE_BETWEEN_SHEETS_SHARE: f32 = 0.05;

/// [`trim`] by `factor`, of only the triangles whose centroid also lies deeper than `depth` mean
/// point spacings inside the points' convex hull ([`BETWEEN_SHEETS_DEPTH`]): opens the fill
/// between sheets of points and keeps a closure behind them. Nothing goes where what would go
/// is less than `min_share` of the mesh's area ([`SPARSE_BETWEEN_SHEETS_SHARE`]; 0: any).
pub fn trim_between_sheets(mesh: &mut Mesh, points: &[[f32; 3]], factor: f32, depth: f32, min_share: f32) -> TrimReport {
    let reach = Reach::of(points);
    let mut near = reach.near_triangles(&mesh.positions, &mesh.indices, factor);
    if let Some(keep) = near.keep.as_mut() {
        let n = mesh.positions.len();
        let far: Vec<usize> = (0..keep.len()).filter(|&t| !keep[t] && mesh.indices[3 * t..3 * t + 3].iter().all(|&i| (i as usize) < n)).collect();
        if !far.is_empty() {
            let hull = reach.hull();
            let inside = depth * near.spacing;
            let shallow = crate::par::map_ranges(far.len(), |range| {
                range.map(|f| hull.depth(centroid(&mesh.positions, &mesh.indices[3 * far[f]..3 * far[f] + 3])) <= inside).collect()
            });
            far.iter().zip(shallow).for_each(|(&t, stays)| keep[t] = stays);
        }
    }
    // Too small a share of the mesh to be an open shell's fill: nothing goes.
    let share = near.keep.as_ref().map_or(0.0, |keep| dropped_area_share(mesh, keep) as f32);
    if share < min_share {
        near.keep = None;
    }
    TrimReport { area_share: if near.keep.is_some() { share } else { 0.0 }, ..drop_far(mesh, near) }
}

/// The share of `mesh`'s area in the triangles `t` that `keep[t]` drops (0 for no area;
/// triangles whose indices are out of range count for nothing): what a trim by [`NearTriangles`]
/// would take, and the Poisson surface's far share ([`crate::poisson::far_share`]).
pub fn dropped_area_share(mesh: &Mesh, keep: &[bool]) -> f64 {
    let (mut dropped, mut all) = (0.0f64, 0.0f64);
    for (t, &kept) in mesh.indices.chunks_exact(3).zip(keep) {
        let Some(area) = triangle_area(&mesh.positions, t) else { continue };
        all += area;
        if !kept {
            dropped += area;
        }
    }
    if all > 0.0 { dropped / all } else { 0.0 }
}

/// The area of triangle `t` (three indices into `positions`), in f64; None when an index is out
/// of range.
fn triangle_area(positions: &[[f32; 3]], t: &[u32]) -> Option<f64> {
    let [a, b, c] = [t[0], t[1], t[2]].map(|i| positions.get(i as usize).map(|p| glam::DVec3::from(p.map(f64::from))));
    Some(0.5 * (b? - a?).cross(c? - a?).length())
}

/// Per triangle of `indices` (into `positions`), its centroid's distance to the nearest point of
/// `index` and that point; None where an index is out of range. The triangles split over the
/// cores.
fn centroid_distances(positions: &[[f32; 3]], indices: &[u32], index: &PointIndex) -> Vec<Option<(f32, u32)>> {
    let triangles: Vec<&[u32]> = indices.chunks_exact(3).collect();
    crate::par::map_ranges(triangles.len(), |range| {
        let mut near = Vec::with_capacity(1);
        triangles[range]
            .iter()
            .map(|t| {
                let [a, b, c] = [t[0], t[1], t[2]].map(|i| positions.get(i as usize).copied());
                let (a, b, c) = (a?, b?, c?);
                index.k_nearest([0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0), 1, &mut near);
                near.first().map(|&(d2, j)| (d2.sqrt(), j))
            })
            .collect()
    })
}

/// How far from each point "far" begins, in units of the cloud's mean nearest-neighbour spacing:
/// 1 where the points are as dense as the cloud's mean or denser, and where they are sparser
/// the point's own spacing over the mean (its distance to its [`LocalSpacing::RANK`]-th
/// neighbour, over the cloud's mean of it).
///
/// Why: a scan's density falls with the distance from the scanner, and where one part was seen
/// from far its points lie several mean spacings apart. Measured against the mean alone, the
/// surface between them was "far from every point": the balloon guard took the sparse end for an
/// unseen side and the trims opened it (issue 26: a density falling 500 times along the object,
/// or a sparse half 55 times sparser than the other, came back with that end in shreds).
///
/// The point's own distance, not the mean of its neighbours' (session 26): where a sparse part
/// is a few points beside dense ones (a far half of about 18 points at 1,000), a sparse point's
/// nearest are mostly dense points, and their mean read it as dense (scale 1 at 8 of 12 sparse
/// points on stanford-bunny's far half): the balloon guard then took that half for a balloon.
/// The noise of one point's distance stays under [`LocalSpacing::RIM`]: the eval, harder, thin
/// and other clouds gave the same meshes either way (docs/poisson.md, "Uneven density").
pub struct LocalSpacing {
    /// The cloud's mean nearest-neighbour spacing ([`mean_spacing`]).
    pub mean: f32,
    /// Per point, at least 1.
    scale: Vec<f32>,
}

impl LocalSpacing {
    /// The neighbour whose distance measures a point's own spacing (as the fit's sparse reach).
    const RANK: usize = 4;
    /// Taken off the ratio before it counts: where a scan ends (a rim, the opening of a cup) half
    /// a point's neighbours are missing and its spacing reads about 1.4 times the mean, and one
    /// point's distance is noisy: up to 2.0 on the even eval and thin clouds, 2.25 along spot cut
    /// in half, 2.6 at the rim of a one-sided scan, which is not sparser points. From 2.5 times
    /// the mean up it counts, less this (1.0 while the ratio was the mean of 8 points' distances,
    /// which stayed under 1.75 on those clouds).
    const RIM: f64 = 1.5;

    /// Over `index`, an index of exactly `points`.
    pub fn of(points: &[[f32; 3]], index: &PointIndex) -> LocalSpacing {
        let mut d = crate::sample::neighbour_distances_in(points, index, &[1, Self::RANK]);
        let by_rank = d.pop().unwrap_or_default();
        let mean = crate::sample::mean_spacing_of(&d.pop().unwrap_or_default());
        let mean_rank = by_rank.iter().map(|&x| x as f64).sum::<f64>() / by_rank.len().max(1) as f64;
        if !(mean_rank > 0.0) {
            return LocalSpacing { mean, scale: vec![1.0; points.len()] };
        }
        let scale = by_rank.iter().map(|&own| (own as f64 / mean_rank - Self::RIM).max(1.0) as f32).collect();
        LocalSpacing { mean, scale }
    }

    /// Point `j`'s spacing over the cloud's mean (at least 1).
    pub fn scale(&self, j: u32) -> f32 {
        self.scale.get(j as usize).copied().unwrap_or(1.0)
    }
}

/// Which triangles [`trim`] keeps, without changing the mesh (the page's live trim uses it too).
pub struct NearTriangles {
    pub spacing: f32,
    pub threshold: f32,
    /// Per triangle: its centroid is within `threshold` of a point (and its indices are in
    /// range). None when the threshold is not positive and finite: nothing is to be removed.
    pub keep: Option<Vec<bool>>,
    /// The triangles within reach of a point that `keep` drops as lying too far outside the
    /// points' hull ([`Reach::near_inside_hull`]; empty otherwise).
    pub outside_hull: Vec<usize>,
}

/// The triangles (`indices` into `positions`) whose centroid lies within `factor` × the point
/// spacing ([`LocalSpacing`]: the cloud's mean, wider where the points are sparser) of the
/// nearest of `points`.
pub fn near_triangles(positions: &[[f32; 3]], indices: &[u32], points: &[[f32; 3]], factor: f32) -> NearTriangles {
    if !(factor > 0.0 && factor.is_finite()) {
        let spacing = mean_spacing(points);
        return NearTriangles { spacing, threshold: factor * spacing, keep: None, outside_hull: Vec::new() };
    }
    Reach::of(points).near_triangles(positions, indices, factor)
}

/// How far outside the points' convex hull ([`Hull`]), in mean point spacings, a Poisson surface
/// that the balloon guard keeps counts as far from the points wherever it is
/// ([`crate::poisson::Balloon::check`]), and is opened there.
///
/// Why: where a part of the points is sparse (a far side seen from afar), a point's own spacing
/// lets the surface lie several mean spacings from it ([`LocalSpacing`]), and a slab the solve
/// hangs beside those points (suzanne's ear on the sparse side of a step in density) is then as
/// "near" as the surface between them. Beyond the hull it is not between them: a scanner sees
/// an object's outside, so a surface it carries lies inside the hull of what it saw, the sides a
/// one-sided scan missed included, which close behind its rim. Measured on 43 Poisson surfaces
/// (Python, a 2000-plane hull, docs/poisson.md "Beyond the points' hull"): the area farther than
/// 8 mean spacings outside it is 0.158 of suzanne's 3k step and 0.092 of fandisk's, 0-0.018 on
/// every other step cloud and 0 on the even, falling and cup clouds. It counts for the guard's
/// trigger and the opening, not for its one-sided verdict ([`crate::poisson::ballooned`]: counted
/// there too, suzanne's step went to the field's level set, CD1 x100 5.1 against 1.4).
pub const OUTSIDE_HULL: f32 = 8.0;

/// The points as "far from them" is measured: their index and their own spacing
/// ([`LocalSpacing`]), made once where more than one mesh is measured against the same points
/// (the balloon guard measures the Poisson surface and the field's mesh), and their hull when
/// asked ([`Reach::near_inside_hull`]).
pub struct Reach<'a> {
    points: &'a [[f32; 3]],
    index: PointIndex<'a>,
    local: LocalSpacing,
    hull: std::cell::OnceCell<Hull>,
}

impl<'a> Reach<'a> {
    pub fn of(points: &'a [[f32; 3]]) -> Reach<'a> {
        let index = PointIndex::new(points);
        let local = LocalSpacing::of(points, &index);
        Reach { points, index, local, hull: std::cell::OnceCell::new() }
    }

    /// How many points.
    pub fn len(&self) -> usize {
        self.local.scale.len()
    }

    /// [`near_triangles`] against these points.
    pub fn near_triangles(&self, positions: &[[f32; 3]], indices: &[u32], factor: f32) -> NearTriangles {
        self.near(positions, indices, factor, None, false)
    }

    /// [`Self::near_triangles`], less the triangles whose centroid lies more than `outside` mean
    /// spacings outside the points' convex hull ([`OUTSIDE_HULL`]).
    pub fn near_inside_hull(&self, positions: &[[f32; 3]], indices: &[u32], factor: f32, outside: f32) -> NearTriangles {
        self.near(positions, indices, factor, Some(outside), false)
    }

    /// Keeps, of the triangles `keep` drops, those within `threshold` × its spacing of one of the
    /// [`SPARSE_REACH_NEAREST`] nearest points sparser than the mean (which says why).
    fn reach_of_sparse_points(&self, positions: &[[f32; 3]], indices: &[u32], threshold: f32, keep: &mut [bool], distances: &[Option<(f32, u32)>]) {
        let sparse: Vec<u32> = (0..self.len() as u32).filter(|&j| self.local.scale(j) > 1.0).collect();
        let dropped: Vec<usize> = (0..keep.len()).filter(|&t| !keep[t] && distances[t].is_some()).collect();
        if sparse.is_empty() || dropped.is_empty() {
            return;
        }
        let at: Vec<[f32; 3]> = sparse.iter().map(|&j| self.points[j as usize]).collect();
        let (index, local) = (PointIndex::new(&at), &self.local);
        let reached = crate::par::map_ranges(dropped.len(), |range| {
            let mut near = Vec::with_capacity(SPARSE_REACH_NEAREST);
            range
                .map(|d| {
                    index.k_nearest(centroid(positions, &indices[3 * dropped[d]..3 * dropped[d] + 3]), SPARSE_REACH_NEAREST, &mut near);
                    near.iter().any(|&(d2, i)| d2.sqrt() <= threshold * local.scale(sparse[i as usize]))
                })
                .collect()
        });
        dropped.iter().zip(reached).for_each(|(&t, r): (&usize, bool)| keep[t] = r);
    }

    /// The points' hull, made on first use.
    fn hull(&self) -> &Hull {
        self.hull.get_or_init(|| Hull::of(self.points))
    }

    /// Near: within `factor` × its spacing of the nearest point, or with `sparse_reach` of any
    /// of the [`SPARSE_REACH_NEAREST`] nearest points sparser than the mean; and with `outside`,
    /// not that many mean spacings outside the hull.
    fn near(&self, positions: &[[f32; 3]], indices: &[u32], factor: f32, outside: Option<f32>, sparse_reach: bool) -> NearTriangles {
        let (spacing, threshold) = (self.local.mean, factor * self.local.mean);
        if !(threshold > 0.0 && threshold.is_finite()) {
            return NearTriangles { spacing, threshold, keep: None, outside_hull: Vec::new() };
        }
        let distances = centroid_distances(positions, indices, &self.index);
        let mut keep: Vec<bool> = distances.iter().map(|d| d.is_some_and(|(d, j)| d <= threshold * self.local.scale(j))).collect();
        if sparse_reach {
            self.reach_of_sparse_points(positions, indices, threshold, &mut keep, &distances);
        }
        let mut outside_hull = Vec::new();
        if let Some(outside) = outside.map(|o| o * spacing).filter(|o| o.is_finite()) {
            // Only a centroid farther than that from every point can lie that far outside their
            // hull, which holds them all: the hull's 2048 planes are tried on those alone.
            let beyond: Vec<usize> = (0..keep.len()).filter(|&t| keep[t] && distances[t].is_some_and(|(d, _)| d > outside)).collect();
            if !beyond.is_empty() {
                let hull = self.hull();
                let out: Vec<bool> = crate::par::map_ranges(beyond.len(), |range| {
                    range.map(|b| hull.depth(centroid(positions, &indices[3 * beyond[b]..3 * beyond[b] + 3])) < -outside).collect()
                });
                outside_hull = beyond.into_iter().zip(out).filter_map(|(t, out)| out.then_some(t)).collect();
                outside_hull.iter().for_each(|&t| keep[t] = false);
            }
        }
        NearTriangles { spacing, threshold, keep: Some(keep), outside_hull }
    }
}

/// The centroid of triangle `t` (three indices into `positions`, in range).
fn centroid(positions: &[[f32; 3]], t: &[u32]) -> [f32; 3] {
    let [a, b, c] = [t[0], t[1], t[2]].map(|i| positions[i as usize]);
    [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0)
}

/// How many of the points sparser than the mean ([`LocalSpacing`] over 1) the opening of a kept
/// Poisson surface ([`open_kept`]) tries for a triangle that the nearest point does not reach.
///
/// Why: a point's spacing reaches only as far as it is the nearest point. Where the density
/// steps, the surface between the last dense points and the first sparse ones is nearest to
/// dense points, farther than 3 mean spacings from them, and within a sparse point's own reach:
/// measured by the nearest point alone, the opening cut a crack along the step (suzanne's step at
/// 3k, teapot's at 1k in the page; docs/poisson.md "Beyond the points' hull"). The sparse points'
/// own reach closes it. Only for the opening: counted in the guard's share too, fandisk's step
/// at 3k was no longer opened (CD1 x100 1.33 -> 2.11). The nearest 8 sparse points, not every
/// point whose reach might cover the triangle: a bounded search, and where the density steps the
/// nearest sparse points are the ones whose reach spans the gap.
const SPARSE_REACH_NEAREST: usize = 8;

/// Opens a Poisson surface that the balloon guard kept ([`crate::poisson::Balloon::Kept`]):
/// drops the triangles farther than [`DEFAULT_TRIM`] point spacings ([`LocalSpacing`]) from
/// every point (the nearest point's, or one of the [`SPARSE_REACH_NEAREST`] nearest sparse
/// points'), and those more than [`OUTSIDE_HULL`] mean spacings outside the points' hull, where
/// the guard counted them far too.
pub fn open_kept(mesh: &mut Mesh, reach: &Reach) -> TrimReport {
    let near = reach.near(&mesh.positions, &mesh.indices, DEFAULT_TRIM, Some(OUTSIDE_HULL), true);
    drop_far(mesh, near)
}

/// How near `mesh` comes to `points`: their mean distance to its nearest vertex (0 for a mesh
/// without vertices or no points). Where a tuned field thinned a sheet of points through,
/// leaving holes, its mesh is farther from them than the network's (docs/poisson.md, "Open
/// shells").
pub fn reach(mesh: &Mesh, points: &[[f32; 3]]) -> f64 {
    if mesh.positions.is_empty() || points.is_empty() {
        return 0.0;
    }
    let index = PointIndex::new(&mesh.positions);
    let sums = crate::par::map_ranges(points.len(), |range| {
        let mut scratch = Vec::new();
        vec![range.map(|i| index.nearest_distance(points[i], &mut scratch) as f64).sum::<f64>()]
    });
    sums.iter().sum::<f64>() / points.len() as f64
}

/// The other way: the mean distance of `mesh`'s surface to the nearest of `points`,
/// area-weighted over its triangles' centroids (0 for a mesh without triangles or no points).
/// A fill that no point carries (a cup or a shell filled with foam, a lid) moves it by its share
/// of the area.
pub fn surface_distance(mesh: &Mesh, points: &[[f32; 3]]) -> f64 {
    if points.is_empty() {
        return 0.0;
    }
    let distances = centroid_distances(&mesh.positions, &mesh.indices, &PointIndex::new(points));
    let (mut area, mut weighted) = (0.0f64, 0.0f64);
    for (t, d) in mesh.indices.chunks_exact(3).zip(distances) {
        if let (Some(w), Some((d, _))) = (triangle_area(&mesh.positions, t), d) {
            area += w;
            weighted += w * d as f64;
        }
    }
    if area > 0.0 {
        weighted / area
    } else {
        0.0
    }
}

/// What the run says when it keeps the network's mesh over the tuned field's
/// ([`super::finish::Closure::distance`]).
pub fn farther_notice(tuned: f64, network: f64) -> String {
    format!(
        "the tuned field's mesh lies {:.0} % farther from the points than the network's (holes where it thinned a sheet, or a fill no point \
         carries): the network's mesh is kept (--method network makes it directly)",
        100.0 * (tuned / network - 1.0)
    )
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

    /// Points on z = 0: dense over x in [0, 1], 25 times sparser over [1, 2], none beyond; a
    /// mesh of the plane over [0, 3] (cells 0.05). The sparse half's surface is near its points
    /// though several mean spacings from them; beyond them it is far. An even sheet's spacing is
    /// the mean's everywhere, its edge included.
    #[test]
    fn far_follows_the_points_own_spacing() {
        let mut rng = crate::rng::SplitMix64(4);
        let mut points: Vec<[f32; 3]> = (0..2500).map(|_| [rng.unit() as f32, rng.unit() as f32, 0.0]).collect();
        points.extend((0..100).map(|_| [1.0 + rng.unit() as f32, rng.unit() as f32, 0.0]));
        let (nx, ny) = (60u32, 20u32);
        let positions: Vec<[f32; 3]> = (0..=ny).flat_map(|j| (0..=nx).map(move |i| [i as f32 * 0.05, j as f32 * 0.05, 0.0])).collect();
        let mut indices = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                let v = j * (nx + 1) + i;
                indices.extend_from_slice(&[v, v + 1, v + nx + 2, v, v + nx + 2, v + nx + 1]);
            }
        }
        let near = near_triangles(&positions, &indices, &points, DEFAULT_TRIM);
        let keep = near.keep.unwrap();
        let share = |lo: f32, hi: f32| {
            let (mut kept, mut all) = (0, 0);
            for (t, &k) in indices.chunks_exact(3).zip(&keep) {
                let x = (positions[t[0] as usize][0] + positions[t[1] as usize][0] + positions[t[2] as usize][0]) / 3.0;
                if x > lo && x < hi {
                    all += 1;
                    kept += k as usize;
                }
            }
            kept as f64 / all as f64
        };
        // The mean spacing alone (3 x about 0.01) left most of the sparse half's cells far.
        let mean_alone = indices
            .chunks_exact(3)
            .filter(|t| positions[t[0] as usize][0] > 1.05 && positions[t[0] as usize][0] < 1.95)
            .filter(|t| {
                let c = [0, 1, 2].map(|k| (positions[t[0] as usize][k] + positions[t[1] as usize][k] + positions[t[2] as usize][k]) / 3.0);
                points.iter().map(|p| (0..3).map(|k| (p[k] - c[k]).powi(2)).sum::<f32>()).fold(f32::INFINITY, f32::min).sqrt() <= near.threshold
            })
            .count();
        // (720 triangles lie over the sparse half.)
        assert!(mean_alone < 360, "the set-up: {mean_alone} of 720 sparse-half triangles near by the mean alone");
        assert!(share(0.05, 0.95) == 1.0 && share(1.05, 1.95) > 0.85, "{} {}", share(0.05, 0.95), share(1.05, 1.95));
        assert_eq!(share(2.4, 3.0), 0.0);
        let even: Vec<[f32; 3]> = (0..=30).flat_map(|i| (0..=30).map(move |j| [i as f32 * 0.1, j as f32 * 0.1, 0.0])).collect();
        let spacing = LocalSpacing::of(&even, &PointIndex::new(&even));
        assert!((0..even.len() as u32).all(|j| spacing.scale(j) == 1.0));
        // A sparse part of a few points beside the dense ones: their nearest are mostly dense
        // points, but their own spacing is theirs (the mean of their neighbours' read 1).
        let mut few = points[..2500].to_vec();
        few.extend([[1.3f32, 0.2, 0.0], [1.3, 0.7, 0.0], [1.7, 0.45, 0.0], [1.95, 0.1, 0.0], [1.95, 0.9, 0.0]]);
        let spacing = LocalSpacing::of(&few, &PointIndex::new(&few));
        assert!((2500..few.len() as u32).all(|j| spacing.scale(j) > 10.0), "{:?}", (2500..few.len() as u32).map(|j| spacing.scale(j)).collect::<Vec<_>>());
    }

    /// The cloud of [`far_follows_the_points_own_spacing`] (dense over x in [0, 1], sparse over
    /// [1, 2], on z = 0) and two sheets over the sparse half: one on the points, one lifted 0.16
    /// (15 mean spacings) off them, as a slab a Poisson solve hangs beside sparse points. The
    /// sparse points' own spacing lets both be near (by 8 spacings); outside the points' hull
    /// (their plane; the lattice's polytope stands out from it by up to 2 % of its width, 0.04)
    /// the slab is not, and the guard's opening takes it.
    #[test]
    fn a_slab_beside_sparse_points_is_far_outside_their_hull() {
        let mut rng = crate::rng::SplitMix64(4);
        let mut points: Vec<[f32; 3]> = (0..2500).map(|_| [rng.unit() as f32, rng.unit() as f32, 0.0]).collect();
        points.extend((0..100).map(|_| [1.0 + rng.unit() as f32, rng.unit() as f32, 0.0]));
        let n = 18u32;
        let sheet = |z: f32| (0..=n).flat_map(move |j| (0..=n).map(move |i| [1.05 + 0.05 * i as f32, 0.05 + 0.05 * j as f32, z]));
        let mut positions: Vec<[f32; 3]> = sheet(0.0).collect();
        positions.extend(sheet(0.16));
        let mut indices = Vec::new();
        for s in 0..2 {
            for j in 0..n {
                for i in 0..n {
                    let v = s * (n + 1) * (n + 1) + j * (n + 1) + i;
                    indices.extend_from_slice(&[v, v + 1, v + n + 2, v, v + n + 2, v + n + 1]);
                }
            }
        }
        let reach = Reach::of(&points);
        assert!(0.16 - 0.04 > OUTSIDE_HULL * reach.local.mean, "the set-up: the slab lies {} mean spacings off", 0.16 / reach.local.mean);
        let per_sheet = (n * n * 2) as usize;
        let kept = |keep: &[bool], s: usize| keep[s * per_sheet..(s + 1) * per_sheet].iter().filter(|&&k| k).count() as f64 / per_sheet as f64;
        let near = reach.near_triangles(&positions, &indices, 8.0).keep.unwrap();
        let inside = reach.near_inside_hull(&positions, &indices, 8.0, OUTSIDE_HULL).keep.unwrap();
        assert!(kept(&near, 1) > 0.5, "the set-up: {} of the slab near by the sparse points' spacing", kept(&near, 1));
        assert_eq!(kept(&inside, 1), 0.0, "the slab, outside the hull");
        assert!(kept(&near, 0) > 0.85 && kept(&inside, 0) == kept(&near, 0), "the sheet on the points: {} {}", kept(&near, 0), kept(&inside, 0));
        // Nearer the plane than the rule's depth, the slab stays where it is near.
        let low: Vec<[f32; 3]> = positions.iter().map(|p| [p[0], p[1], p[2].min(0.5 * OUTSIDE_HULL * reach.local.mean)]).collect();
        assert_eq!(reach.near_inside_hull(&low, &indices, 8.0, OUTSIDE_HULL).keep, reach.near_triangles(&low, &indices, 8.0).keep);
        // The opening takes the slab and keeps the sheet on the points.
        let mut mesh = Mesh { normals: vec![[0.0, 0.0, 1.0]; positions.len()], colors: None, indices, positions };
        let r = open_kept(&mut mesh, &Reach::of(&points));
        assert!(r.triangles_removed >= per_sheet && mesh.positions.iter().all(|p| p[2] == 0.0), "{r:?}");
        assert!(r.opened_notice().contains(&format!("opened the Poisson surface: {} triangles", r.triangles_removed)));
    }

    /// Where the density steps: a grid of points 0.01 apart over x in [0, 1], one 0.1 apart over
    /// [1.1, 2] (z = 0), and a sheet on them over [0.5, 1.5]. Between the last dense column and
    /// the first sparse one the sheet is nearest to dense points and farther than 3 mean
    /// spacings from them: `trim` (the nearest point's spacing alone) cuts a crack there; the
    /// opening of a kept Poisson surface counts the sparse points' own reach and keeps it whole.
    #[test]
    fn the_opening_keeps_the_surface_where_the_density_steps() {
        let mut points: Vec<[f32; 3]> = (0..=100).flat_map(|i| (0..=100).map(move |j| [0.01 * i as f32, 0.01 * j as f32, 0.0])).collect();
        points.extend((0..10).flat_map(|i| (0..=10).map(move |j| [1.1 + 0.1 * i as f32, 0.1 * j as f32, 0.0])));
        let n = 40u32;
        let positions: Vec<[f32; 3]> = (0..=n).flat_map(|j| (0..=n).map(move |i| [0.5 + 0.025 * i as f32, 0.025 * j as f32, 0.0])).collect();
        let mut indices = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let v = j * (n + 1) + i;
                indices.extend_from_slice(&[v, v + 1, v + n + 2, v, v + n + 2, v + n + 1]);
            }
        }
        let mesh = Mesh { normals: vec![[0.0, 0.0, 1.0]; positions.len()], colors: None, indices, positions };
        let mut trimmed = mesh.clone();
        let t = trim(&mut trimmed, &points, DEFAULT_TRIM);
        assert!(t.triangles_removed > 0, "the set-up: trim cut nothing");
        // What trim cuts lies in the band between the two grids.
        let key = |m: &Mesh, t: &[u32]| centroid(&m.positions, t).map(|c| (c * 1e5).round() as i64);
        let left: std::collections::HashSet<[i64; 3]> = trimmed.indices.chunks_exact(3).map(|t| key(&trimmed, t)).collect();
        let gone: Vec<f32> = mesh.indices.chunks_exact(3).filter(|t| !left.contains(&key(&mesh, t))).map(|t| centroid(&mesh.positions, t)[0]).collect();
        assert!(gone.len() == t.triangles_removed && gone.iter().all(|&x| x > 1.0 && x < 1.1), "{gone:?}");
        let mut opened = mesh.clone();
        let r = open_kept(&mut opened, &Reach::of(&points));
        assert_eq!((r.triangles_removed, &opened.indices), (0, &mesh.indices), "the opening keeps the band");
    }

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

    /// `reach`: the points' mean distance to the nearest vertex; `surface_distance`: the
    /// mesh's area-weighted mean distance (at the centroids) to the nearest point.
    #[test]
    fn reach_and_surface_distance_are_the_two_sides() {
        let mesh = Mesh { positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], normals: vec![], colors: None, indices: vec![0, 1, 2] };
        let points = [[0.0, 0.0, 0.5], [1.0, 0.0, -0.25], [0.0, 1.0, 0.0]];
        assert!((reach(&mesh, &points) - 0.25).abs() < 1e-9);
        // The centroid (1/3, 1/3, 0) is nearest to the first point.
        assert!((surface_distance(&mesh, &points) - (2.0f64 / 9.0 + 0.25).sqrt()).abs() < 1e-6, "{}", surface_distance(&mesh, &points));
        for empty in [reach(&mesh, &[]), reach(&Mesh::default(), &points), surface_distance(&mesh, &[]), surface_distance(&Mesh::default(), &points)] {
            assert_eq!(empty, 0.0);
        }
    }

    /// A lid far from every point (a filled cup's) leaves the points' side as it was and moves
    /// the mesh's side by its share of the area. Triangles are weighed by their area, not
    /// counted.
    #[test]
    fn a_lid_no_point_carries_makes_the_mesh_farther() {
        let points: Vec<[f32; 3]> = (0..=10).flat_map(|i| (0..=10).map(move |j| [i as f32 * 0.1, j as f32 * 0.1, 0.0])).collect();
        let floor = Mesh { positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]], normals: vec![], colors: None, indices: vec![0, 1, 2, 0, 2, 3] };
        let mut lidded = floor.clone();
        lidded.positions.extend([[0.0, 0.0, 0.5], [1.0, 0.0, 0.5], [1.0, 1.0, 0.5], [0.0, 1.0, 0.5]]);
        lidded.indices.extend([4, 5, 6, 4, 6, 7]);
        assert_eq!(reach(&floor, &points), reach(&lidded, &points));
        let (open, closed) = (surface_distance(&floor, &points), surface_distance(&lidded, &points));
        assert!((closed - 0.5 * (open + 0.5)).abs() < 0.01, "{open} vs {closed}");
        // Split one triangle of the floor into many small ones: the same surface, the same value.
        let mut fine = floor.clone();
        fine.indices.truncate(3);
        let n = fine.positions.len() as u32;
        fine.positions.push([1.0 / 3.0, 2.0 / 3.0, 0.0]);
        fine.indices.extend([0, 2, n, 2, 3, n, 3, 0, n]);
        assert!((surface_distance(&fine, &points) - open).abs() < 0.01, "{} vs {open}", surface_distance(&fine, &points));
    }

    /// Points on a bowl (the lower half of a unit sphere: a sheet, open at the top). A square
    /// across its middle is far from them and deep inside their hull (the prior's fill of an
    /// open shell): it goes. A square as far from them above the rim is outside their hull (a
    /// closure behind what was seen, as a one-sided scan's): it stays, as does a square on the
    /// bowl's floor. `trim` drops both far squares.
    #[test]
    fn the_fill_between_sheets_goes_and_a_closure_outside_the_hull_stays() {
        let mut points = Vec::new();
        for i in 0..40 {
            for j in 0..80 {
                let (theta, phi) = (std::f32::consts::FRAC_PI_2 * (i as f32 + 0.5) / 40.0, std::f32::consts::TAU * j as f32 / 80.0);
                points.push([theta.sin() * phi.cos(), theta.sin() * phi.sin(), -theta.cos()]);
            }
        }
        let square = |z: f32, r: f32| [[-r, -r, z], [r, -r, z], [r, r, z], [-r, r, z]];
        let mut positions = square(-0.5, 0.1).to_vec(); // the fill: 0.5 from the floor, 0.5 inside the rim
        positions.extend_from_slice(&square(0.5, 0.1)); // a closure: 0.5 above the rim's plane
        positions.extend_from_slice(&square(-0.99, 0.05)); // on the floor
        let indices: Vec<u32> = (0..3).flat_map(|s| [0, 1, 2, 0, 2, 3].map(|i| 4 * s + i)).collect();
        let mesh = Mesh { normals: vec![[0.0, 0.0, 1.0]; 12], colors: None, indices, positions };
        let spacing = mean_spacing(&points);
        assert!(0.5 > 3.0 * spacing && 0.5 > BETWEEN_SHEETS_DEPTH * spacing, "{spacing}");
        let mut between = mesh.clone();
        let r = trim_between_sheets(&mut between, &points, DEFAULT_TRIM, BETWEEN_SHEETS_DEPTH, 0.0);
        assert_eq!((r.triangles_removed, r.vertices_removed), (2, 4), "{r:?}");
        assert_eq!(between.positions, mesh.positions[4..].to_vec(), "the closure and the floor stay");
        assert!(r.between_sheets_notice(DEFAULT_TRIM, BETWEEN_SHEETS_DEPTH).unwrap().contains("opened 2 triangles (44.4 % of the area)"));
        // The fill is 0.04 of the 0.09 in all: a least share above that keeps it, one below opens it.
        let mut kept = mesh.clone();
        let r = trim_between_sheets(&mut kept, &points, DEFAULT_TRIM, BETWEEN_SHEETS_DEPTH, 0.5);
        assert_eq!((r.triangles_removed, r.area_share, &kept.positions), (0, 0.0, &mesh.positions), "{r:?}");
        assert!(r.between_sheets_notice(DEFAULT_TRIM, BETWEEN_SHEETS_DEPTH).is_none());
        let mut opened = mesh.clone();
        assert_eq!(trim_between_sheets(&mut opened, &points, DEFAULT_TRIM, BETWEEN_SHEETS_DEPTH, 0.4).triangles_removed, 2);
        let mut all = mesh.clone();
        assert_eq!(trim(&mut all, &points, DEFAULT_TRIM).triangles_removed, 4);
        // The hull's depth: the distance to the nearest face inside (here the rim's plane), negative outside.
        let hull = Hull::of(&points);
        let rim = points.iter().map(|p| p[2]).fold(f32::NEG_INFINITY, f32::max);
        let (inside, outside) = (hull.depth([0.0, 0.0, -0.5]), hull.depth([0.0, 0.0, 0.5]));
        // (The lattice's polytope stands out from the rim's flat face by up to 2 % of the
        // bowl's width, 2.)
        assert!(inside >= rim + 0.5 && inside < rim + 0.5 + 0.04, "{inside} {rim}");
        assert!(outside >= rim - 0.5 && outside < rim - 0.5 + 0.04, "{outside} {rim}");
    }
}
