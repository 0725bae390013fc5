//! Stray points (flying pixels, reflections, dust: every real scan has some), found before
//! anything else sees the cloud, by the textbook statistical filter (PCL's and Open3D's
//! `remove_statistical_outlier`): a point whose mean distance to its `k` nearest neighbours is
//! more than `ratio` standard deviations above the cloud's mean of that distance is dropped.
//!
//! Why before the normalisation: stray points far out set the bounding box, so the object
//! would shrink inside the network's unit cube; and the network, which never saw stray points
//! in training, turns each cluster of them into a floating blob.

use crate::sample::PointIndex;

/// Neighbours whose mean distance scores a point (Open3D's usual 20).
pub const NEIGHBOURS: usize = 20;

/// Which of `points` the filter keeps (`true`), with `k` neighbours and a threshold of `ratio`
/// standard deviations. Fewer than `k + 1` points, or a cloud whose distances do not vary,
/// keeps everything. Points must be finite.
pub fn statistical_filter(points: &[[f32; 3]], k: usize, ratio: f32) -> Vec<bool> {
    let n = points.len();
    if n <= k || k == 0 {
        return vec![true; n];
    }
    let index = PointIndex::new(points);
    let mut near = Vec::with_capacity(k + 1);
    let mean: Vec<f64> = points
        .iter()
        .map(|&p| {
            // The point itself comes back first, at distance 0.
            index.k_nearest(p, k + 1, &mut near);
            near.iter().skip(1).map(|&(d2, _)| f64::from(d2).sqrt()).sum::<f64>() / k as f64
        })
        .collect();
    let mu = mean.iter().sum::<f64>() / n as f64;
    let sd = (mean.iter().map(|d| (d - mu) * (d - mu)).sum::<f64>() / (n - 1) as f64).sqrt();
    let limit = mu + f64::from(ratio) * sd;
    mean.iter().map(|&d| d <= limit).collect()
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
        let keep = statistical_filter(&pts, NEIGHBOURS, 2.0);
        let surface_kept = keep[..3000].iter().filter(|&&k| k).count();
        let strays_kept = keep[3000..].iter().filter(|&&k| k).count();
        assert!(surface_kept >= 2970, "{surface_kept} of 3000 surface points kept");
        assert!(strays_kept <= 150, "{strays_kept} of 300 stray points kept");
        // A clean cloud loses only the tail of its own spacings (a few per cent at most); tiny
        // clouds are left alone.
        let clean = statistical_filter(&pts[..3000], NEIGHBOURS, 2.0);
        let lost = clean.iter().filter(|&&k| !k).count();
        assert!(lost <= 150, "{lost} of 3000 clean points dropped");
        assert_eq!(statistical_filter(&pts[..10], NEIGHBOURS, 2.0), vec![true; 10]);
    }
}
