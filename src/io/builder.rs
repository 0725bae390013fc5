//! The one way every reader turns points into a [`PointCloud`]: origin, non-finite points and
//! attribute alignment handled alike for every format.

use crate::cloud::PointCloud;

/// What became of a pushed point.
#[derive(Clone, Copy, Debug, PartialEq)]
#[must_use]
pub(crate) enum Pushed {
    Kept,
    /// A NaN or infinite coordinate: counted in `dropped`.
    NonFinite,
    /// Coordinate `axis` (0 = x) is finite but `value - origin` exceeds `f32::MAX`.
    TooLarge { axis: usize, value: f64, origin: f64 },
}

impl Pushed {
    /// The message for [`Pushed::TooLarge`] (without the where, which the caller adds). When
    /// the origin is not 0 it came from the cloud's first point, which may be the outlier: the
    /// message says so.
    pub fn too_large(axis: usize, value: f64, origin: f64) -> String {
        let name = ["x", "y", "z"][axis.min(2)];
        if origin == 0.0 {
            format!(
                "{name} = {value:e} is too large for a 32-bit float (at most about 3.4e38): nkrr keeps positions as \
                 32-bit floats; is the value or the column wrong?"
            )
        } else {
            format!(
                "{name} = {value:e} is {:e} from the cloud's origin ({name} = {origin:e}, taken from the first point), \
                 too far for a 32-bit float (at most about 3.4e38): nkrr keeps positions as 32-bit floats relative to \
                 that origin; is this value, or the first point, wrong?",
                value - origin
            )
        }
    }
}

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

    /// Adds a point. A point with a NaN or infinite coordinate is counted in `dropped` and
    /// skipped; one that is finite but too far from the origin for an `f32` is not stored
    /// either, and the caller is told which coordinate, to refuse the file saying where (calling
    /// it "NaN or infinite" pointed the user the wrong way).
    #[inline]
    pub fn push(&mut self, p: [f64; 3], normal: [f32; 3], color: [u8; 4]) -> Pushed {
        if !p.iter().all(|c| c.is_finite()) {
            self.dropped += 1;
            return Pushed::NonFinite;
        }
        let o = *self.origin.get_or_insert_with(|| crate::cloud::origin_for(p));
        let pos = [(p[0] - o[0]) as f32, (p[1] - o[1]) as f32, (p[2] - o[2]) as f32];
        if let Some(axis) = pos.iter().position(|c| !c.is_finite()) {
            return Pushed::TooLarge { axis, value: p[axis], origin: o[axis] };
        }
        self.positions.push(pos);
        if let Some(v) = &mut self.normals {
            v.push(normal);
        }
        if let Some(v) = &mut self.colors {
            v.push(color);
        }
        Pushed::Kept
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
