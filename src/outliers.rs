//! Stray points (flying pixels, reflections, dust: every real scan has some), found before
//! anything else sees the cloud, by the textbook statistical filter (PCL's and Open3D's
//! `remove_statistical_outlier`): a point whose mean distance to its `k` nearest neighbours is
//! more than `ratio` standard deviations above the cloud's mean of that distance is dropped.
//!
//! Why before the normalisation: stray points far out set the bounding box, so the object
//! would shrink inside the network's unit cube; and the network, which never saw stray points
//! in training, turns each cluster of them into a floating blob.
//!
//! The filter alone also takes the sparse side of a scan whose density falls with distance
//! (measured: a cloud whose density falls 55x along the object lost its sparse end, CD1 ×100
//! 0.91 → 3.17), since its spacing is what the filter calls far. So a flagged point is only
//! dropped when its neighbourhood does not look like a piece of surface it lies on: its 20
//! neighbours flat (the smallest principal spread well below the middle one) and the point on
//! their plane keep it. Stray points in open space have neighbours spread in all three
//! directions, or lie off the plane of the surface points around them.

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
    points
        .iter()
        .zip(&mean)
        .map(|(&p, &d)| {
            if d <= limit {
                return true;
            }
            index.k_nearest(p, k + 1, &mut near);
            on_surface(p, near.iter().skip(1).map(|&(_, j)| points[j as usize]))
        })
        .collect()
}

/// The smallest principal spread of a flat neighbourhood is at most this share of the middle
/// one (a noisy or gently curved patch is well below; points spread in open space near 1).
const FLAT: f64 = 0.15;
/// A point lies on its neighbours' plane when it is within this many of their spreads across it.
const ON_PLANE: f64 = 3.0;

/// Whether `p` lies on the plane of a flat neighbourhood `near`.
fn on_surface(p: [f32; 3], near: impl Iterator<Item = [f32; 3]>) -> bool {
    let q: Vec<[f64; 3]> = near.map(|x| x.map(f64::from)).collect();
    let m = q.len() as f64;
    let c = [0, 1, 2].map(|a| q.iter().map(|x| x[a]).sum::<f64>() / m);
    let mut cov = [[0.0; 3]; 3];
    for x in &q {
        for i in 0..3 {
            for j in 0..3 {
                cov[i][j] += (x[i] - c[i]) * (x[j] - c[j]) / m;
            }
        }
    }
    let Some((values, vectors)) = crate::eigen3::symmetric(cov) else { return true };
    let mut order = [0, 1, 2];
    order.sort_by(|&i, &j| values[j].total_cmp(&values[i]));
    let (mid, low) = (values[order[1]].max(0.0), values[order[2]].max(0.0));
    let normal = vectors[order[2]];
    let off = (0..3).map(|a| (f64::from(p[a]) - c[a]) * normal[a]).sum::<f64>().abs();
    low <= FLAT * mid && off <= ON_PLANE * low.sqrt()
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

    #[test]
    fn the_sparse_side_of_a_falling_density_stays() {
        // A plane patch whose density falls 55x along x, as a scanner's does with distance: the
        // global statistics call its sparse end far, but each point there lies on a flat patch.
        let mut rng = SplitMix64(9);
        let mut pts = Vec::new();
        while pts.len() < 3000 {
            let (x, y) = (rng.unit(), rng.unit());
            if rng.unit() < (-(55f64).ln() * x).exp() {
                pts.push([x as f32, y as f32, (0.002 * rng.normal()) as f32]);
            }
        }
        let keep = statistical_filter(&pts, NEIGHBOURS, 2.0);
        let sparse: Vec<bool> = pts.iter().zip(&keep).filter(|(p, _)| p[0] > 0.7).map(|(_, &k)| k).collect();
        let kept = sparse.iter().filter(|&&k| k).count();
        assert!(kept as f64 >= 0.95 * sparse.len() as f64, "{kept} of {} sparse-end points kept", sparse.len());
    }
}
