//! Training pairs for the kernel regression (paper eq. 6, Algorithm 1; method.md §2).
//!
//! Around every input point p the regression gets one extra point p~ = p + N(0, σ_p² I), with
//! σ_p the distance from p to its k-th nearest input neighbour, as Neural-Pull samples its
//! queries: dense regions get tight offsets, sparse ones wide, so the pseudo-labels l(p~) cover a
//! band around the surface whose width follows the sampling density rather than a fixed scale.

use std::collections::HashSet;

use crate::rng::SplitMix64;

/// Default neighbour rank for σ_p (Neural-Pull uses about 50).
pub const DEFAULT_K: usize = 50;

/// Distance from each point to its k-th nearest other point (k clamped to n - 1). Exact: a
/// uniform grid searched in growing rings, stopping once no unvisited cell can hold a closer
/// point. Points must be finite.
pub fn kth_neighbour_distance(points: &[[f32; 3]], k: usize) -> Vec<f32> {
    neighbour_distances(points, &[k]).pop().unwrap_or_default()
}

/// [`kth_neighbour_distance`] for each of the ranks `ks` (each clamped to n - 1), from one
/// search for the largest.
pub fn neighbour_distances(points: &[[f32; 3]], ks: &[usize]) -> Vec<Vec<f32>> {
    neighbour_distances_in(points, &PointIndex::new(points), ks)
}

/// [`neighbour_distances`] over `index`, an index of exactly `points`, for a caller that has one.
pub fn neighbour_distances_in(points: &[[f32; 3]], index: &PointIndex, ks: &[usize]) -> Vec<Vec<f32>> {
    let n = points.len();
    if n < 2 {
        return vec![vec![0.0; n]; ks.len()];
    }
    let ks: Vec<usize> = ks.iter().map(|&k| k.clamp(1, n - 1)).collect();
    let k = ks.iter().copied().max().unwrap_or(1);
    // For each point, its distance to each rank in turn; the points split over the cores. The
    // k + 1 nearest hold the point itself (at distance 0) unless more than k duplicates of it
    // come first, and either way the k nearest others.
    let flat: Vec<f32> = crate::par::map_ranges(n, |range| {
        let mut near = Vec::with_capacity(k + 1);
        let mut others: Vec<f32> = Vec::with_capacity(k + 1); // squared distances, ascending
        let mut out = Vec::with_capacity(range.len() * ks.len());
        for i in range {
            index.k_nearest(points[i], k + 1, &mut near);
            others.clear();
            others.extend(near.iter().filter(|&&(_, j)| j as usize != i).map(|&(d2, _)| d2));
            out.extend(ks.iter().map(|&kr| others.get(kr - 1).copied().unwrap_or(0.0).sqrt()));
        }
        out
    });
    (0..ks.len()).map(|r| flat.iter().skip(r).step_by(ks.len()).copied().collect()).collect()
}

/// How the extra points P~ are drawn around the input points (see [`upsample`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Offsets {
    /// Neighbour rank whose distance σ_p scales the offsets (the paper's, via Neural-Pull).
    pub k: usize,
    /// A second, finer rank: every other extra point is offset by this neighbour's distance
    /// instead. `None`: one scale (the paper).
    pub near_k: Option<usize>,
    /// Extra points per input point (the paper: 1).
    pub per_point: usize,
}

impl Offsets {
    /// The paper's: one extra point per input point at the `k`-th neighbour's distance.
    pub fn paper(k: usize) -> Offsets {
        Offsets { k, near_k: None, per_point: 1 }
    }

    /// Extra points per input point so that `n` points get at least `least` of them, at most
    /// [`MAX_PER_POINT`]; `None` (or a dense cloud): one.
    pub fn per_point_for(n: usize, least: Option<usize>) -> usize {
        least.map_or(1, |l| l.div_ceil(n.max(1)).clamp(1, MAX_PER_POINT))
    }
}

/// The most extra points drawn around one input point: beyond it a sparse cloud's pairs
/// repeat the same few logits at a growing cost.
pub const MAX_PER_POINT: usize = 16;

