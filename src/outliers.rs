//! Stray points (flying pixels, reflections, dust: every real scan has some), found before
//! anything else sees the cloud: a point whose mean distance to its 20 nearest neighbours is more
//! than `ratio` times the median of that same distance over its 100 nearest neighbours is
//! dropped. Around a stray point the neighbourhood is the surface (or other stray points spread
//! thinner than it), so its distance stands out from theirs; on a surface, however thin its
//! sampling, neighbours share one density.
//!
//! Why not the textbook filter (PCL's and Open3D's `remove_statistical_outlier`: the distance
//! against the whole cloud's mean and standard deviation): it takes the sparse side of a scan
//! whose density falls with distance, which is what it calls far. Measured on the harder clouds
//! of docs/results.md (3000 points of each of the six eval shapes): with 10 % stray points it
//! drops 887 of the 1800 stray points and this filter 1095; on clouds whose density falls 55x
//! along the object it drops 913 real points and this filter 1 (CD1 ×100 3.17 with it against
//! 0.91 without any filter).
//!
//! Why before the normalisation: stray points far out set the bounding box, so the object
//! would shrink inside the network's unit cube; and the network, which never saw stray points
//! in training, turns each cluster of them into a floating blob.

use crate::cloud::Bounds;
use crate::sample::PointIndex;

/// Neighbours whose mean distance scores a point (Open3D's usual 20).
pub const NEIGHBOURS: usize = 20;
/// The neighbourhood whose median score a point's is held against.
pub const AROUND: usize = 100;

/// `points` without the stray ones ([`local_density_filter`] with [`NEIGHBOURS`], less those
/// that lie beyond the edge of the points it kept: [`beyond_the_edge`]), how many went, and how
/// many the density test alone would have dropped but stayed.
pub fn drop_stray(points: Vec<[f32; 3]>, ratio: f32) -> (Vec<[f32; 3]>, usize, usize) {
    let index = PointIndex::new(&points);
    let scores = mean_distances(&points, &index, NEIGHBOURS);
    let mut keep = verdicts(&points, &index, &scores, ratio);
    let kept_back = beyond_the_edge(&points, &scores, &mut keep);
    let dropped = keep.iter().filter(|&&k| !k).count();
    if dropped == 0 {
        return (points, 0, kept_back);
    }
    (points.into_iter().zip(keep).filter(|(_, k)| *k).map(|(p, _)| p).collect(), dropped, kept_back)
}

/// A kept point is the edge of the kept points when the centroid of its [`EDGE_NEIGHBOURS`]
/// nearest kept points lies beside it, in their plane, by more than this share of their mean
/// distance to it: about 0.42 at the straight edge of an even sheet (a half disc's centroid),
/// 0.1-0.3 inside one.
const EDGE: f64 = 0.4;
/// The kept neighbours that say whether a kept point is an edge.
const EDGE_NEIGHBOURS: usize = 20;

