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

/// Rescaled rows `v_d / s_d`, so that distances are plain squared distances.
fn rescale(m: &[f64], inv_s: &[f64]) -> Vec<f64> {
    m.chunks_exact(inv_s.len()).flat_map(|r| r.iter().zip(inv_s).map(|(v, w)| v * w)).collect()
}

#[inline]
fn k_scaled(u: &[f64], v: &[f64]) -> f64 {
    let mut d2 = 0.0;
    for (a, b) in u.iter().zip(v) {
        let t = a - b;
        d2 += t * t;
    }
    (-0.5 * d2).exp()
}

/// Rows of the result per unit of work handed to a thread.
const ROWS: usize = 8;

/// Cross kernel matrix `K(A, B)` (`na × nb`) between the rows of `a` (`na × d`) and `b`
/// (`nb × d`); `inv_s` holds `1/s_d` (length `d`). Threaded over rows natively.
pub fn cross(a: &[f64], b: &[f64], inv_s: &[f64]) -> Vec<f64> {
    let d = inv_s.len();
    assert!(d > 0 && a.len().is_multiple_of(d) && b.len().is_multiple_of(d), "kernel::cross: shapes");
    // Rescale once so the inner loop is a plain squared distance.
    let (sa, sb) = (rescale(a, inv_s), rescale(b, inv_s));
    let (na, nb) = (a.len() / d, b.len() / d);
    let mut k = vec![0.0; na * nb];
    if nb == 0 {
        return k;
    }
    let work = (ROWS * nb * (d + 8)) as f64;
    super::linalg::par_row_units(&mut k, nb, na, ROWS, super::linalg::max_threads(), &|_| work, |u0, u1, out| {
        for (ra, orow) in sa[u0 * ROWS * d..(u1 * ROWS).min(na) * d].chunks_exact(d).zip(out.chunks_mut(nb)) {
            for (o, rb) in orow.iter_mut().zip(sb.chunks_exact(d)) {
                *o = k_scaled(ra, rb);
            }
        }
    });
    k
}

/// [`cross`] by the expansion `‖u − v‖² = ‖u‖² + ‖v‖² − 2uᵀv` of the rescaled rows, whose
/// `uᵀv` is one blocked GEMM (the [`super::linalg`] kernel, threaded and SIMD): several times
/// faster than the differences for the mesher's ~300k queries. In f64 the cancellation costs
/// about `ε (‖u‖² + ‖v‖²)` of the squared distance (1e-15 relative for features of size ~1-10,
/// far below anything exp(−d²/2) shows); the squared distance is clamped at 0. For prediction
/// only: the objective and its gradient keep the difference form (the module docs).
pub fn cross_expanded(a: &[f64], b: &[f64], inv_s: &[f64]) -> Vec<f64> {
    let d = inv_s.len();
    assert!(d > 0 && a.len().is_multiple_of(d) && b.len().is_multiple_of(d), "kernel::cross_expanded: shapes");
    let (sa, sb) = (rescale(a, inv_s), rescale(b, inv_s));
    let (na, nb) = (a.len() / d, b.len() / d);
    if na == 0 || nb == 0 {
        return vec![0.0; na * nb];
    }
    let norms = |m: &[f64]| -> Vec<f64> { m.chunks_exact(d).map(|r| r.iter().map(|v| v * v).sum()).collect() };
    let (a2, b2) = (norms(&sa), norms(&sb));
    let mut k = super::linalg::matmul_nt(&sa, &sb, na, d, nb);
    let work = (ROWS * nb * 8) as f64;
    super::linalg::par_row_units(&mut k, nb, na, ROWS, super::linalg::max_threads(), &|_| work, |u0, _u1, out| {
        for (i, orow) in (u0 * ROWS..).zip(out.chunks_mut(nb)) {
            for (o, bj) in orow.iter_mut().zip(&b2) {
                *o = (-0.5 * (a2[i] + bj - 2.0 * *o).max(0.0)).exp();
            }
        }
    });
    k
}

/// `K(A, A)` (`n × n`) for the rows of `a`: the upper triangle, mirrored — exactly symmetric,
/// and entry for entry what [`cross`]`(a, a, inv_s)` gives (`(u − v)² = (v − u)²` exactly).
pub fn cross_sym(a: &[f64], inv_s: &[f64]) -> Vec<f64> {
    let d = inv_s.len();
    assert!(d > 0 && a.len().is_multiple_of(d), "kernel::cross_sym: shapes");
    let sa = rescale(a, inv_s);
    let n = a.len() / d;
    let mut k = vec![0.0; n * n];
    if n == 0 {
        return k;
    }
    let work = |u: usize| (ROWS * (n - (u * ROWS).min(n)) * (d + 8)) as f64;
    super::linalg::par_row_units(&mut k, n, n, ROWS, super::linalg::max_threads(), &work, |u0, u1, out| {
        for i in u0 * ROWS..(u1 * ROWS).min(n) {
            let ri = &sa[i * d..(i + 1) * d];
            let orow = &mut out[(i - u0 * ROWS) * n..(i - u0 * ROWS) * n + n];
            for (j, rj) in sa.chunks_exact(d).enumerate().skip(i) {
                orow[j] = k_scaled(ri, rj);
            }
        }
    });
    super::linalg::mirror_upper(&mut k, n);
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
    let k = cross_sym(z, &inv_scales(log_s));
    debug_assert_eq!(k.len(), m * m);
    k
}
