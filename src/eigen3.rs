//! The eigen-decomposition of a symmetric 3×3 matrix, by cyclic Jacobi rotations: the one
//! solver behind the flatness check's principal spreads (`cloud::principal_spread`), the planes
//! of point neighbourhoods ([`plane`]: PCA normals, the stray-point filter's edge test) and the
//! mesh fit's plane normals (`mesh::fit`). A few sweeps converge to f64 precision for a 3×3;
//! the loop is bounded whatever the input.

/// The centroid of `points` and their scatter matrix (the sum of the outer products of their
/// offsets from it: `n` times their covariance); the origin and zero for no points.
pub fn scatter(points: impl ExactSizeIterator<Item = [f32; 3]> + Clone) -> ([f64; 3], [[f64; 3]; 3]) {
    let n = points.len().max(1) as f64;
    let mut c = [0.0f64; 3];
    for p in points.clone() {
        (0..3).for_each(|a| c[a] += p[a] as f64 / n);
    }
    let mut cov = [[0.0f64; 3]; 3];
    for p in points {
        let d = [0, 1, 2].map(|a| p[a] as f64 - c[a]);
        for r in 0..3 {
            for s in 0..3 {
                cov[r][s] += d[r] * d[s];
            }
        }
    }
    (c, cov)
}

/// The least-squares plane through `points`: their centroid and its unit normal, the
/// eigenvector of their [`scatter`] with the smallest eigenvalue; None for fewer than 3 points
/// or a NaN or an infinity among them. The PCA normals (`orient::pca_normals`) and the
/// stray-point filter's edge test (`outliers`) take their planes from here; the mesh fit's
/// (`mesh::fit`) weighs each neighbour by its distance and keeps its own sums.
pub fn plane(points: impl ExactSizeIterator<Item = [f32; 3]> + Clone) -> Option<([f64; 3], [f64; 3])> {
    if points.len() < 3 {
        return None;
    }
    let (c, cov) = scatter(points);
    let (values, vectors) = symmetric(cov)?;
    let smallest = (0..3).min_by(|&a, &b| values[a].total_cmp(&values[b]))?;
    Some((c, vectors[smallest]))
}

/// Eigenvalues (diagonal order, unsorted) and unit eigenvectors (`vectors[i]` belongs to
/// `values[i]`) of the symmetric matrix `a`; None when `a` has a NaN or an infinity.
pub fn symmetric(mut a: [[f64; 3]; 3]) -> Option<([f64; 3], [[f64; 3]; 3])> {
    if a.iter().flatten().any(|x| !x.is_finite()) {
        return None;
    }
    // Columns of v are the eigenvectors.
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..64 {
        let off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        let diag = a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2];
        if !(off > 1e-32 * diag) {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            // The rotation that zeroes a[p][q] (Golub & Van Loan, the symmetric Schur step).
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            for row in a.iter_mut() {
                let (kp, kq) = (row[p], row[q]);
                row[p] = c * kp - s * kq;
                row[q] = s * kp + c * kq;
            }
            for k in 0..3 {
                let (pk, qk) = (a[p][k], a[q][k]);
                a[p][k] = c * pk - s * qk;
                a[q][k] = s * pk + c * qk;
            }
            for row in v.iter_mut() {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    let values = [a[0][0], a[1][1], a[2][2]];
    let vectors = [0, 1, 2].map(|i| {
        let e = [v[0][i], v[1][i], v[2][i]];
        let len = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
        e.map(|x| x / len)
    });
    Some((values, vectors))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rotated_diagonal_matrix() {
        // diag(3, 1, 2) rotated about z by (0.6, 0.8): the vectors are the rotated axes.
        let (c, s) = (0.6f64, 0.8f64);
        let r = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]];
        let d = [3.0, 1.0, 2.0];
        let mut a = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                a[i][j] = (0..3).map(|k| r[i][k] * d[k] * r[j][k]).sum();
            }
        }
        let (values, vectors) = symmetric(a).unwrap();
        for (value, vector) in values.iter().zip(&vectors) {
            let k = d.iter().position(|x| (x - value).abs() < 1e-12).expect("an eigenvalue");
            let axis = [r[0][k], r[1][k], r[2][k]];
            let dot: f64 = (0..3).map(|i| axis[i] * vector[i]).sum();
            assert!((dot.abs() - 1.0).abs() < 1e-12, "{values:?} {vectors:?}");
        }
        assert_eq!(symmetric([[f64::NAN; 3]; 3]), None);
    }
}