/// The extra points P~: `per_point` around each input point (all of point 0's first, then
/// point 1's, …), each offset by a Gaussian of that point's k-th-neighbour distance, or, for
/// every other one when `near_k` is set, of its `near_k`-th. Why two scales: on a sparse cloud
/// the k-th neighbour is a sizeable part of the object, so the pairs land far from the surface
/// and carry little about where it is; the near ones pin the field's slope at the surface.
/// Seeded, so a reconstruction repeats.
pub fn upsample(points: &[[f32; 3]], offsets: &Offsets, seed: u64) -> Vec<[f32; 3]> {
    // One neighbour search for both scales.
    let mut ranks = neighbour_distances(points, &[Some(offsets.k), offsets.near_k].into_iter().flatten().collect::<Vec<_>>());
    let near = offsets.near_k.and_then(|_| ranks.pop());
    let far = ranks.pop().unwrap_or_default();
    let mut rng = SplitMix64(seed);
    let mut out = Vec::with_capacity(points.len() * offsets.per_point);
    for (i, p) in points.iter().enumerate() {
        for j in 0..offsets.per_point {
            let s = match &near {
                Some(near) if j % 2 == 1 || (offsets.per_point == 1 && i % 2 == 1) => near[i],
                _ => far[i],
            };
            out.push([0, 1, 2].map(|a| p[a] + (s as f64 * rng.normal()) as f32));
        }
    }
    out
}

