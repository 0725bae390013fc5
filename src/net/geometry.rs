//! The geometry both implementations share (plane coordinates, cell indices, the cell → points
//! lists the encoder pools over), once, because it is where [`super::cpu`] and [`super::gpu`]
//! must agree bit for bit: a point moved across a cell boundary changes the result
//! discontinuously, everything else only by rounding.

/// The three planes as `(a, b)` axis pairs, in storage order: xz, xy, yz. The plane coordinate
/// `u` comes from `p[a]`, `v` from `p[b]`.
pub const PLANES: [(usize, usize); 3] = [(0, 2), (0, 1), (1, 2)];

/// Upper clamp of the plane coordinates: PyTorch's `1 - 1e-5` (a double) rounded to f32.
pub const UV_MAX: f32 = (1.0f64 - 1e-5) as f32;

/// Feature planes: `[3][c_dim][reso][reso]` f32, planes in [`PLANES`] order, row (v) major.
#[derive(Clone, Debug, PartialEq)]
pub struct Planes {
    pub c_dim: usize,
    pub reso: usize,
    pub data: Vec<f32>,
}

impl Planes {
    pub fn zeros(c_dim: usize, reso: usize) -> Planes {
        Planes { c_dim, reso, data: vec![0.0; 3 * c_dim * reso * reso] }
    }
}

/// Plane coordinates `(u, v)` of `p` on each plane, exactly as the contract computes them in
/// f32: an IEEE division by `divisor` (= `(1 + padding)` rounded to f32), `+ 0.5`, then the clamp
/// to `[0, UV_MAX]`. Non-finite input gives NaN coordinates, which [`cell_index`] maps to cell 0.
#[inline]
pub fn plane_uv(p: [f32; 3], divisor: f32) -> [[f32; 2]; 3] {
    let c = |x: f32| (x / divisor + 0.5).clamp(0.0, UV_MAX);
    PLANES.map(|(a, b)| [c(p[a]), c(p[b])])
}

/// The flat cell `iy * reso + ix` of plane coordinates `uv` (`ix = floor(u * reso)`, f32).
#[inline]
pub fn cell_index(uv: [f32; 2], reso: usize) -> usize {
    // `as usize` saturates (NaN → 0), and the min keeps hostile input in range.
    let ix = ((uv[0] * reso as f32).floor() as usize).min(reso - 1);
    let iy = ((uv[1] * reso as f32).floor() as usize).min(reso - 1);
    iy * reso + ix
}

/// The encoder's pooling structure: for every non-empty (plane, cell), the points inside it,
/// in increasing point order (a stable counting sort, O(N + R²)), so sums and maxima over a
/// cell are taken in a fixed order and results are deterministic on any device.
#[derive(Clone, Debug, PartialEq)]
pub struct Cells {
    /// `cell_of[3 n + p]`: the index (into `cell_start`/`cell_plane_cell`) of point n's cell on
    /// plane p.
    pub cell_of: Vec<u32>,
    /// CSR offsets: the points of cell k are `points[cell_start[k]..cell_start[k + 1]]`.
    pub cell_start: Vec<u32>,
    /// Point indices grouped by cell (each point appears once per plane: 3 N entries).
    pub points: Vec<u32>,
    /// `p * reso² + iy * reso + ix` of cell k: where its mean goes in the scattered planes.
    pub cell_plane_cell: Vec<u32>,
}

impl Cells {
    /// Groups `points` (normalised coordinates) by cell on each plane.
    pub fn new(points: &[[f32; 3]], reso: usize, divisor: f32) -> Cells {
        let rr = reso * reso;
        let n = points.len();
        // Flat (plane, cell) of every (point, plane), then a counting sort by it.
        let flat: Vec<usize> = points
            .iter()
            .flat_map(|&p| {
                let uv = plane_uv(p, divisor);
                [0, 1, 2].map(|k| k * rr + cell_index(uv[k], reso))
            })
            .collect();
        let mut count = vec![0u32; 3 * rr];
        for &f in &flat {
            count[f] += 1;
        }
        // Compact numbering of the non-empty cells, in flat order.
        let mut compact = vec![u32::MAX; 3 * rr];
        let mut cell_start = Vec::new();
        let mut cell_plane_cell = Vec::new();
        let mut acc = 0u32;
        for (f, &c) in count.iter().enumerate() {
            if c > 0 {
                compact[f] = cell_start.len() as u32;
                cell_start.push(acc);
                cell_plane_cell.push(f as u32);
                acc += c;
            }
        }
        cell_start.push(acc);
        let mut fill: Vec<u32> = cell_start[..cell_start.len() - 1].to_vec();
        let mut pts = vec![0u32; 3 * n];
        let mut cell_of = vec![0u32; 3 * n];
        for (i, &f) in flat.iter().enumerate() {
            let k = compact[f] as usize;
            cell_of[i] = k as u32;
            pts[fill[k] as usize] = (i / 3) as u32;
            fill[k] += 1;
        }
        Cells { cell_of, cell_start, points: pts, cell_plane_cell }
    }

    /// Number of non-empty (plane, cell) pairs.
    pub fn len(&self) -> usize {
        self.cell_plane_cell.len()
    }

    pub fn is_empty(&self) -> bool {
        self.cell_plane_cell.is_empty()
    }

    /// The points of non-empty cell k.
    pub fn points_of(&self, k: usize) -> &[u32] {
        &self.points[self.cell_start[k] as usize..self.cell_start[k + 1] as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uv_clamps_and_cells_stay_in_range() {
        let d = 1.1f32;
        let uv = plane_uv([10.0, -10.0, f32::NAN], d);
        assert_eq!(uv[1], [UV_MAX, 0.0]);
        assert_eq!(cell_index(uv[0], 8), 7); // NaN v → row 0
        assert_eq!(cell_index([UV_MAX, UV_MAX], 64), 64 * 64 - 1);
    }

    #[test]
    fn cells_group_points_in_order() {
        let pts = [[0.0f32, 0.0, 0.0], [0.4, 0.4, 0.4], [0.001, 0.001, 0.001], [-0.4, 0.0, 0.4]];
        let c = Cells::new(&pts, 4, 1.1);
        assert_eq!(c.points.len(), 12);
        for k in 0..c.len() {
            let ps = c.points_of(k);
            assert!(ps.windows(2).all(|w| w[0] < w[1]));
            for &p in ps {
                let plane = c.cell_plane_cell[k] as usize / 16;
                assert_eq!(c.cell_of[3 * p as usize + plane] as usize, k);
            }
        }
        // Points 0 and 2 share their cells on every plane.
        assert_eq!(c.cell_of[0..3], c.cell_of[6..9]);
    }
}
