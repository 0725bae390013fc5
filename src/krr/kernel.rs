//! The Gaussian kernel with one length-scale per feature dimension (`docs/method.md` §0):
//!
//! `k(x, z) = exp(-½ Σ_d (x_d − z_d)² / s_d²)`, so `k(x, x) = 1` and `Tr(K) = n`.
//!
//! Distances are computed as sums of squared *differences* of the rescaled coordinates, not by
//! the `‖x‖² + ‖z‖² − 2xᵀz` expansion: slower on a GPU, but free of cancellation, which is what a
//! reference is for. Matrices are row-major f64.

/// `1 / s_d` for every dimension, from the log length-scales.
pub fn inv_scales(log_s: &[f64]) -> Vec<f64> {
    log_s.iter().map(|l| (-l).exp()).collect()
}

/// `k(x, z)` for one pair of points, given `1/s` per dimension.
#[inline]
pub fn k_pair(x: &[f64], z: &[f64], inv_s: &[f64]) -> f64 {
    let mut d2 = 0.0;
    for ((a, b), w) in x.iter().zip(z).zip(inv_s) {
        let t = (a - b) * w;
        d2 += t * t;
    }
    (-0.5 * d2).exp()
}

/// Cross kernel matrix `K(A, B)` (`na × nb`) between the rows of `a` (`na × d`) and `b`
/// (`nb × d`); `inv_s` holds `1/s_d` (length `d`).
pub fn cross(a: &[f64], b: &[f64], inv_s: &[f64]) -> Vec<f64> {
    let d = inv_s.len();
    assert!(d > 0 && a.len().is_multiple_of(d) && b.len().is_multiple_of(d), "kernel::cross: shapes");
    // Rescale once so the inner loop is a plain squared distance.
    let scale = |m: &[f64]| -> Vec<f64> {
        m.chunks_exact(d).flat_map(|r| r.iter().zip(inv_s).map(|(v, w)| v * w)).collect()
    };
    let (sa, sb) = (scale(a), scale(b));
    let nb = b.len() / d;
    let mut k = Vec::with_capacity(a.len() / d * nb);
    for ra in sa.chunks_exact(d) {
        for rb in sb.chunks_exact(d) {
            let mut d2 = 0.0;
            for (u, v) in ra.iter().zip(rb) {
                let t = u - v;
                d2 += t * t;
            }
            k.push((-0.5 * d2).exp());
        }
    }
    k
}

/// `K_nm = k(X, Z)` (`n × m`) for `x: n × d`, `z: m × d`.
pub fn k_nm(x: &[f64], z: &[f64], log_s: &[f64]) -> Vec<f64> {
    cross(x, z, &inv_scales(log_s))
}

/// `K_mm = k(Z, Z)` (`m × m`, exactly symmetric, unit diagonal), without jitter.
pub fn k_mm(z: &[f64], log_s: &[f64]) -> Vec<f64> {
    let d = log_s.len();
    let m = z.len() / d;
    let mut k = cross(z, z, &inv_scales(log_s));
    super::linalg::symmetrize(&mut k, m);
    k
}