thread_local! {
    /// [`PointIndex::k_nearest`]'s candidates, one list a thread: (key, index).
    static CANDIDATES: std::cell::RefCell<Vec<(u64, u32)>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Exact k-nearest-neighbour queries against a fixed set of points (the same grid search as
/// [`kth_neighbour_distance`]); queries may lie anywhere, inside the points' bounds or not.
pub struct PointIndex<'a> {
    points: &'a [[f32; 3]],
    grid: Grid,
}

impl<'a> PointIndex<'a> {
    /// Indexes `points` (finite; may be empty, then every query finds nothing).
    pub fn new(points: &'a [[f32; 3]]) -> PointIndex<'a> {
        PointIndex { points, grid: Grid::new(points) }
    }

    /// The `k` points nearest to `q` as (squared distance, index), nearest first, ties in the
    /// order the search met them. Fewer when there are fewer than `k` points.
    ///
    /// The candidates of each ring go into a list that is cut back to the `k` nearest by a
    /// selection at the ring's end; a list kept sorted as they come moved most of itself on
    /// every insertion, which at the stray-point filter's 101 neighbours was a quarter of a
    /// 100k-point reconstruction's time. Each candidate's key is its squared distance's bits
    /// (ordered like the distances: they are never negative) above its visit number, so the
    /// result is exactly the sorted list's, ties included.
    pub fn k_nearest(&self, q: [f32; 3], k: usize, out: &mut Vec<(f32, u32)>) {
        out.clear();
        let k = k.min(self.points.len());
        if k == 0 {
            return;
        }
        CANDIDATES.with_borrow_mut(|found| {
            found.clear();
            let c = self.grid.cell_of(&q);
            let (mut visited, mut worst) = (0u64, u64::MAX);
            let mut ring = 0i64;
            loop {
                self.grid.for_ring(c, ring, |j| {
                    let p = self.points[j as usize];
                    let d2 = (0..3).map(|a| (p[a] - q[a]) * (p[a] - q[a])).sum::<f32>();
                    let key = (u64::from(d2.to_bits()) << 32) | visited;
                    visited += 1;
                    if key < worst {
                        found.push((key, j));
                    }
                });
                if found.len() >= k {
                    found.select_nth_unstable(k - 1);
                    found.truncate(k);
                    worst = found[k - 1].0;
                }
                // Cells beyond this ring are at least `ring * h` from q (also when q lies
                // outside the grid and its cell was clamped: it is then farther still).
                let reach = ring as f32 * self.grid.h;
                let kth = f32::from_bits((worst >> 32) as u32);
                if (found.len() == k && kth <= reach * reach) || ring > self.grid.max_ring() {
                    break;
                }
                ring += 1;
            }
            found.sort_unstable();
            out.extend(found.iter().map(|&(key, j)| (f32::from_bits((key >> 32) as u32), j)));
        });
    }

    /// Distance from `q` to the nearest point (infinite when there are none).
    pub fn nearest_distance(&self, q: [f32; 3], scratch: &mut Vec<(f32, u32)>) -> f32 {
        self.k_nearest(q, 1, scratch);
        scratch.first().map_or(f32::INFINITY, |&(d2, _)| d2.sqrt())
    }
}

/// Mean distance from each point to its nearest other point, over the points that have one at
/// a non-zero distance (exact duplicates would otherwise pull the spacing towards zero); 0 when
/// there is none.
pub fn mean_spacing(points: &[[f32; 3]]) -> f32 {
    mean_spacing_of(&kth_neighbour_distance(points, 1))
}

/// [`mean_spacing`] from the points' nearest-neighbour distances `d`, for a caller that found
/// them in a search for other ranks too ([`neighbour_distances`]).
pub fn mean_spacing_of(d: &[f32]) -> f32 {
    let (sum, n) = d.iter().filter(|&&x| x > 0.0).fold((0.0f64, 0usize), |(s, n), &x| (s + x as f64, n + 1));
    if n == 0 {
        0.0
    } else {
        (sum / n as f64) as f32
    }
}

/// Points bucketed in a uniform grid (counting sort into CSR order).
struct Grid {
    min: [f32; 3],
    h: f32,
    dims: [i64; 3],
    start: Vec<u32>,
    items: Vec<u32>,
}

impl Grid {
    fn new(points: &[[f32; 3]]) -> Grid {
        let mut min = [f32::INFINITY; 3];
        let mut max = [f32::NEG_INFINITY; 3];
        for p in points {
            for a in 0..3 {
                min[a] = min[a].min(p[a]);
                max[a] = max[a].max(p[a]);
            }
        }
        let extent = (0..3).map(|a| max[a] - min[a]).fold(0.0f32, f32::max).max(1e-30);
        // About two points per cell if they filled the box; surfaces fill far fewer cells, so
        // occupied cells hold more, which is what a k-NN search with k ~ 50 wants.
        let per_axis = ((points.len() as f64 / 2.0).cbrt().ceil() as i64).clamp(1, 256);
        let h = surface_cell(points, min, max, extent / per_axis as f32);
        // (At least one cell: an empty cloud's box is inverted.)
        let dims = [0, 1, 2].map(|a| (((max[a] - min[a]) / h) as i64 + 1).clamp(1, 1 << 22));
        let mut grid = Grid { min, h, dims, start: Vec::new(), items: Vec::new() };
        let cells = (dims[0] * dims[1] * dims[2]) as usize;
        let ids: Vec<usize> = points.iter().map(|p| grid.index(grid.cell_of(p))).collect();
        let mut start = vec![0u32; cells + 1];
        for &c in &ids {
            start[c + 1] += 1;
        }
        for c in 0..cells {
            start[c + 1] += start[c];
        }
        let mut fill = start.clone();
        let mut items = vec![0u32; points.len()];
        for (i, &c) in ids.iter().enumerate() {
            items[fill[c] as usize] = i as u32;
            fill[c] += 1;
        }
        grid.start = start;
        grid.items = items;
        grid
    }

    fn cell_of(&self, p: &[f32; 3]) -> [i64; 3] {
        [0, 1, 2].map(|a| (((p[a] - self.min[a]) / self.h) as i64).clamp(0, self.dims[a] - 1))
    }

    fn index(&self, c: [i64; 3]) -> usize {
        ((c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]) as usize
    }

    fn max_ring(&self) -> i64 {
        self.dims.iter().copied().max().unwrap_or(1)
    }

    /// Calls `f` with every point in the cells at Chebyshev distance exactly `r` from `c`.
    fn for_ring(&self, c: [i64; 3], r: i64, mut f: impl FnMut(u32)) {
        let lo = [0, 1, 2].map(|a| (c[a] - r).max(0));
        let hi = [0, 1, 2].map(|a| (c[a] + r).min(self.dims[a] - 1));
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                let on_shell_yz = (z - c[2]).abs() == r || (y - c[1]).abs() == r;
                let mut x = lo[0];
                while x <= hi[0] {
                    if on_shell_yz || (x - c[0]).abs() == r {
                        let k = self.index([x, y, z]);
                        for &i in &self.items[self.start[k] as usize..self.start[k + 1] as usize] {
                            f(i);
                        }
                    }
                    // Inside the shell only the two end cells of a row are on it.
                    x = if on_shell_yz || x >= c[0] + r { x + 1 } else { c[0] + r };
                }
            }
        }
    }
}

