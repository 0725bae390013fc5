//! The point cloud as the rest of the pipeline sees it.

/// A cloud as read from a file: positions in the user's coordinates, plus optional per-point
/// attributes (same length as `positions` when present).
///
/// Positions are `f32` relative to `origin` (`f64`): a point's user coordinates are
/// `origin + position`. Readers put far-off (e.g. georeferenced) clouds' offset there, so that
/// the `f32` positions keep their precision; it is zero otherwise.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    pub positions: Vec<[f32; 3]>,
    /// Added to every position (and to the reconstructed mesh's) to give user coordinates.
    pub origin: [f64; 3],
    pub normals: Option<Vec<[f32; 3]>>,
    /// RGBA in 0..=255.
    pub colors: Option<Vec<[u8; 4]>>,
}

/// Axis-aligned bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    pub min: [f32; 3],
    pub max: [f32; 3],
}

impl Bounds {
    /// Bounds of `points`, or `None` when there are none.
    pub fn of(points: &[[f32; 3]]) -> Option<Bounds> {
        Bounds::of_iter(points)
    }
    /// [`Bounds::of`] for points chosen on the way (a filter), without collecting them.
    pub fn of_iter<'a>(points: impl IntoIterator<Item = &'a [f32; 3]>) -> Option<Bounds> {
        let mut points = points.into_iter();
        let first = *points.next()?;
        let mut b = Bounds { min: first, max: first };
        for p in points {
            for a in 0..3 {
                b.min[a] = b.min[a].min(p[a]);
                b.max[a] = b.max[a].max(p[a]);
            }
        }
        Some(b)
    }
    pub fn extent(&self) -> [f32; 3] {
        [self.max[0] - self.min[0], self.max[1] - self.min[1], self.max[2] - self.min[2]]
    }
    pub fn center(&self) -> [f32; 3] {
        [
            0.5 * (self.min[0] + self.max[0]),
            0.5 * (self.min[1] + self.max[1]),
            0.5 * (self.min[2] + self.max[2]),
        ]
    }
    pub fn longest_side(&self) -> f32 {
        let e = self.extent();
        e[0].max(e[1]).max(e[2])
    }
}

impl PointCloud {
    pub fn len(&self) -> usize {
        self.positions.len()
    }
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
    /// Bounds of the positions (relative to `origin`), or `None` for an empty cloud.
    pub fn bounds(&self) -> Option<Bounds> {
        Bounds::of(&self.positions)
    }
}

/// Why a cloud cannot be reconstructed at all.
#[derive(Clone, Debug, PartialEq)]
pub enum CloudError {
    /// Fewer points than any surface needs.
    TooFewPoints { count: usize, needed: usize },
    /// Every point at one position (or the bounds are not finite).
    Degenerate,
    /// The points lie on one line: their spread along the second principal axis is `ratio` of
    /// that along the first.
    Collinear { ratio: f64 },
    /// The points lie on one plane: their spread along the third principal axis is `ratio` of
    /// that along the first.
    Flat { ratio: f64 },
    /// A line or a plane only because of `count` points far from the rest (the farthest
    /// `distance` from the others' middle, in the cloud's units): without them the cloud has
    /// a surface. Stray points the filter was told to keep (or that it could not judge).
    FarPoints { count: usize, distance: f64, shape: &'static str },
}

impl std::fmt::Display for CloudError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CloudError::TooFewPoints { count, needed } => {
                write!(f, "the cloud has {count} point(s); a surface needs at least {needed}")
            }
            CloudError::Degenerate => write!(f, "all points are at the same position: there is no surface to reconstruct"),
            CloudError::Collinear { ratio } => write!(
                f,
                "all points lie on one line (whatever its direction: the spread across it is {ratio:.1e} of the spread \
                 along it): there is no surface to reconstruct"
            ),
            CloudError::FarPoints { count, distance, shape } => write!(
                f,
                "the cloud looks like {shape} only because of {count} point(s) far from the rest (the farthest \
                 {distance:.3e} from the middle of the others); without them it has a surface: let the stray-point \
                 filter drop them (--outliers 2, the default; the page's \"Drop stray points\") or remove them from the file"
            ),
            CloudError::Flat { ratio } => write!(
                f,
                "all points lie on one plane (whatever its tilt: the spread across it is {ratio:.1e} of the spread \
                 along it): a flat patch encloses nothing, so there is no surface to reconstruct; a scan of a real \
                 surface has some relief or noise"
            ),
        }
    }
}

