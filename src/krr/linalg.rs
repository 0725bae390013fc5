//! Small dense f64 linear algebra on row-major slices, hand-written (pure std, wasm32-friendly).
//!
//! Conventions: a matrix with `r` rows and `c` columns is a `&[f64]` of length `r * c`, element
//! `(i, j)` at `i * c + j`. Dimensions are passed explicitly and *asserted*: a length mismatch
//! here is a bug in the caller (the public KRR entry points validate user data before reaching
//! this module). Numerical failure — a matrix that is not positive definite — is an error value,
//! [`KrrError::NotPositiveDefinite`], never a panic.
//!
//! Only what `docs/method.md` §5–§6 need, written for correctness first; the one hot spot, the
//! n·m² products (`A = K_nmᵀ K_nm` and `K_nm W`), goes through a cache-tiled kernel
//! ([`matmul_acc`]) so the reference stays usable at the paper's sizes.

use super::KrrError;

/// Dot product of two equal-length slices.
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len(), "dot: length mismatch");
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Transpose of an `r × c` matrix (returns `c × r`).
pub fn transpose(a: &[f64], r: usize, c: usize) -> Vec<f64> {
    assert_eq!(a.len(), r * c, "transpose: length");
    let mut t = vec![0.0; r * c];
    for i in 0..r {
        for j in 0..c {
            t[j * r + i] = a[i * c + j];
        }
    }
    t
}

/// The `n × n` identity.
pub fn identity(n: usize) -> Vec<f64> {
    let mut m = vec![0.0; n * n];
    for i in 0..n {
        m[i * n + i] = 1.0;
    }
    m
}

/// `y = A x` for `A` of shape `r × c`.
pub fn matvec(a: &[f64], x: &[f64], r: usize, c: usize) -> Vec<f64> {
    assert_eq!(a.len(), r * c, "matvec: matrix length");
    assert_eq!(x.len(), c, "matvec: vector length");
    (0..r).map(|i| dot(&a[i * c..(i + 1) * c], x)).collect()
}

/// `y = Aᵀ x` for `A` of shape `r × c` (so `x` has length `r`, `y` length `c`).
pub fn matvec_t(a: &[f64], x: &[f64], r: usize, c: usize) -> Vec<f64> {
    assert_eq!(a.len(), r * c, "matvec_t: matrix length");
    assert_eq!(x.len(), r, "matvec_t: vector length");
    let mut y = vec![0.0; c];
    for i in 0..r {
        let xi = x[i];
        for (yj, aij) in y.iter_mut().zip(&a[i * c..(i + 1) * c]) {
            *yj += xi * aij;
        }
    }
    y
}

/// `C += A B` with `A: n × k`, `B: k × p`, `C: n × p` — the tiled kernel behind every product.
///
/// Tiles of `B` (128 × 256, 256 KiB) stay in L2 while four rows of `C` at a time sweep them, so
/// each loaded element of `B` feeds four multiply-adds and the inner loop is a contiguous,
/// auto-vectorisable AXPY.
pub fn matmul_acc(c: &mut [f64], a: &[f64], b: &[f64], n: usize, k: usize, p: usize) {
    gemm_tiled(c, a, b, n, k, p, false);
}

const KB: usize = 128;
const PB: usize = 256;