/// Sets back to kept (`keep[i] = true`) each point the density test dropped that lies beyond
/// the edge of the kept points: its nearest kept point is an edge ([`EDGE`]) and it lies on the
/// open side of it (outwards along the kept neighbours' plane, not behind it). Returns how many.
///
/// Why: where a scan's density falls by a step (one side of the object seen from far, or a
/// second scan from farther away), the sparse side's points have neighbours in the dense side,
/// and when it holds fewer points than [`AROUND`] every one of them is held against the dense
/// side's spacing: the density test took the whole sparse half (3,000 points, half of the object
/// 55 times sparser: 223 of about 320 such points went on the six eval shapes, and with them that
/// half of the mesh, CD1 ×100 4.9 against screened Poisson's 2.1). Locally a sparse side's points
/// and stray points look alike (as far apart, as far from the dense points); what tells them
/// apart is where they lie against the dense points: a sparse side starts at the dense points'
/// edge and goes on from it, while a stray point floats over a surface that goes on under it.
/// Measured on the harder set's stray-point clouds (10 % of the points uniform in the box): 105
/// of the 1,095 stray points the test drops come back, the nearest ones to a surface's edge (the
/// rest of their error in docs/results.md).
///
/// `scores`: each point's mean distance to its [`NEIGHBOURS`] nearest
/// ([`mean_distances`], the density test's own).
fn beyond_the_edge(points: &[[f32; 3]], scores: &[f32], keep: &mut [bool]) -> usize {
    let dropped: Vec<usize> = (0..points.len()).filter(|&i| !keep[i]).collect();
    let kept: Vec<[f32; 3]> = points.iter().zip(keep.iter()).filter(|(_, &k)| k).map(|(p, _)| *p).collect();
    if dropped.is_empty() || kept.len() <= EDGE_NEIGHBOURS {
        return 0;
    }
    let kept_index = PointIndex::new(&kept);
    let back = crate::par::map_ranges(dropped.len(), |range| {
        let mut near = Vec::with_capacity(EDGE_NEIGHBOURS + 1);
        range
            .map(|d| {
                let p = points[dropped[d]];
                kept_index.k_nearest(p, 1, &mut near);
                let Some(&(_, q)) = near.first() else { return false };
                let q = kept[q as usize];
                kept_index.k_nearest(q, EDGE_NEIGHBOURS + 1, &mut near);
                outward(q, &near[1..], &kept).is_some_and(|out| (0..3).map(|a| (p[a] - q[a]) as f64 * out[a]).sum::<f64>() > 0.0)
            })
            .collect()
    });
    // A sparse side is many points; a stray point beyond the tip of a horn or a tail is one or a
    // few, and its blob would hang on the surface there. The candidates link when one lies
    // within the other's mean distance to its NEIGHBOURS nearest points, and a group of them
    // stays when it is as large as a piece of the mesh must be to stay ([`MIN_GROUP`]), or, where
    // two in three of the dropped points are candidates ([`SPARSE_SHARE`]), from [`FEW`] points up.
    let candidates: Vec<usize> = dropped.iter().zip(back).filter(|(_, b)| *b).map(|(&i, _)| i).collect();
    let at: Vec<[f32; 3]> = candidates.iter().map(|&i| points[i]).collect();
    let among = PointIndex::new(&at);
    let links: Vec<Vec<u32>> = crate::par::map_ranges(candidates.len(), |range| {
        let mut near = Vec::with_capacity(LINKS + 1);
        range
            .map(|c| {
                let reach = scores[candidates[c]];
                among.k_nearest(at[c], LINKS + 1, &mut near);
                near.iter().skip(1).filter(|&&(d2, _)| d2.sqrt() <= reach).map(|&(_, j)| j).collect()
            })
            .collect()
    });
    let mut parent: Vec<u32> = (0..candidates.len() as u32).collect();
    let root = crate::mesh::components::find;
    for (c, l) in links.iter().enumerate() {
        for &j in l {
            let (a, b) = (root(&mut parent, c as u32), root(&mut parent, j));
            parent[a.max(b) as usize] = a.min(b);
        }
    }
    let mut size = vec![0usize; candidates.len()];
    let roots: Vec<u32> = (0..candidates.len() as u32).map(|c| root(&mut parent, c)).collect();
    roots.iter().for_each(|&r| size[r as usize] += 1);
    let sparse_side = candidates.len() as f64 >= SPARSE_SHARE * dropped.len() as f64;
    let least = if sparse_side { FEW } else { MIN_GROUP.max(points.len() / 200) };
    let mut count = 0;
    for (&i, &r) in candidates.iter().zip(&roots) {
        if size[r as usize] >= least {
            keep[i] = true;
            count += 1;
        }
    }
    count
}