impl std::error::Error for CloudError {}

/// Coordinates at least this large (in magnitude) are read relative to an origin (see
/// [`origin_for`]): beyond it an `f32` keeps less than about 1e-3 of absolute precision.
pub const FAR_COORDINATE: f64 = 1e4;

/// The origin a reader should subtract from `f64` coordinates before storing them as `f32`,
/// chosen from the cloud's first point `first`: per axis, that coordinate rounded to a whole
/// unit when its magnitude is at least [`FAR_COORDINATE`], else 0, so that ordinary clouds
/// keep their coordinates as they are. Points near the first then keep `f32` precision relative
/// to the cloud's size, wherever it lies: the difference of two nearby `f64`s is exact, so the
/// detail the file's `f64` values hold survives at any magnitude (an upper cut at 1e15 once
/// made such clouds collapse onto a few `f32` values). Beyond 2^52 an `f64` is already a whole
/// number, and rounding leaves it as it is.
pub fn origin_for(first: [f64; 3]) -> [f64; 3] {
    first.map(|c| if c.is_finite() && c.abs() >= FAR_COORDINATE { c.round() } else { 0.0 })
}

/// Spread across a cloud's thinnest principal axis, as a fraction of the spread along its
/// widest, below which it is taken as flat (and, for the middle axis, as a line). Rounding to
/// `f32` leaves about 1e-7; a real scan's relief or noise is far above 1e-4.
pub const FLAT_RATIO: f64 = 1e-4;

/// The standard deviations of `points` along their principal axes, largest first (square
/// roots of the covariance matrix's eigenvalues, in f64).
///
/// Why principal axes: a flatness check on the bounding box only sees clouds flat along x, y
/// or z; a tilted plane or line has a box of full size on every axis, passed, and came out a
/// needle-like mesh with exit status 0.
pub fn principal_spread(points: &[[f32; 3]]) -> [f64; 3] {
    if points.is_empty() {
        return [0.0; 3];
    }
    let n = points.len() as f64;
    let cov = crate::eigen3::scatter(points.iter().copied()).1.map(|row| row.map(|v| v / n));
    let mut ev = crate::eigen3::symmetric(cov).map_or([0.0; 3], |(values, _)| values).map(|v| v.max(0.0).sqrt());
    ev.sort_by(|a, b| b.total_cmp(a));
    ev
}

/// Why `points` have no surface by their principal spreads (a line or a plane), if they have none.
fn shape_error(points: &[[f32; 3]]) -> Option<CloudError> {
    let spread = principal_spread(points);
    if spread[0] > 0.0 {
        let (second, third) = (spread[1] / spread[0], spread[2] / spread[0]);
        if second <= FLAT_RATIO {
            return Some(CloudError::Collinear { ratio: second });
        }
        if third <= FLAT_RATIO {
            return Some(CloudError::Flat { ratio: third });
        }
    }
    None
}

/// Where a line or a plane (`shape`) is so only because of a few far points (at most 1 % of
/// the cloud, the farthest from its per-axis median), the error that says so; else None. A
/// sphere with one stray point 1e7 away has its spread all along that point's direction, and
/// "all points lie on one line" sent the user looking for the wrong problem.
fn far_points(points: &[[f32; 3]], shape: &CloudError) -> Option<CloudError> {
    let shape = match shape {
        CloudError::Collinear { .. } => "a line",
        CloudError::Flat { .. } => "a plane",
        _ => return None,
    };
    let median = [0, 1, 2].map(|a| {
        let mut v: Vec<f32> = points.iter().map(|p| p[a]).collect();
        let mid = v.len() / 2;
        *v.select_nth_unstable_by(mid, f32::total_cmp).1 as f64
    });
    let dist = |p: &[f32; 3]| (0..3).map(|a| (p[a] as f64 - median[a]).powi(2)).sum::<f64>().sqrt();
    let mut order: Vec<(f64, usize)> = points.iter().enumerate().map(|(i, p)| (dist(p), i)).collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0));
    let most = (points.len() / 100).max(1);
    for count in 1..=most.min(points.len().saturating_sub(Normalization::MIN_POINTS)) {
        let kept: Vec<[f32; 3]> = order[..points.len() - count].iter().map(|&(_, i)| points[i]).collect();
        if shape_error(&kept).is_none() {
            return Some(CloudError::FarPoints { count, distance: order[points.len() - 1].0, shape });
        }
        // Only a clear gap makes a point "far": stop where the next one is near the others.
        if count < most && order[points.len() - 1 - count].0 < 10.0 * order[(points.len() - 1) / 2].0.max(f64::MIN_POSITIVE) {
            return None;
        }
    }
    None
}