/// The kernel of [`matmul_acc`]. With `upper_only`, tiles of `C` lying entirely below the
/// diagonal are skipped (for symmetric results, which the caller then mirrors); entries of a
/// tile are always complete or untouched, never partial.
fn gemm_tiled(c: &mut [f64], a: &[f64], b: &[f64], n: usize, k: usize, p: usize, upper_only: bool) {
    assert_eq!(a.len(), n * k, "matmul: A length");
    assert_eq!(b.len(), k * p, "matmul: B length");
    assert_eq!(c.len(), n * p, "matmul: C length");
    for k0 in (0..k).step_by(KB) {
        let k1 = (k0 + KB).min(k);
        for p0 in (0..p).step_by(PB) {
            let p1 = (p0 + PB).min(p);
            let len = p1 - p0;
            let mut i = 0;
            while i + 4 <= n {
                if upper_only && p1 <= i {
                    i += 4;
                    continue;
                }
                let block = &mut c[i * p..(i + 4) * p];
                let (r0, rest) = block.split_at_mut(p);
                let (r1, rest) = rest.split_at_mut(p);
                let (r2, r3) = rest.split_at_mut(p);
                let r0 = &mut r0[p0..p1];
                let r1 = &mut r1[p0..p1];
                let r2 = &mut r2[p0..p1];
                let r3 = &mut r3[p0..p1];
                for kk in k0..k1 {
                    let a0 = a[i * k + kk];
                    let a1 = a[(i + 1) * k + kk];
                    let a2 = a[(i + 2) * k + kk];
                    let a3 = a[(i + 3) * k + kk];
                    let brow = &b[kk * p + p0..kk * p + p1];
                    let (r0, r1, r2, r3) = (&mut r0[..len], &mut r1[..len], &mut r2[..len], &mut r3[..len]);
                    for t in 0..len {
                        let bv = brow[t];
                        r0[t] += a0 * bv;
                        r1[t] += a1 * bv;
                        r2[t] += a2 * bv;
                        r3[t] += a3 * bv;
                    }
                }
                i += 4;
            }
            while i < n {
                if !(upper_only && p1 <= i) {
                    let row = &mut c[i * p + p0..i * p + p1];
                    for kk in k0..k1 {
                        let av = a[i * k + kk];
                        let brow = &b[kk * p + p0..kk * p + p1];
                        for (x, bv) in row.iter_mut().zip(brow) {
                            *x += av * bv;
                        }
                    }
                }
                i += 1;
            }
        }
    }
}

/// `A B` with `A: n × k`, `B: k × p`.
pub fn matmul(a: &[f64], b: &[f64], n: usize, k: usize, p: usize) -> Vec<f64> {
    let mut c = vec![0.0; n * p];
    matmul_acc(&mut c, a, b, n, k, p);
    c
}

/// `Aᵀ B` with `A: n × k`, `B: n × p` (result `k × p`).
pub fn matmul_tn(a: &[f64], b: &[f64], n: usize, k: usize, p: usize) -> Vec<f64> {
    let at = transpose(a, n, k);
    matmul(&at, b, k, n, p)
}

/// `A Bᵀ` with `A: n × k`, `B: p × k` (result `n × p`).
pub fn matmul_nt(a: &[f64], b: &[f64], n: usize, k: usize, p: usize) -> Vec<f64> {
    let bt = transpose(b, p, k);
    matmul(a, &bt, n, k, p)
}

/// The Gram matrix `Aᵀ A` (`k × k`, exactly symmetric) of `A: n × k`. Half the work of
/// [`matmul_tn`]: only tiles touching the upper triangle are computed, then mirrored.
pub fn gram(a: &[f64], n: usize, k: usize) -> Vec<f64> {
    let at = transpose(a, n, k);
    let mut c = vec![0.0; k * k];
    gemm_tiled(&mut c, &at, a, k, n, k, true);
    mirror_upper(&mut c, k);
    c
}

/// Copy the upper triangle of an `n × n` matrix onto its lower triangle.
pub fn mirror_upper(a: &mut [f64], n: usize) {
    assert_eq!(a.len(), n * n, "mirror_upper: length");
    for i in 0..n {
        for j in 0..i {
            a[i * n + j] = a[j * n + i];
        }
    }
}

/// Replace an `n × n` matrix by its symmetric part `(A + Aᵀ)/2` (removes rounding asymmetry).
pub fn symmetrize(a: &mut [f64], n: usize) {
    assert_eq!(a.len(), n * n, "symmetrize: length");
    for i in 0..n {
        for j in 0..i {
            let v = 0.5 * (a[i * n + j] + a[j * n + i]);
            a[i * n + j] = v;
            a[j * n + i] = v;
        }
    }
}

/// `Tr(A)` of an `n × n` matrix.
pub fn trace(a: &[f64], n: usize) -> f64 {
    assert_eq!(a.len(), n * n, "trace: length");
    (0..n).map(|i| a[i * n + i]).sum()
}

/// `Tr(A B) = Σ_ij A_ij B_ji` for `n × n` matrices, without forming the product.
pub fn trace_prod(a: &[f64], b: &[f64], n: usize) -> f64 {
    assert_eq!(a.len(), n * n, "trace_prod: A length");
    assert_eq!(b.len(), n * n, "trace_prod: B length");
    let mut s = 0.0;
    for i in 0..n {
        for j in 0..n {
            s += a[i * n + j] * b[j * n + i];
        }
    }
    s
}