/// Candidates of [`beyond_the_edge`] each links to at most (its nearest).
const LINKS: usize = 8;
/// The fewest points a sparse part beyond the edge of the dense points is taken to be, or 0.5 %
/// of the points where that is more (the share a piece of the mesh must be nearest to, to stay).
const MIN_GROUP: usize = 10;
/// Where at least this share of the points the density test dropped lies beyond the edge of the
/// kept points, what it dropped is a sparse part of the scan and not stray points, and its
/// groups stay from [`FEW`] points up. Stray points float all around a surface, in front of it
/// and behind it as much as beyond its edge: on clouds with 3-20 % of their points uniform in
/// the box (500 to 3,000 points, the six eval shapes, 16 clouds a shape) at most 0.62 of the
/// dropped points were beyond an edge (0.01-0.18 at 10 % of 3,000); where a sparse end had fewer
/// points than [`MIN_GROUP`] or 0.5 % of the cloud and went with its part of the mesh (a far
/// half 55 times sparser at 1,000 and 10,000 points, a density falling 200 or 500 times, scans
/// of one side), 0.70-1.0. Two in three lies between (2026-12-05; docs/poisson.md, "Uneven
/// density"). A cloud with both (a sparse half and 5 % stray points) stays under it (0.38-0.60)
/// and keeps the rule by group size alone.
const SPARSE_SHARE: f64 = 2.0 / 3.0;
/// The fewest points of a group that stays where the dropped points are a sparse part of the
/// scan ([`SPARSE_SHARE`]): a lone point or a pair carries no surface.
const FEW: usize = 3;

/// Where the kept point `q` is an edge of its kept neighbours `near` (squared distances and
/// indices into `kept`): the direction in their plane from their centroid to `q` (the open
/// side), when its length is more than [`EDGE`] × their mean distance to `q`; else None.
fn outward(q: [f32; 3], near: &[(f32, u32)], kept: &[[f32; 3]]) -> Option<[f64; 3]> {
    let (c, normal) = crate::eigen3::plane(near.iter().map(|&(_, j)| kept[j as usize]))?;
    let n = near.len() as f64;
    let off = [0, 1, 2].map(|a| q[a] as f64 - c[a]);
    let along = (0..3).map(|a| off[a] * normal[a]).sum::<f64>();
    let out = [0, 1, 2].map(|a| off[a] - along * normal[a]);
    let mean = near.iter().map(|&(d2, _)| (d2 as f64).sqrt()).sum::<f64>() / n;
    let length = out.iter().map(|x| x * x).sum::<f64>().sqrt();
    (mean > 0.0 && length > EDGE * mean).then_some(out)
}

/// `points` without the stray ones and without the few that lie apart from the rest
/// ([`apart`]), and what to tell the user: (text, whether it is a warning) — a warning when the
/// density test took more than [`LARGE_SHARE`] of them, else a notice of how many went (nothing
/// when none did), and a notice of the points that lay apart.
pub fn filter(points: Vec<[f32; 3]>, ratio: f32) -> (Vec<[f32; 3]>, Vec<(String, bool)>) {
    let total = points.len();
    let (kept, dropped, kept_back) = drop_stray(points, ratio);
    let mut said: Vec<(String, bool)> = match warning(dropped, total, ratio) {
        Some(w) => vec![(w, true)],
        None => notice(dropped, kept_back, ratio).map(|n| (n, false)).into_iter().collect(),
    };
    let (kept, away) = drop_apart(kept);
    said.extend(away.map(|a| (a, false)));
    (kept, said)
}

/// The most of the points that a part lying apart may hold and still be dropped ([`apart`]): a
/// reflection or a bit of another object is a handful of points; two objects of a scan hold
/// more, and stay.
pub const APART_SHARE: f64 = 0.01;

