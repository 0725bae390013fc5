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

use crate::sample::PointIndex;

/// Neighbours whose mean distance scores a point (Open3D's usual 20).
pub const NEIGHBOURS: usize = 20;
/// The neighbourhood whose median score a point's is held against.
pub const AROUND: usize = 100;

/// `points` without the stray ones ([`local_density_filter`] with [`NEIGHBOURS`]), and how
/// many went.
pub fn drop_stray(points: Vec<[f32; 3]>, ratio: f32) -> (Vec<[f32; 3]>, usize) {
    let keep = local_density_filter(&points, NEIGHBOURS, ratio);
    let dropped = keep.iter().filter(|&&k| !k).count();
    if dropped == 0 {
        return (points, 0);
    }
    (points.into_iter().zip(keep).filter(|(_, k)| *k).map(|(p, _)| p).collect(), dropped)
}

/// `points` without the stray ones, and what to tell the user: (text, whether it is a warning)
/// — a warning when the filter took more than [`LARGE_SHARE`] of them, else a notice of how many
/// went (nothing when none did).
pub fn filter(points: Vec<[f32; 3]>, ratio: f32) -> (Vec<[f32; 3]>, Option<(String, bool)>) {
    let total = points.len();
    let (kept, dropped) = drop_stray(points, ratio);
    let said = match warning(dropped, total, ratio) {
        Some(w) => Some((w, true)),
        None => notice(dropped, ratio).map(|n| (n, false)),
    };
    (kept, said)
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

/// What the reconstruction tells the user when `dropped` points went (nothing when none did).
fn notice(dropped: usize, ratio: f32) -> Option<String> {
    (dropped > 0).then(|| {
        format!(
            "dropped {dropped} stray points (their mean distance to their {NEIGHBOURS} nearest neighbours is more than {ratio} times that of the points around them)"
        )
    })
}

/// Which of `points` the filter keeps (`true`): a point goes when its mean distance to its `k`
/// nearest neighbours is more than `ratio` times the median of the same over its [`AROUND`]
/// nearest. Clouds of at most `k` points are kept whole. Points must be finite.
pub fn local_density_filter(points: &[[f32; 3]], k: usize, ratio: f32) -> Vec<bool> {
    let n = points.len();
    if n <= k || k == 0 {
        return vec![true; n];
    }
    let index = PointIndex::new(points);
    // Each point's mean distance to its k nearest others (the point itself comes back first,
    // at distance 0), then its verdict against the median of the same over its `m` nearest.
    // Two searches a point rather than one list of n·m neighbours (400 MB for a 1M-point scan);
    // the points split over the cores.
    let mean: Vec<f32> = crate::par::map_ranges(n, |range| {
        let mut near = Vec::with_capacity(k + 1);
        range
            .map(|i| {
                index.k_nearest(points[i], k + 1, &mut near);
                near.iter().skip(1).take(k).map(|&(d2, _)| d2.sqrt()).sum::<f32>() / k as f32
            })
            .collect()
    });
    let m = AROUND.min(n - 1);
    crate::par::map_ranges(n, |range| {
        let mut near = Vec::with_capacity(AROUND.max(k) + 1);
        let mut theirs = Vec::with_capacity(m);
        range
            .map(|i| {
                index.k_nearest(points[i], AROUND.max(k) + 1, &mut near);
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

    #[test]
    fn scattered_points_go_and_the_surface_stays() {
        // 3000 points on a unit sphere and 300 uniform in the box around it.
        let mut rng = SplitMix64(5);
        let mut pts: Vec<[f32; 3]> = (0..3000)
            .map(|_| {
                let v = [rng.normal(), rng.normal(), rng.normal()];
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                v.map(|c| (c / l) as f32)
            })
            .collect();
        pts.extend((0..300).map(|_| [0, 1, 2].map(|_| (rng.unit() * 3.0 - 1.5) as f32)));
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