/// Cholesky factor `L` (lower triangular, upper part zero) of a symmetric `n × n` matrix, with
/// `A = L Lᵀ`. Only the lower triangle of `A` is read.
///
/// Errors with [`KrrError::NotPositiveDefinite`] (naming the matrix by `what`) when a pivot is
/// not strictly positive or not finite — that is, when `A` is not numerically SPD.
pub fn cholesky(a: &[f64], n: usize, what: &'static str) -> Result<Vec<f64>, KrrError> {
    assert_eq!(a.len(), n * n, "cholesky: length");
    let mut l = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            let s = a[i * n + j] - dot(&l[i * n..i * n + j], &l[j * n..j * n + j]);
            if i == j {
                if s <= 0.0 || !s.is_finite() {
                    return Err(KrrError::NotPositiveDefinite { what, index: i, pivot: s });
                }
                l[i * n + i] = s.sqrt();
            } else {
                l[i * n + j] = s / l[j * n + j];
            }
        }
    }
    Ok(l)
}

/// Solve `L X = B` in place for lower-triangular `L: n × n` and `B: n × p` (`p` right-hand
/// sides as columns; rows are contiguous, so each step is an AXPY over `p`).
pub fn solve_lower_in_place(l: &[f64], n: usize, b: &mut [f64], p: usize) {
    assert_eq!(l.len(), n * n, "solve_lower: L length");
    assert_eq!(b.len(), n * p, "solve_lower: B length");
    for i in 0..n {
        let (done, rest) = b.split_at_mut(i * p);
        let row = &mut rest[..p];
        for k in 0..i {
            let lik = l[i * n + k];
            if lik != 0.0 {
                for (x, y) in row.iter_mut().zip(&done[k * p..(k + 1) * p]) {
                    *x -= lik * y;
                }
            }
        }
        let inv = 1.0 / l[i * n + i];
        row.iter_mut().for_each(|x| *x *= inv);
    }
}

/// Solve `Lᵀ X = B` in place for lower-triangular `L: n × n` and `B: n × p`.
pub fn solve_lower_t_in_place(l: &[f64], n: usize, b: &mut [f64], p: usize) {
    assert_eq!(l.len(), n * n, "solve_lower_t: L length");
    assert_eq!(b.len(), n * p, "solve_lower_t: B length");
    for i in (0..n).rev() {
        let (head, tail) = b.split_at_mut((i + 1) * p);
        let row = &mut head[i * p..];
        for k in i + 1..n {
            let lki = l[k * n + i];
            if lki != 0.0 {
                let yk = &tail[(k - i - 1) * p..(k - i) * p];
                for (x, y) in row.iter_mut().zip(yk) {
                    *x -= lki * y;
                }
            }
        }
        let inv = 1.0 / l[i * n + i];
        row.iter_mut().for_each(|x| *x *= inv);
    }
}

/// Solve `A X = B` given the Cholesky factor `L` of `A` (`B: n × p`, returns `X`).
pub fn cholesky_solve(l: &[f64], n: usize, b: &[f64], p: usize) -> Vec<f64> {
    let mut x = b.to_vec();
    solve_lower_in_place(l, n, &mut x, p);
    solve_lower_t_in_place(l, n, &mut x, p);
    x
}

/// `A⁻¹` from the Cholesky factor `L` of `A`, exactly symmetric.
pub fn cholesky_inverse(l: &[f64], n: usize) -> Vec<f64> {
    let mut inv = cholesky_solve(l, n, &identity(n), n);
    symmetrize(&mut inv, n);
    inv
}

/// Solve `A X = B` for symmetric positive definite `A: n × n`, `B: n × p`.
pub fn spd_solve(a: &[f64], n: usize, b: &[f64], p: usize, what: &'static str) -> Result<Vec<f64>, KrrError> {
    let l = cholesky(a, n, what)?;
    Ok(cholesky_solve(&l, n, b, p))
}

/// `A⁻¹` of a symmetric positive definite `A: n × n`, via Cholesky.
pub fn spd_inverse(a: &[f64], n: usize, what: &'static str) -> Result<Vec<f64>, KrrError> {
    let l = cholesky(a, n, what)?;
    Ok(cholesky_inverse(&l, n))
}