/// Which of `points` lie apart from the rest (`true`): beyond an empty slab across one axis
/// wider than the bulk of the cloud is long (the longest side of the box between the 5th and
/// 95th percentiles along each axis), where at most [`APART_SHARE`] of the points lie on the
/// slab's far side. Points must be finite.
///
/// Why: the density test keeps a tight cluster however far from the object it lies (a
/// reflection, a piece of a wall through a door, a second object), and the bounding box it
/// stretches shrinks the object inside the network's unit cube and the mesh's grid: a sphere of
/// 3,000 points with 30 points 50 radii away came back as a blob of 217 triangles. An empty slab
/// wider than the object itself is what no scan of one object holds, however its density falls
/// (a sparse end's points leave gaps of about their spacing).
pub fn apart(points: &[[f32; 3]]) -> Vec<bool> {
    let slabs = slabs(points);
    points.iter().map(|p| !within(&slabs, p)).collect()
}

/// Per axis, where the part lying [`apart`] begins below and above, if anywhere.
type Slabs = [(Option<f32>, Option<f32>); 3];

fn within(slabs: &Slabs, p: &[f32; 3]) -> bool {
    (0..3).all(|a| slabs[a].0.is_none_or(|lo| p[a] >= lo) && slabs[a].1.is_none_or(|hi| p[a] <= hi))
}

/// The slabs of [`apart`] found on `points`.
fn slabs(points: &[[f32; 3]]) -> Slabs {
    let n = points.len();
    let mut slabs: Slabs = [(None, None); 3];
    if n < 20 {
        return slabs;
    }
    let sorted: Vec<Vec<f32>> = (0..3)
        .map(|a| {
            let mut xs: Vec<f32> = points.iter().map(|p| p[a]).collect();
            xs.sort_unstable_by(f32::total_cmp);
            xs
        })
        .collect();
    let at = |xs: &[f32], q: f64| xs[(q * (n - 1) as f64).round() as usize];
    let bulk = sorted.iter().map(|xs| at(xs, 0.95) - at(xs, 0.05)).fold(0.0f32, f32::max);
    if bulk <= 0.0 {
        return slabs;
    }
    let most = (APART_SHARE * n as f64).floor() as usize;
    for (a, xs) in sorted.iter().enumerate() {
        // From the median outwards, the first slab wider than the bulk with few enough points
        // beyond it, on each side.
        let wide = |i: usize| xs[i + 1] - xs[i] > bulk;
        // Each bound is the slab's middle, so that a sample's slab holds the whole cloud's too.
        let middle = |i: usize| 0.5 * (xs[i] + xs[i + 1]);
        let below = (0..n / 2).rev().find(|&i| wide(i) && i < most).map(middle);
        let above = (n / 2..n - 1).find(|&i| wide(i) && n - 1 - i <= most).map(middle);
        slabs[a] = (below, above);
    }
    slabs
}

/// The most points [`bulk_bounds`] sorts: a uniform sample of a larger cloud finds the same
/// slabs (the part apart is a share of the points, the slab wider than the whole object).
const BULK_SAMPLE: usize = 1 << 18;

/// The bounds of `points` without those lying [`apart`] (found on a uniform sample of at most
/// [`BULK_SAMPLE`] of them): the object's own size. What the size decides before the filter
/// runs (the units a file's numbers suggest, whether a cloud is a scene to tile) must not be
/// decided by a reflection 50 object-lengths away: a 20 cm part with a handful of such points
/// in a metre-stated file was tiled as a 10 m scene, and in unstated units its size suggested
/// millimetres. Points must be finite.
pub fn bulk_bounds(points: &[[f32; 3]]) -> Option<Bounds> {
    // A uniform sample, not every k-th point: a file's order can be periodic (scan lines).
    let slabs = slabs(&crate::cloud::subsample(points, BULK_SAMPLE, 0x6275_6c6b));
    Bounds::of_iter(points.iter().filter(|p| within(&slabs, p)))
}