/// Points per occupied cell beyond which the volume's cell is refined ([`surface_cell`]): an
/// object's cloud stays well below it (its cells as before), a scene's surfaces in their large
/// box far above (a street's 3M mesh centroids: hundreds a cell).
const CROWDED: f64 = 32.0;

/// Points per occupied cell that a refined cell aims at: a 3 × 3 × 3 search around a surface
/// point then holds about k ~ 50 points.
const SURFACE_PER_CELL: f64 = 8.0;

/// The grid's cell: `h` (sized as if the points filled their box), or, when the points crowd
/// into few of its cells (surfaces in a large box: a street, a room's mesh), finer by the
/// square root of the crowding (points on a surface per cell go as h²), but never so fine that
/// the grid holds more than four cells a point (or 2M): its offsets are an array over every
/// cell of the box.
fn surface_cell(points: &[[f32; 3]], min: [f32; 3], max: [f32; 3], h: f32) -> f32 {
    let n = points.len();
    let occupied: HashSet<[i64; 3]> = points.iter().map(|p| [0, 1, 2].map(|a| ((p[a] - min[a]) / h) as i64)).collect();
    let crowding = n as f64 / occupied.len().max(1) as f64;
    if crowding <= CROWDED {
        return h;
    }
    let cells = |h: f32| (0..3).map(|a| ((max[a] - min[a]) / h) as f64 + 1.0).product::<f64>();
    let most = (4 * n).max(1 << 21) as f64;
    let mut fine = h * (SURFACE_PER_CELL / crowding).sqrt() as f32;
    while cells(fine) > most {
        fine *= 1.1;
    }
    fine.min(h)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(points: &[[f32; 3]], k: usize) -> Vec<f32> {
        points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let mut d: Vec<f32> = points
                    .iter()
                    .enumerate()
                    .filter(|&(j, _)| j != i)
                    .map(|(_, q)| (0..3).map(|a| (p[a] - q[a]) * (p[a] - q[a])).sum::<f32>())
                    .collect();
                d.sort_by(f32::total_cmp);
                d[k.min(d.len()) - 1].sqrt()
            })
            .collect()
    }

    fn sphere_cloud(n: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut r = SplitMix64(seed);
        (0..n)
            .map(|_| {
                let v = [r.normal(), r.normal(), r.normal()];
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                v.map(|x| (0.4 * x / l) as f32)
            })
            .collect()
    }

    #[test]
    fn knn_matches_brute_force() {
        for (n, k, seed) in [(2, 1, 1), (10, 50, 2), (500, 1, 3), (2000, 50, 4), (1500, 7, 5)] {
            let pts = sphere_cloud(n, seed);
            assert_eq!(kth_neighbour_distance(&pts, k), brute(&pts, k), "n={n} k={k}");
        }
        // Clusters with empty space between them, and duplicates.
        let mut pts = sphere_cloud(300, 6);
        pts.extend(sphere_cloud(300, 7).iter().map(|p| [p[0] * 0.01 + 5.0, p[1] * 0.01, p[2]]));
        pts.extend(vec![[1.0, 1.0, 1.0]; 20]);
        assert_eq!(kth_neighbour_distance(&pts, 30), brute(&pts, 30));
    }

    #[test]
    fn point_index_matches_brute_force_inside_and_outside_the_bounds() {
        let pts = sphere_cloud(3000, 11);
        let index = PointIndex::new(&pts);
        let mut r = SplitMix64(12);
        let mut got = Vec::new();
        for q in 0..300 {
            // Half near the sphere, half anywhere in a box three times its size.
            let s = if q % 2 == 0 { 0.5 } else { 1.5 };
            let p = [0, 1, 2].map(|_| (s * (2.0 * r.unit() - 1.0)) as f32);
            for k in [1, 8, 40] {
                index.k_nearest(p, k, &mut got);
                let mut d: Vec<f32> =
                    pts.iter().map(|x| (0..3).map(|a| (p[a] - x[a]) * (p[a] - x[a])).sum::<f32>()).collect();
                d.sort_by(f32::total_cmp);
                let got_d: Vec<f32> = got.iter().map(|&(d2, _)| d2).collect();
                assert_eq!(got_d, d[..k], "q={p:?} k={k}");
                for &(d2, j) in &got {
                    let x = pts[j as usize];
                    assert_eq!(d2, (0..3).map(|a| (p[a] - x[a]) * (p[a] - x[a])).sum::<f32>());
                }
            }
        }
        index.k_nearest([0.0; 3], 5000, &mut got);
        assert_eq!(got.len(), 3000);
        let empty: Vec<[f32; 3]> = Vec::new();
        assert_eq!(PointIndex::new(&empty).nearest_distance([0.0; 3], &mut got), f32::INFINITY);
        assert_eq!(mean_spacing(&[[0.0; 3], [0.0; 3], [1.0, 0.0, 0.0], [3.0, 0.0, 0.0]]), (1.0 + 2.0) / 2.0);
    }

    /// The list kept sorted as candidates come (the search before the selection replaced it):
    /// what [`PointIndex::k_nearest`] must give, ties in the order met included.
    fn k_nearest_by_insertion(index: &PointIndex, q: [f32; 3], k: usize) -> Vec<(f32, u32)> {
        let mut out: Vec<(f32, u32)> = Vec::new();
        let k = k.min(index.points.len());
        let c = index.grid.cell_of(&q);
        let mut ring = 0i64;
        loop {
            index.grid.for_ring(c, ring, |j| {
                let p = index.points[j as usize];
                let d2 = (0..3).map(|a| (p[a] - q[a]) * (p[a] - q[a])).sum::<f32>();
                if out.len() < k || d2 < out[k - 1].0 {
                    let at = out.partition_point(|&(b, _)| b <= d2);
                    out.insert(at, (d2, j));
                    out.truncate(k);
                }
            });
            let reach = ring as f32 * index.grid.h;
            if (out.len() == k && out[k - 1].0 <= reach * reach) || ring > index.grid.max_ring() {
                return out;
            }
            ring += 1;
        }
    }

    #[test]
    fn k_nearest_keeps_ties_in_the_order_met() {
        // A lattice with duplicates: most distances tie, some at exactly zero.
        let mut pts: Vec<[f32; 3]> = Vec::new();
        for i in 0..12 {
            for j in 0..12 {
                for l in 0..6 {
                    pts.push([i as f32 * 0.1, j as f32 * 0.1, l as f32 * 0.1]);
                }
            }
        }
        pts.extend(pts[..200].to_vec());
        let index = PointIndex::new(&pts);
        let mut got = Vec::new();
        let mut r = SplitMix64(5);
        for q in 0..200 {
            let p = if q % 2 == 0 { pts[q * 5] } else { [0, 1, 2].map(|_| (1.4 * r.unit() - 0.2) as f32) };
            for k in [1, 6, 27, 101] {
                index.k_nearest(p, k, &mut got);
                assert_eq!(got, k_nearest_by_insertion(&index, p, k), "q={p:?} k={k}");
            }
        }
    }

    #[test]
    fn surfaces_in_a_large_box_get_finer_cells_and_the_same_neighbours() {
        // A street's ground and one facade: 60k points on 40 x 20 m and 40 x 12 m, in a box
        // 40 x 20 x 12 m that they fill little of.
        let mut r = SplitMix64(21);
        let mut pts: Vec<[f32; 3]> = (0..40_000).map(|_| [(40.0 * r.unit()) as f32, (20.0 * r.unit()) as f32, 0.0]).collect();
        pts.extend((0..20_000).map(|_| [(40.0 * r.unit()) as f32, 20.0, (12.0 * r.unit()) as f32]));
        let volume_h = 40.0 / (30_000f64.cbrt().ceil() as f32);
        let grid = Grid::new(&pts);
        let occupied: HashSet<usize> = pts.iter().map(|p| grid.index(grid.cell_of(p))).collect();
        let per_cell = pts.len() as f64 / occupied.len() as f64;
        assert!(grid.h < 0.5 * volume_h && per_cell < 2.0 * SURFACE_PER_CELL, "cell {} m (volume's {volume_h}), {per_cell:.1} points a cell", grid.h);
        assert!((grid.dims.iter().product::<i64>() as usize) <= (4 * pts.len()).max(1 << 21));
        let index = PointIndex::new(&pts);
        let mut got = Vec::new();
        for q in 0..200 {
            let p = if q % 2 == 0 { pts[q * 97] } else { [(50.0 * r.unit() - 5.0) as f32, (30.0 * r.unit() - 5.0) as f32, (20.0 * r.unit() - 4.0) as f32] };
            index.k_nearest(p, 24, &mut got);
            let mut d: Vec<f32> = pts.iter().map(|x| (0..3).map(|a| (p[a] - x[a]) * (p[a] - x[a])).sum::<f32>()).collect();
            d.sort_by(f32::total_cmp);
            assert_eq!(got.iter().map(|&(d2, _)| d2).collect::<Vec<_>>(), d[..24], "q={p:?}");
        }
        // An object's cloud keeps the volume's cell (its neighbours as before).
        let sphere = sphere_cloud(10_000, 22);
        let extent = (0..3).map(|a| sphere.iter().map(|p| p[a]).fold(f32::MIN, f32::max) - sphere.iter().map(|p| p[a]).fold(f32::MAX, f32::min)).fold(0.0, f32::max);
        assert_eq!(Grid::new(&sphere).h, extent / 5_000f64.cbrt().ceil() as f32, "the sphere's cell changed");
    }

    #[test]
    fn upsample_offsets_scale_with_local_spacing() {
        let pts = sphere_cloud(4000, 8);
        let sigma = kth_neighbour_distance(&pts, DEFAULT_K);
        let extra = upsample(&pts, &Offsets::paper(DEFAULT_K), 9);
        assert_eq!(extra.len(), pts.len());
        // The offsets' RMS per axis is σ: check the pooled normalised offsets have unit variance.
        let mut s2 = 0.0f64;
        for ((p, q), s) in pts.iter().zip(&extra).zip(&sigma) {
            for a in 0..3 {
                s2 += ((q[a] - p[a]) as f64 / *s as f64).powi(2);
            }
        }
        let var = s2 / (3.0 * pts.len() as f64);
        assert!((var - 1.0).abs() < 0.05, "{var}");
        assert_eq!(upsample(&pts, &Offsets::paper(DEFAULT_K), 9), extra, "seeded");
    }

    #[test]
    fn sparse_clouds_get_several_extra_points_at_two_scales() {
        let pts = sphere_cloud(300, 3);
        assert_eq!(Offsets::per_point_for(300, Some(4000)), 14);
        assert_eq!(Offsets::per_point_for(300, Some(100_000)), MAX_PER_POINT);
        assert_eq!(Offsets::per_point_for(10_000, Some(4000)), 1);
        assert_eq!(Offsets::per_point_for(300, None), 1);
        let offsets = Offsets { k: DEFAULT_K, near_k: Some(5), per_point: 4 };
        let extra = upsample(&pts, &offsets, 9);
        assert_eq!(extra.len(), 4 * pts.len());
        let far = kth_neighbour_distance(&pts, DEFAULT_K);
        let near = kth_neighbour_distance(&pts, 5);
        // Each point's extras come in order: even ones at the far scale, odd ones at the near one.
        let mut s2 = [0.0f64; 2];
        for (j, q) in extra.iter().enumerate() {
            let (i, scale) = (j / 4, j % 4 % 2);
            let s = if scale == 0 { far[i] } else { near[i] };
            s2[scale] += (0..3).map(|a| ((q[a] - pts[i][a]) as f64 / s as f64).powi(2)).sum::<f64>();
        }
        for v in s2 {
            let var = v / (3.0 * 2.0 * pts.len() as f64);
            assert!((var - 1.0).abs() < 0.1, "{var}");
        }
        assert!(near.iter().zip(&far).all(|(n, f)| n < f));
        // The paper's draw is unchanged by the new options' defaults.
        assert_eq!(upsample(&pts, &Offsets::paper(DEFAULT_K), 9), upsample(&pts, &Offsets { k: DEFAULT_K, near_k: None, per_point: 1 }, 9));
    }
}
