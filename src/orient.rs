//! Pairs across the surface (issue 14: thin parts).
//!
//! The paper's pairs take the network's logit as their label wherever they land. Where the
//! network misses a thin part (an ear, a flap, a handle thinner than its 64² feature cells),
//! it calls both sides "outside", the pairs say the same, and the regression can only pin its
//! zero level to the points from one side: the part comes back in pieces or not at all.
//!
//! Here every input point p gets two more points, p ± δ·n along its PCA normal n. The network
//! is asked which of the two is more inside (the higher logit): an ordering it gets right far
//! more often than the sign, since its logits still rise towards a sheet it does not close. The
//! neighbours' orderings vote (aligned to p's normal), the inner point's label is made at least
//! +`floor` and the outer one's at most −`floor`, and the network's own logit is kept where it
//! already says more. The surface then has an inside wherever the points say it has two sides.

use crate::sample::PointIndex;

/// Neighbours for each point's PCA normal and for the vote over orderings.
pub const NEIGHBOURS: usize = 10;

/// The least |label| of the two points across the surface: a logit of 1 is a probability of
/// 0.73, clearly on one side without overruling what the network says with more confidence.
pub const FLOOR: f32 = 1.0;

/// Each point's `k` nearest points (itself included) and its distance to its `rank`-th nearest
/// other point, from one search: the normals, the vote and the offsets all read it.
pub struct Neighbourhoods {
    k: usize,
    /// `k` indices per point (k at most the point count), nearest first.
    near: Vec<u32>,
    /// Distance to the `rank`-th nearest other point: [`crate::sample::kth_neighbour_distance`]'s.
    pub spacing: Vec<f32>,
}

impl Neighbourhoods {
    /// Point `i`'s neighbours (itself first), nearest first.
    pub fn of(&self, i: usize) -> &[u32] {
        &self.near[i * self.k..(i + 1) * self.k]
    }
}

/// One k-nearest search over `points` for [`Neighbourhoods`]: the `rank`-th other point is the
/// `rank`-th after the point itself, so a search for max(k, rank + 1) serves both.
pub fn neighbourhoods(points: &[[f32; 3]], k: usize, rank: usize) -> Neighbourhoods {
    let index = PointIndex::new(points);
    let reach = k.max(rank + 1);
    let k = k.min(points.len());
    let rank = rank.clamp(1, points.len().saturating_sub(1).max(1));
    // One (neighbours, spacings) pair per range of points, the ranges split over the cores.
    let parts = crate::par::map_ranges(points.len(), |range| {
        let mut found = Vec::with_capacity(reach);
        let mut near = Vec::with_capacity(range.len() * k);
        let mut spacing = Vec::with_capacity(range.len());
        for &p in &points[range] {
            index.k_nearest(p, reach, &mut found);
            near.extend(found[..k].iter().map(|&(_, j)| j));
            spacing.push(found.get(rank).map_or(0.0, |&(d2, _)| d2.sqrt()));
        }
        vec![(near, spacing)]
    });
    let near = parts.iter().flat_map(|(n, _)| n).copied().collect();
    let spacing = parts.iter().flat_map(|(_, s)| s).copied().collect();
    Neighbourhoods { k, near, spacing }
}

/// Unit normals (unoriented) of each point: the least-spread direction of its neighbourhood
/// (itself included); (0, 0, 1) where it does not define one.
pub fn pca_normals(points: &[[f32; 3]], nb: &Neighbourhoods) -> Vec<[f32; 3]> {
    crate::par::map_ranges(points.len(), |range| {
        range.map(|i| {
            let near = nb.of(i).iter().map(|&j| points[j as usize]);
            crate::eigen3::plane(near).map_or([0.0, 0.0, 1.0], |(_, normal)| normal.map(|v| v as f32))
        })
        .collect()
    })
}

/// The two points across the surface at each input point: `2 i` is p + δ_i n_i, `2 i + 1` is
/// p − δ_i n_i.
pub fn across(points: &[[f32; 3]], normals: &[[f32; 3]], delta: &[f32]) -> Vec<[f32; 3]> {
    let mut out = Vec::with_capacity(2 * points.len());
    for ((p, n), &d) in points.iter().zip(normals).zip(delta) {
        out.push([0, 1, 2].map(|a| p[a] + d * n[a]));
        out.push([0, 1, 2].map(|a| p[a] - d * n[a]));
    }
    out
}