/// `points` without those that lie [`apart`], and a notice of how many went and how far.
fn drop_apart(points: Vec<[f32; 3]>) -> (Vec<[f32; 3]>, Option<String>) {
    let away = apart(&points);
    let went = away.iter().filter(|&&a| a).count();
    if went == 0 {
        return (points, None);
    }
    let total = points.len();
    let all = Bounds::of(&points).map_or(0.0, |b| b.longest_side());
    let kept: Vec<[f32; 3]> = points.into_iter().zip(away).filter(|(_, a)| !*a).map(|(p, _)| p).collect();
    let rest = Bounds::of(&kept).map_or(0.0, |b| b.longest_side());
    let notice = format!(
        "dropped {went} of {total} points that lie apart from the rest, beyond empty space wider than the rest of the cloud \
         (they stretched its extent from {rest:.4} to {all:.4} units, which would shrink the object in the reconstruction): \
         a reflection or a piece of something else; --keep-outliers keeps them"
    );
    (kept, Some(notice))
}

/// A share of the points beyond which the filter is more likely wrong than the cloud: stray
/// points are a few percent of a real scan (10 % in the harder eval clouds), and `--outliers 1`
/// dropped half of a clean one.
pub const LARGE_SHARE: f64 = 0.2;

/// A warning when the filter dropped more than [`LARGE_SHARE`] of the `total` points, with the
/// count and how to keep them; None otherwise (then [`notice`] says what went).
fn warning(dropped: usize, total: usize, ratio: f32) -> Option<String> {
    (dropped as f64 > LARGE_SHARE * total as f64).then(|| {
        format!(
            "the stray-point filter dropped {dropped} of {total} points ({:.0} %), far more than stray points usually are: \
             if they are real, raise its ratio (now {ratio}; --outliers, \"Drop stray points\") or turn it off (--keep-outliers)",
            100.0 * dropped as f64 / total.max(1) as f64
        )
    })
}

/// What the reconstruction tells the user when `dropped` points went and `kept_back` stayed
/// beyond the edge of the denser points ([`beyond_the_edge`]; nothing when neither).
fn notice(dropped: usize, kept_back: usize, ratio: f32) -> Option<String> {
    let went = (dropped > 0).then(|| {
        format!(
            "dropped {dropped} stray points (their mean distance to their {NEIGHBOURS} nearest neighbours is more than {ratio} times that of the points around them)"
        )
    });
    let stayed = (kept_back > 0).then(|| {
        format!("kept {kept_back} points as sparse as stray points that lie beyond the edge of the denser points: a part of the scan seen from farther, not strays")
    });
    match (went, stayed) {
        (Some(w), Some(s)) => Some(format!("{w}; {s}")),
        (w, s) => w.or(s),
    }
}

/// Which of `points` the filter keeps (`true`): a point goes when its mean distance to its `k`
/// nearest neighbours is more than `ratio` times the median of the same over its [`AROUND`]
/// nearest. Clouds of at most `k` points are kept whole. Points must be finite.
pub fn local_density_filter(points: &[[f32; 3]], k: usize, ratio: f32) -> Vec<bool> {
    let index = PointIndex::new(points);
    verdicts(points, &index, &mean_distances(points, &index, k), ratio)
}

/// Each point's mean distance to its `k` nearest others (`index` indexes `points`; the point
/// itself comes back first, at distance 0); empty for a cloud of at most `k` points, which
/// [`verdicts`] keeps whole. The points split over the cores.
fn mean_distances(points: &[[f32; 3]], index: &PointIndex, k: usize) -> Vec<f32> {
    if points.len() <= k || k == 0 {
        return Vec::new();
    }
    crate::par::map_ranges(points.len(), |range| {
        let mut near = Vec::with_capacity(k + 1);
        range
            .map(|i| {
                index.k_nearest(points[i], k + 1, &mut near);
                near.iter().skip(1).take(k).map(|&(d2, _)| d2.sqrt()).sum::<f32>() / k as f32
            })
            .collect()
    })
}

