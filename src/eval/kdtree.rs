//! Exact nearest neighbours in `f64`: a balanced k-d tree stored implicitly in one array.
//!
//! A node covers a range `[lo, hi)` of the reordered points; its split is the median at
//! `mid = lo + (hi - lo) / 2` along the axis of largest extent, with `[lo, mid)` at or below the
//! median and `[mid, hi)` at or above it. The split axis and value are stored at index `mid`,
//! which no other inner node shares (the median point itself moves when its half is split in
//! turn, so its coordinate cannot stand in for the value). Unlike a uniform grid,
//! queries far from every sample (a reconstruction's spurious blob) stay logarithmic.

const LEAF: usize = 8;

pub(crate) struct KdTree {
    points: Vec<[f64; 3]>,
    ids: Vec<u32>,
    axis: Vec<u8>,
    split: Vec<f64>,
}

impl KdTree {
    pub fn new(points: &[[f64; 3]]) -> KdTree {
        let mut ids: Vec<u32> = (0..points.len() as u32).collect();
        let mut axis = vec![0u8; points.len()];
        let mut split = vec![0.0; points.len()];
        build(points, &mut ids, 0, &mut axis, &mut split);
        KdTree { points: ids.iter().map(|&i| points[i as usize]).collect(), ids, axis, split }
    }

    /// `(squared distance, index)` of the point nearest to `q`, or `None` when the tree is empty.
    pub fn nearest(&self, q: [f64; 3]) -> Option<(f64, u32)> {
        let mut best = (f64::INFINITY, u32::MAX);
        self.search(q, 0, self.points.len(), 0.0, &mut [0.0; 3], &mut best);
        (best.1 != u32::MAX).then_some(best)
    }

    /// Searches the node `[lo, hi)`, whose box is `sqrt(box_d2)` from `q`, with `off[a]` the
    /// distance from `q` to the box's slab along axis `a` (so `box_d2 = Σ off²`). A far child is
    /// skipped when its box, not just its splitting plane, is farther than the best so far:
    /// with the plane alone, a query far outside the data (a reconstruction's stray blob)
    /// would visit nearly every node.
    fn search(&self, q: [f64; 3], lo: usize, hi: usize, box_d2: f64, off: &mut [f64; 3], best: &mut (f64, u32)) {
        if hi - lo <= LEAF {
            for i in lo..hi {
                let p = self.points[i];
                let d2 = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
                if d2 < best.0 {
                    *best = (d2, self.ids[i]);
                }
            }
            return;
        }
        let mid = lo + (hi - lo) / 2;
        let a = self.axis[mid] as usize;
        let diff = q[a] - self.split[mid];
        let (near, far) = if diff < 0.0 { ((lo, mid), (mid, hi)) } else { ((mid, hi), (lo, mid)) };
        self.search(q, near.0, near.1, box_d2, off, best);
        let old = off[a];
        let far_d2 = box_d2 - old * old + diff * diff;
        if far_d2 < best.0 {
            off[a] = diff.abs();
            self.search(q, far.0, far.1, far_d2, off, best);
            off[a] = old;
        }
    }
}

fn build(points: &[[f64; 3]], ids: &mut [u32], offset: usize, axis: &mut [u8], split: &mut [f64]) {
    if ids.len() <= LEAF {
        return;
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &i in ids.iter() {
        for a in 0..3 {
            lo[a] = lo[a].min(points[i as usize][a]);
            hi[a] = hi[a].max(points[i as usize][a]);
        }
    }
    let a = (0..3).max_by(|&x, &y| (hi[x] - lo[x]).total_cmp(&(hi[y] - lo[y]))).unwrap_or(0);
    let mid = ids.len() / 2;
    ids.select_nth_unstable_by(mid, |&x, &y| points[x as usize][a].total_cmp(&points[y as usize][a]));
    axis[offset + mid] = a as u8;
    split[offset + mid] = points[ids[mid] as usize][a];
    let (left, right) = ids.split_at_mut(mid);
    build(points, left, offset, axis, split);
    build(points, right, offset + mid, axis, split);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    #[test]
    fn nearest_matches_brute_force() {
        let mut r = SplitMix64(5);
        // Two clusters far apart, duplicates, and points on a plane (zero extent on one axis).
        let mut pts: Vec<[f64; 3]> = (0..3000).map(|_| [r.unit(), r.unit(), r.unit()]).collect();
        pts.extend((0..500).map(|_| [10.0 + 0.01 * r.unit(), 0.01 * r.unit(), 0.0]));
        pts.extend(vec![[0.5, 0.5, 0.5]; 40]);
        let tree = KdTree::new(&pts);
        for _ in 0..2000 {
            // Some queries far outside the data, where only box pruning keeps the search short.
            let far = if r.unit() < 0.2 { 100.0 } else { 1.0 };
            let q = [far * (12.0 * r.unit() - 1.0), 2.0 * r.unit() - 0.5, far * r.unit()];
            let (d2, i) = tree.nearest(q).unwrap();
            let brute = pts.iter().map(|p| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).fold(f64::INFINITY, f64::min);
            assert_eq!(d2, brute);
            let p = pts[i as usize];
            assert_eq!((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2), d2);
        }
        assert!(KdTree::new(&[]).nearest([0.0; 3]).is_none());
        assert_eq!(KdTree::new(&[[1.0, 2.0, 3.0]]).nearest([0.0; 3]), Some((14.0, 0)));
    }
}
