//! The one way every reader turns points into a [`PointCloud`]: origin, non-finite points and
//! attribute alignment handled alike for every format.

use crate::cloud::PointCloud;

/// Builds a cloud from `f64` points, as every reader does: the origin is chosen at the first
/// finite point (see [`crate::cloud::origin_for`]) unless recentring is off, points with a
/// non-finite coordinate are counted and dropped, and attributes stay aligned with the kept
/// points.
pub(crate) struct CloudBuilder {
    positions: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    colors: Option<Vec<[u8; 4]>>,
    origin: Option<[f64; 3]>,
    pub dropped: u64,
}

impl CloudBuilder {
    /// `recentre`: choose an origin for far-off points (off for coordinates an `f32` already
    /// holds exactly, such as PLY `float`s).
    pub fn new(normals: bool, colors: bool, recentre: bool) -> Self {
        CloudBuilder {
            positions: Vec::new(),
            normals: normals.then(Vec::new),
            colors: colors.then(Vec::new),
            origin: (!recentre).then_some([0.0; 3]),
            dropped: 0,
        }
    }

    /// Reserves room for `n` more points; callers pass a count already bounded by the input.
    pub fn reserve(&mut self, n: usize) {
        self.positions.reserve(n);
        if let Some(v) = &mut self.normals {
            v.reserve(n);
        }
        if let Some(v) = &mut self.colors {
            v.reserve(n);
        }
    }

    #[inline]
    pub fn push(&mut self, p: [f64; 3], normal: [f32; 3], color: [u8; 4]) {
        if !p.iter().all(|c| c.is_finite()) {
            self.dropped += 1;
            return;
        }
        let o = *self.origin.get_or_insert_with(|| crate::cloud::origin_for(p));
        let pos = [(p[0] - o[0]) as f32, (p[1] - o[1]) as f32, (p[2] - o[2]) as f32];
        if !pos.iter().all(|c| c.is_finite()) {
            self.dropped += 1;
            return;
        }
        self.positions.push(pos);
        if let Some(v) = &mut self.normals {
            v.push(normal);
        }
        if let Some(v) = &mut self.colors {
            v.push(color);
        }
    }

    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn finish(self) -> PointCloud {
        PointCloud {
            positions: self.positions,
            origin: self.origin.unwrap_or([0.0; 3]),
            normals: self.normals,
            colors: self.colors,
        }
    }
}