/// Labels of the points made by [`across`], from the network's `logits` there (same order):
/// each point's side is the vote of its neighbourhood's orderings (each one's logit difference,
/// its sign turned to agree with p's normal); the inner point gets at least +`floor`, the outer
/// at most −`floor`, both within ±`clip`. Where the vote is a tie, the logits stay.
pub fn across_targets(normals: &[[f32; 3]], nb: &Neighbourhoods, logits: &[f32], floor: f32, clip: f32) -> Vec<f32> {
    // d_i > 0: the −n side is the more inside one.
    let order: Vec<f32> = (0..normals.len()).map(|i| logits[2 * i + 1] - logits[2 * i]).collect();
    let mut out = Vec::with_capacity(logits.len());
    for i in 0..normals.len() {
        let vote: f32 = nb
            .of(i)
            .iter()
            .map(|&j| {
                let nj = normals[j as usize];
                let dot = (0..3).map(|a| nj[a] * normals[i][a]).sum::<f32>();
                // A neighbour's ordering counts by its size (a clear one outweighs noise) and
                // by how well its normal agrees with p's.
                dot * order[j as usize]
            })
            .sum();
        let (plus, minus) = (logits[2 * i], logits[2 * i + 1]);
        let (plus, minus) = if vote > 0.0 {
            (plus.min(-floor), minus.max(floor))
        } else if vote < 0.0 {
            (plus.max(floor), minus.min(-floor))
        } else {
            (plus, minus)
        };
        out.push(plus.clamp(-clip, clip));
        out.push(minus.clamp(-clip, clip));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on a sphere of radius 0.3, evenly spread (a Fibonacci lattice).
    fn sphere(n: usize, r: f32) -> Vec<[f32; 3]> {
        (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                let t = i as f32 * 2.399_963;
                let s = (1.0 - z * z).sqrt();
                [r * s * t.cos(), r * s * t.sin(), r * z]
            })
            .collect()
    }

    #[test]
    fn pca_normals_are_radial_on_a_sphere() {
        let pts = sphere(2000, 0.3);
        let nb = neighbourhoods(&pts, NEIGHBOURS, NEIGHBOURS);
        for (p, n) in pts.iter().zip(pca_normals(&pts, &nb)) {
            let cos = (0..3).map(|a| p[a] * n[a]).sum::<f32>().abs() / 0.3;
            assert!(cos > 0.99, "normal {n:?} at {p:?}");
        }
    }

    #[test]
    fn a_sheet_the_network_calls_outside_on_both_sides_gets_an_inside() {
        // A thin plate z ∈ [-0.01, 0.01]: points on both faces. The "network" rises towards
        // the plate's middle but never above 0 (it misses the plate), as it does on thin ears.
        let mut pts = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (x, y) = (i as f32 * 0.01 - 0.2, j as f32 * 0.01 - 0.2);
                pts.push([x, y, 0.01]);
                pts.push([x + 0.005, y + 0.005, -0.01]);
            }
        }
        let nb = neighbourhoods(&pts, NEIGHBOURS, NEIGHBOURS);
        let normals = pca_normals(&pts, &nb);
        let delta = vec![0.004; pts.len()];
        let q = across(&pts, &normals, &delta);
        let logits: Vec<f32> = q.iter().map(|p| -3.0 - 100.0 * p[2].abs()).collect();
        let y = across_targets(&normals, &nb, &logits, FLOOR, 4.0);
        for (i, p) in q.iter().enumerate() {
            // Inside the plate: |z| < 0.01.
            let inside = p[2].abs() < 0.01;
            assert_eq!(y[i] > 0.0, inside, "point {p:?} label {}", y[i]);
            assert!(y[i].abs() >= FLOOR && y[i].abs() <= 4.0);
        }
    }

    #[test]
    fn the_vote_overrules_one_point_whose_ordering_is_wrong() {
        let pts = sphere(500, 0.3);
        let nb = neighbourhoods(&pts, NEIGHBOURS, NEIGHBOURS);
        let normals = pca_normals(&pts, &nb);
        let q = across(&pts, &normals, &vec![0.01; pts.len()]);
        // A good network: logit 10 (0.3 − |q|); one point's pair swapped.
        let mut logits: Vec<f32> = q.iter().map(|p| 10.0 * (0.3 - (0..3).map(|a| p[a] * p[a]).sum::<f32>().sqrt())).collect();
        logits.swap(20, 21);
        let y = across_targets(&normals, &nb, &logits, FLOOR, 4.0);
        for (i, p) in q.iter().enumerate() {
            let inside = (0..3).map(|a| p[a] * p[a]).sum::<f32>().sqrt() < 0.3;
            assert_eq!(y[i] > 0.0, inside, "point {i} {p:?} label {}", y[i]);
        }
    }
}