/// Each point's verdict ([`local_density_filter`]): its `mean` distance ([`mean_distances`])
/// against `ratio` times the median of the same over its [`AROUND`] nearest. Two searches a point
/// rather than one list of n·m neighbours (400 MB for a 1M-point scan); the points split over the
/// cores.
fn verdicts(points: &[[f32; 3]], index: &PointIndex, mean: &[f32], ratio: f32) -> Vec<bool> {
    let n = points.len();
    if mean.len() != n {
        return vec![true; n];
    }
    let m = AROUND.min(n - 1);
    crate::par::map_ranges(n, |range| {
        let mut near = Vec::with_capacity(AROUND + 1);
        let mut theirs = Vec::with_capacity(m);
        range
            .map(|i| {
                index.k_nearest(points[i], AROUND + 1, &mut near);
                theirs.clear();
                theirs.extend(near.iter().skip(1).take(m).map(|&(_, j)| mean[j as usize]));
                let mid = theirs.len() / 2;
                let median = *theirs.select_nth_unstable_by(mid, f32::total_cmp).1;
                mean[i] <= ratio * median
            })
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// A point uniform on the unit sphere.
    fn on_sphere(rng: &mut SplitMix64) -> [f64; 3] {
        let v = [rng.normal(), rng.normal(), rng.normal()];
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|c| c / l)
    }

    /// 3000 points on a unit sphere, then 300 uniform in the box around it.
    fn sphere_and_strays(rng: &mut SplitMix64) -> Vec<[f32; 3]> {
        let mut pts: Vec<[f32; 3]> = (0..3000).map(|_| on_sphere(rng).map(|c| c as f32)).collect();
        pts.extend((0..300).map(|_| [0, 1, 2].map(|_| (rng.unit() * 3.0 - 1.5) as f32)));
        pts
    }

    #[test]
    fn scattered_points_go_and_the_surface_stays() {
        let mut rng = SplitMix64(5);
        let pts = sphere_and_strays(&mut rng);
        let keep = local_density_filter(&pts, NEIGHBOURS, 2.0);
        let surface_kept = keep[..3000].iter().filter(|&&k| k).count();
        let strays_kept = keep[3000..].iter().filter(|&&k| k).count();
        assert!(surface_kept >= 2990, "{surface_kept} of 3000 surface points kept");
        assert!(strays_kept <= 100, "{strays_kept} of 300 stray points kept");
        // A clean cloud loses (next to) nothing; tiny clouds are left alone.
        let clean = local_density_filter(&pts[..3000], NEIGHBOURS, 2.0);
        let lost = clean.iter().filter(|&&k| !k).count();
        assert!(lost <= 3, "{lost} of 3000 clean points dropped");
        assert_eq!(local_density_filter(&pts[..10], NEIGHBOURS, 2.0), vec![true; 10]);
    }

    #[test]
    fn a_sparse_side_beyond_the_dense_points_stays_and_strays_still_go() {
        // A sphere seen from near on one side (2,950 points on x < 0) and 55 times sparser on the
        // other (55 points): fewer sparse points than the density test's AROUND, so it holds each
        // of them against the dense side's spacing and drops most.
        let mut rng = SplitMix64(3);
        let mut pts: Vec<[f32; 3]> = Vec::new();
        let (mut dense, mut sparse) = (0, 0);
        while dense < 2950 || sparse < 55 {
            let p = on_sphere(&mut rng).map(|c| (c + 0.002 * rng.normal()) as f32);
            if p[0] < 0.0 && dense < 2950 {
                dense += 1;
                pts.push(p);
            } else if p[0] >= 0.0 && sparse < 55 && rng.unit() < 1.0 / 55.0 {
                sparse += 1;
                pts.push(p);
            }
        }
        let on_sparse = |keep: &[bool]| pts.iter().zip(keep).filter(|(p, &k)| k && p[0] >= 0.0).count();
        let index = PointIndex::new(&pts);
        let scores = mean_distances(&pts, &index, NEIGHBOURS);
        let mut keep = verdicts(&pts, &index, &scores, 2.0);
        let by_density = on_sparse(&keep);
        assert!(by_density < 30, "the set-up: the density test should take most of the sparse side ({by_density} of 55 kept)");
        let back = beyond_the_edge(&pts, &scores, &mut keep);
        assert!(on_sparse(&keep) >= 50, "{} of 55 sparse-side points kept ({back} set back)", on_sparse(&keep));
        // The same filter on scattered stray points around a whole sphere: none lies beyond an
        // edge, since the surface has none, and they still go.
        let (kept, dropped, back) = drop_stray(sphere_and_strays(&mut rng), 2.0);
        assert!(dropped >= 200 && back == 0 && kept.len() == 3300 - dropped, "{dropped} dropped, {back} set back");
    }

    #[test]
    fn a_sparse_side_of_a_few_points_stays_where_it_is_what_the_density_test_drops() {
        // A sphere of 1,000 points whose x > 0 half is 120 times sparser: 6 points beyond x = 0.1, fewer
        // than MIN_GROUP, but nearly all that the density test drops lies beyond the dense
        // half's edge.
        let mut rng = SplitMix64(21);
        let mut pts: Vec<[f32; 3]> = Vec::new();
        while pts.len() < 1000 {
            let p = on_sphere(&mut rng).map(|c| (c + 0.002 * rng.normal()) as f32);
            if p[0] < 0.0 || rng.unit() < 1.0 / 120.0 {
                pts.push(p);
            }
        }
        let far = pts.iter().filter(|p| p[0] > 0.1).count();
        let far_kept = |kept: &[[f32; 3]]| kept.iter().filter(|p| p[0] > 0.1).count();
        let index = PointIndex::new(&pts);
        let scores = mean_distances(&pts, &index, NEIGHBOURS);
        let by_density = far_kept(&pts.iter().zip(verdicts(&pts, &index, &scores, 2.0)).filter(|(_, k)| *k).map(|(p, _)| *p).collect::<Vec<_>>());
        assert!(by_density + 5 < far, "the set-up: the density test should take most of the sparse side ({by_density} of {far} kept)");
        let (kept, _, back) = drop_stray(pts.clone(), 2.0);
        assert!(far_kept(&kept) + 2 >= far, "{} of {far} sparse-side points kept ({back} set back)", far_kept(&kept));
        // 1,000 points of a whole sphere and 100 stray points: what the test drops is mostly in
        // front of the surface, and the strays still go.
        let mut cloud: Vec<[f32; 3]> = (0..1000).map(|_| on_sphere(&mut rng).map(|c| c as f32)).collect();
        cloud.extend((0..100).map(|_| [0, 1, 2].map(|_| (rng.unit() * 3.0 - 1.5) as f32)));
        let (_, dropped, back) = drop_stray(cloud, 2.0);
        assert!(dropped >= 40 && back <= 2, "{dropped} dropped, {back} set back");
    }

    #[test]
    fn a_few_points_far_apart_go_and_the_object_stays() {
        // 3,000 points of a unit sphere and 30 in a tight cluster 50 radii away: dense among
        // themselves, so the density test keeps them.
        let mut rng = SplitMix64(4);
        let mut pts: Vec<[f32; 3]> = (0..3000).map(|_| on_sphere(&mut rng).map(|c| (c + 0.005 * rng.normal()) as f32)).collect();
        pts.extend((0..30).map(|_| [0, 1, 2].map(|_| (50.0 + 0.01 * rng.normal()) as f32)));
        let (kept, said) = filter(pts.clone(), 2.0);
        assert_eq!(kept.len(), 3000, "{said:?}");
        assert!(kept.iter().all(|p| p[0] < 2.0));
        assert!(said.iter().any(|(s, w)| !w && s.starts_with("dropped 30 of 3030 points that lie apart")), "{said:?}");
        // One far point on the other side too, along one axis only.
        pts.push([-40.0, 0.0, 0.0]);
        assert_eq!(apart(&pts).iter().filter(|&&a| a).count(), 31);
        // More than APART_SHARE of the points apart (a second object): they stay.
        pts.extend((0..30).map(|_| [0, 1, 2].map(|_| (50.0 + 0.01 * rng.normal()) as f32)));
        assert_eq!(apart(&pts).iter().filter(|&&a| a).count(), 1, "only the lone point at x = -40");
    }

    #[test]
    fn the_bulk_bounds_are_the_objects_whatever_lies_apart_and_however_many_points() {
        let mut rng = SplitMix64(5);
        for n in [3000, 3 * BULK_SAMPLE] {
            let mut pts: Vec<[f32; 3]> = (0..n).map(|_| on_sphere(&mut rng).map(|c| c as f32)).collect();
            let sphere = Bounds::of(&pts).unwrap();
            // A cluster 50 radii away, 0.5 % of the points, every 200th in the file's order (a
            // period that a sample of every k-th point would alias).
            pts = pts.chunks(199).flat_map(|c| std::iter::once([0, 1, 2].map(|_| (50.0 + 0.01 * rng.normal()) as f32)).chain(c.iter().copied())).collect();
            assert!(Bounds::of(&pts).unwrap().longest_side() > 40.0);
            assert_eq!(bulk_bounds(&pts), Some(sphere), "{n} points");
        }
        assert_eq!(bulk_bounds(&[]), None);
        assert_eq!(bulk_bounds(&[[1.0, 2.0, 3.0]]), Some(Bounds { min: [1.0, 2.0, 3.0], max: [1.0, 2.0, 3.0] }));
    }

    #[test]
    fn nothing_lies_apart_in_an_object_its_strays_or_a_falling_density() {
        let mut rng = SplitMix64(6);
        // Strays uniform in the box around a sphere, and the sphere alone.
        let pts = sphere_and_strays(&mut rng);
        assert!(apart(&pts).iter().all(|&a| !a));
        // Two spheres as far apart as they are wide, the second half as dense.
        let mut two: Vec<[f32; 3]> = pts[..3000].to_vec();
        two.extend((0..1500).map(|_| on_sphere(&mut rng).map(|c| c as f32)).map(|p| [p[0] + 6.0, p[1], p[2]]));
        assert!(apart(&two).iter().all(|&a| !a));
        // A flat patch whose density falls 500x along x (its sparse end a few points with wide
        // gaps between them), and a thin object lying on a floor (the floor's bulk is thin across
        // it, not the cloud's).
        let mut falling = Vec::new();
        while falling.len() < 3000 {
            let (x, y) = (rng.unit(), rng.unit());
            if rng.unit() < (-(500f64).ln() * x).exp() {
                falling.push([x as f32, y as f32, (0.002 * rng.normal()) as f32]);
            }
        }
        assert!(apart(&falling).iter().all(|&a| !a));
        let mut floor: Vec<[f32; 3]> = (0..3000).map(|_| [rng.unit() as f32, rng.unit() as f32, 0.0]).collect();
        floor.extend((0..20).map(|_| [0.5 + 0.01 * rng.unit() as f32, 0.5, 0.05]));
        assert!(apart(&floor).iter().all(|&a| !a));
    }

    #[test]
    fn the_sparse_side_of_a_falling_density_stays() {
        // A plane patch whose density falls 55x along x, as a scanner's does with distance: the
        // global statistics call its sparse end far, but its points share their neighbours'
        // density.
        let mut rng = SplitMix64(9);
        let mut pts = Vec::new();
        while pts.len() < 3000 {
            let (x, y) = (rng.unit(), rng.unit());
            if rng.unit() < (-(55f64).ln() * x).exp() {
                pts.push([x as f32, y as f32, (0.002 * rng.normal()) as f32]);
            }
        }
        let keep = local_density_filter(&pts, NEIGHBOURS, 2.0);
        let sparse: Vec<bool> = pts.iter().zip(&keep).filter(|(p, _)| p[0] > 0.7).map(|(_, &k)| k).collect();
        let kept = sparse.iter().filter(|&&k| k).count();
        assert!(kept as f64 >= 0.97 * sparse.len() as f64, "{kept} of {} sparse-end points kept", sparse.len());
    }
}