/// The similarity that maps a cloud's positions (relative to its `origin`) to the network's
/// unit cube (bounding-box centre at 0, longest side 1) and back, in f64.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Normalization {
    pub center: [f64; 3],
    pub scale: f64,
}

impl Normalization {
    /// Fewest points accepted for reconstruction.
    pub const MIN_POINTS: usize = 4;

    /// Whether `count` points are enough for any surface ([`Self::MIN_POINTS`]).
    pub fn enough_points(count: usize) -> Result<(), CloudError> {
        if count < Self::MIN_POINTS {
            return Err(CloudError::TooFewPoints { count, needed: Self::MIN_POINTS });
        }
        Ok(())
    }

    /// The normalisation of `cloud`, or why it has none: too few points, all at one place, or
    /// all on one line or plane in any orientation (see [`principal_spread`]).
    pub fn of(cloud: &PointCloud) -> Result<Normalization, CloudError> {
        Self::enough_points(cloud.len())?;
        let b = cloud.bounds().ok_or(CloudError::TooFewPoints { count: 0, needed: Self::MIN_POINTS })?;
        let center = [0, 1, 2].map(|a| 0.5 * (b.min[a] as f64 + b.max[a] as f64));
        let scale = (0..3).map(|a| b.max[a] as f64 - b.min[a] as f64).fold(0.0, f64::max);
        if !(scale > 0.0 && scale.is_finite()) {
            return Err(CloudError::Degenerate);
        }
        if let Some(e) = shape_error(&cloud.positions) {
            return Err(far_points(&cloud.positions, &e).unwrap_or(e));
        }
        Ok(Normalization { center, scale })
    }

    /// User coordinates → unit cube.
    pub fn forward(&self, p: [f32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|a| ((p[a] as f64 - self.center[a]) / self.scale) as f32)
    }

    /// Unit cube → user coordinates.
    pub fn inverse(&self, p: [f32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|a| (p[a] as f64 * self.scale + self.center[a]) as f32)
    }
}

/// At most `max` of `points`, chosen uniformly at random (seeded, so runs repeat), in their
/// original order. Returns the input unchanged when it is small enough.
pub fn subsample(points: &[[f32; 3]], max: usize, seed: u64) -> Vec<[f32; 3]> {
    if points.len() <= max {
        return points.to_vec();
    }
    // Selection sampling (Knuth's algorithm S): one pass, exact count, no index buffer.
    let mut rng = crate::rng::SplitMix64(seed);
    let mut out = Vec::with_capacity(max);
    let n = points.len();
    for (i, p) in points.iter().enumerate() {
        let needed = max - out.len();
        if needed == 0 {
            break;
        }
        if ((n - i) as f64) * rng.unit() < needed as f64 {
            out.push(*p);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(points: Vec<[f32; 3]>) -> PointCloud {
        PointCloud { positions: points, ..Default::default() }
    }

    #[test]
    fn normalization_round_trips_and_fits_the_unit_cube() {
        let c = cloud(vec![[10.0, 20.0, 30.0], [12.0, 21.0, 30.5], [11.0, 20.5, 30.0], [10.5, 20.0, 30.2]]);
        let n = Normalization::of(&c).unwrap();
        assert_eq!(n.scale, 2.0);
        for p in &c.positions {
            let q = n.forward(*p);
            assert!(q.iter().all(|v| v.abs() <= 0.5 + 1e-6), "{q:?}");
            let back = n.inverse(q);
            for a in 0..3 {
                assert!((back[a] - p[a]).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn degenerate_clouds_are_errors() {
        assert_eq!(Normalization::of(&cloud(vec![[1.0; 3]])), Err(CloudError::TooFewPoints { count: 1, needed: 4 }));
        assert_eq!(Normalization::of(&cloud(vec![[1.0; 3]; 10])), Err(CloudError::Degenerate));
    }

    #[test]
    fn subsample_keeps_exactly_max_points_in_order() {
        let pts: Vec<[f32; 3]> = (0..1000).map(|i| [i as f32, 0.0, 0.0]).collect();
        let s = subsample(&pts, 100, 7);
        assert_eq!(s.len(), 100);
        assert!(s.windows(2).all(|w| w[0][0] < w[1][0]));
        assert_eq!(subsample(&pts, 5000, 7).len(), 1000);
    }
}
