//! Small dense f64 linear algebra on row-major slices, hand-written (pure std, wasm32-friendly).
//!
//! Conventions: a matrix with `r` rows and `c` columns is a `&[f64]` of length `r * c`, element
//! `(i, j)` at `i * c + j`. Dimensions are passed explicitly and *asserted*: a length mismatch
//! here is a bug in the caller (the public KRR entry points validate user data before reaching
//! this module). Numerical failure — a matrix that is not positive definite — is an error value,
//! [`KrrError::NotPositiveDefinite`], never a panic.
//!
//! Only what `docs/method.md` §5–§6 need. Every O(m³) and O(n·m²) operation goes through one
//! cache-blocked, register-tiled product, [`gemm`], that takes transposed and triangular operands
//! and can restrict itself to one triangle of a symmetric result; the Cholesky factorisation is
//! blocked so that its bulk is that product too, and the triangular inverse runs on the same
//! register tiles.
//!
//! **Threads.** Natively the kernels split their *output* over scoped threads
//! ([`max_threads`]: `available_parallelism()`, or `NKRR_THREADS`), never a sum, so results are
//! bitwise the same for any number of threads. On `wasm32` they split over the page's pool of
//! Web Workers in the threaded build (`crate::par`), else run on the calling thread.
//! **SIMD.** On x86-64 CPUs with AVX2 and FMA (detected at run time) the register tile uses
//! 4-wide fused multiply-adds; elsewhere the compiler vectorises plain Rust (separate multiply
//! and add) as the target allows. The two differ in the last bits, never in accuracy.

use super::error::KrrError;

// ---------------------------------------------------------------------------------------------
// threads

/// Threads the kernels of this module may use: [`crate::par::threads`] (`NKRR_THREADS` if set
/// to a positive integer, else every core; on `wasm32` the page's pool, or 1).
pub fn max_threads() -> usize {
    crate::par::threads()
}

/// Least work (multiply-adds) worth a thread of its own: starting one costs tens of µs.
const MIN_WORK_PER_THREAD: f64 = 262144.0;

/// Runs `f(first_unit, end_unit, rows)` over consecutive ranges of row units (a unit is
/// `unit_rows` rows of `c`, whose row stride is `ld`), each range of about equal `weight`, on up
/// to `threads` threads. `rows` starts at the first row of its range. `c` holds `total_rows`
/// rows (the last possibly shorter than `ld`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn par_row_units<F>(
    c: &mut [f64],
    ld: usize,
    total_rows: usize,
    unit_rows: usize,
    threads: usize,
    weight: &dyn Fn(usize) -> f64,
    f: F,
) where
    F: Fn(usize, usize, &mut [f64]) + Sync,
{
    let units = total_rows.div_ceil(unit_rows);
    if units == 0 {
        return;
    }
    let weights: Vec<f64> = (0..units).map(weight).collect();
    let total: f64 = weights.iter().sum();
    let t = threads.min(units).min((total / MIN_WORK_PER_THREAD) as usize).max(1);
    if t == 1 {
        f(0, units, c);
        return;
    }
    // Cut where the running weight crosses multiples of total/t.
    let mut bounds = vec![0];
    let mut acc = 0.0;
    for (u, w) in weights.iter().enumerate() {
        acc += w;
        let want = bounds.len() as f64 * total / t as f64;
        if acc >= want && u + 1 < units && bounds.len() < t {
            bounds.push(u + 1);
        }
    }
    bounds.push(units);
    let mut parts: Vec<(usize, usize, &mut [f64])> = Vec::with_capacity(t);
    let mut rest = c;
    for w in bounds.windows(2) {
        let (u0, u1) = (w[0], w[1]);
        if u1 == units {
            parts.push((u0, u1, std::mem::take(&mut rest)));
        } else {
            let (head, tail) = std::mem::take(&mut rest).split_at_mut((u1 - u0) * unit_rows * ld);
            parts.push((u0, u1, head));
            rest = tail;
        }
    }
    run_parts(parts, &f);
}

type Part<'a> = (usize, usize, &'a mut [f64]);

/// Runs `f` on each part, natively on scoped threads started as a tree (each thread starts half
/// of what is left of its share), so that starting `t` threads takes `log₂ t` thread starts of
/// wall time rather than `t`.
#[cfg(not(target_arch = "wasm32"))]
fn run_parts<F>(parts: Vec<Part<'_>>, f: &F)
where
    F: Fn(usize, usize, &mut [f64]) + Sync,
{
    fn spread<'s, 'e, F>(s: &'s std::thread::Scope<'s, 'e>, mut parts: Vec<Part<'e>>, f: &'e F)
    where
        F: Fn(usize, usize, &mut [f64]) + Sync,
    {
        while parts.len() > 1 {
            let upper = parts.split_off(parts.len() / 2);
            s.spawn(move || spread(s, upper, f));
        }
        if let Some((u0, u1, c)) = parts.pop() {
            f(u0, u1, c);
        }
    }
    std::thread::scope(|s| spread(s, parts, f));
}

/// Runs `f` on each part on the page's pool of Web Workers (the threaded wasm build).
#[cfg(all(target_arch = "wasm32", feature = "wasm-threads"))]
fn run_parts<F>(parts: Vec<Part<'_>>, f: &F)
where
    F: Fn(usize, usize, &mut [f64]) + Sync,
{
    rayon::scope(|s| {
        for (u0, u1, c) in parts {
            s.spawn(move |_| f(u0, u1, c));
        }
    });
}

/// Runs `f` on each part, in order, on this thread (the plain wasm build has no threads).
#[cfg(all(target_arch = "wasm32", not(feature = "wasm-threads")))]
fn run_parts<F>(parts: Vec<Part<'_>>, f: &F)
where
    F: Fn(usize, usize, &mut [f64]) + Sync,
{
    for (u0, u1, c) in parts {
        f(u0, u1, c);
    }
}

/// `(fa(ta), fb(tb))` for two independent jobs sharing `threads` (`ta ≈ share_a · threads`,
/// `tb` the rest): natively `fa` on a scoped thread of its own while `fb` runs here, on `wasm32`
/// both on the page's pool, when there are at least two threads; otherwise one after the other,
/// each with all of them.
pub(crate) fn join<A, B, FA, FB>(threads: usize, share_a: f64, fa: FA, fb: FB) -> (A, B)
where
    A: Send,
    B: Send,
    FA: FnOnce(usize) -> A + Send,
    FB: FnOnce(usize) -> B + Send,
{
    let ta = ((threads as f64 * share_a).round() as usize).clamp(1, threads.max(2) - 1);
    #[cfg(all(target_arch = "wasm32", feature = "wasm-threads"))]
    {
        if threads >= 2 {
            let tb = threads - ta;
            return rayon::join(move || fa(ta), move || fb(tb));
        }
    }
    #[cfg(not(target_arch = "wasm32"))]
    {
        if threads >= 2 {
            let tb = threads - ta;
            return std::thread::scope(|s| {
                let ha = s.spawn(move || fa(ta));
                let b = fb(tb);
                let a = ha.join().unwrap_or_else(|e| std::panic::resume_unwind(e));
                (a, b)
            });
        }
    }
    let _ = ta;
    (fa(threads), fb(threads))
}

// ---------------------------------------------------------------------------------------------
// basics

/// Dot product of two equal-length slices.
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len(), "dot: length mismatch");
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Transpose of an `r × c` matrix (returns `c × r`), in cache-sized tiles.
pub fn transpose(a: &[f64], r: usize, c: usize) -> Vec<f64> {
    assert_eq!(a.len(), r * c, "transpose: length");
    let mut t = vec![0.0; r * c];
    const T: usize = 32;
    for i0 in (0..r).step_by(T) {
        for j0 in (0..c).step_by(T) {
            for i in i0..(i0 + T).min(r) {
                for j in j0..(j0 + T).min(c) {
                    t[j * r + i] = a[i * c + j];
                }
            }
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

// ---------------------------------------------------------------------------------------------
// the register tile

/// Rows of `C` per register tile.
const MR: usize = 4;
/// Columns of `C` per register tile (and per packed panel of `B`).
const NR: usize = 8;

/// Whether the AVX2 + FMA tile can be used (x86-64 with both, detected at run time).
#[inline]
fn use_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The register tile `T[r][·] = Σ_{kk < len} A(r, kk) · panel[kk][·]` for `R` rows, with
/// `A(r, kk) = a[a0 + r·rs + kk·cs]` (so `cs = 1` reads rows, `rs = 1` reads columns, i.e. a
/// transposed operand) and `len` rows of a packed panel (`NR` wide), summed over `kk` in order.
/// With AVX2 + FMA each step is one fused multiply-add (one rounding instead of two: as
/// accurate or more, but not bitwise the portable path's result).
#[inline]
#[allow(clippy::too_many_arguments)]
fn tile<const R: usize>(fma: bool, a: &[f64], a0: usize, rs: usize, cs: usize, panel: &[f64], len: usize) -> [[f64; NR]; R] {
    assert!(R > 0 && len > 0, "tile: empty");
    assert!(a0 + (R - 1) * rs + (len - 1) * cs < a.len() && len * NR <= panel.len(), "tile: bounds");
    #[cfg(target_arch = "x86_64")]
    {
        if fma {
            // SAFETY: `fma` is only true where `use_avx2_fma()` detected AVX2 and FMA; bounds
            // checked above.
            return unsafe { tile_avx2_fma::<R>(a, a0, rs, cs, panel, len) };
        }
    }
    let _ = fma;
    let mut acc = [[0.0; NR]; R];
    for (kk, bv) in panel[..len * NR].chunks_exact(NR).enumerate() {
        for (r, acc_r) in acc.iter_mut().enumerate() {
            let av = a[a0 + r * rs + kk * cs];
            for t in 0..NR {
                acc_r[t] += av * bv[t];
            }
        }
    }
    acc
}

/// [`tile`] with AVX2 + FMA intrinsics: two 4-wide accumulators per row.
///
/// # Safety
/// The CPU must support AVX2 and FMA, and the bounds must hold (as [`tile`] asserts).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn tile_avx2_fma<const R: usize>(a: &[f64], a0: usize, rs: usize, cs: usize, panel: &[f64], len: usize) -> [[f64; NR]; R] {
    use std::arch::x86_64::{__m256d, _mm256_fmadd_pd, _mm256_loadu_pd, _mm256_set1_pd, _mm256_setzero_pd, _mm256_storeu_pd};
    const { assert!(NR == 8) };
    let pa = a.as_ptr().add(a0);
    let pb = panel.as_ptr();
    let mut acc: [[__m256d; 2]; R] = [[_mm256_setzero_pd(); 2]; R];
    for kk in 0..len {
        let b0 = _mm256_loadu_pd(pb.add(kk * NR));
        let b1 = _mm256_loadu_pd(pb.add(kk * NR + 4));
        let ak = pa.add(kk * cs);
        for (r, acc_r) in acc.iter_mut().enumerate() {
            let av = _mm256_set1_pd(*ak.add(r * rs));
            acc_r[0] = _mm256_fmadd_pd(av, b0, acc_r[0]);
            acc_r[1] = _mm256_fmadd_pd(av, b1, acc_r[1]);
        }
    }
    let mut out = [[0.0; NR]; R];
    for (o, acc_r) in out.iter_mut().zip(&acc) {
        _mm256_storeu_pd(o.as_mut_ptr(), acc_r[0]);
        _mm256_storeu_pd(o.as_mut_ptr().add(4), acc_r[1]);
    }
    out
}

// ---------------------------------------------------------------------------------------------
// the product

/// Which entries of a square-ish operand may be non-zero, or which entries of a result are
/// wanted.
///
/// For an operand, `Lower` promises `X[i][j] = 0` for `j > i` and `Upper` promises `X[i][j] = 0`
/// for `j < i` (indices of the operand as used, i.e. after any transposition; the zeros must be
/// stored: the kernel skips most of them but may read some). For the result, `Lower`/`Upper`
/// means only the entries with `j ≤ i`/`j ≥ i` are updated; the others are left untouched.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tri {
    Full,
    Lower,
    Upper,
}

/// An operand of [`gemm`]: `data` with row stride `ld`, used as stored or transposed, with a
/// declared triangular structure (of the operand as used).
#[derive(Clone, Copy, Debug)]
pub struct Op<'a> {
    pub data: &'a [f64],
    pub ld: usize,
    pub trans: bool,
    pub tri: Tri,
}

impl<'a> Op<'a> {
    /// The matrix as stored, row stride `ld`.
    pub fn new(data: &'a [f64], ld: usize) -> Self {
        Op { data, ld, trans: false, tri: Tri::Full }
    }
    /// The stored matrix transposed.
    pub fn t(data: &'a [f64], ld: usize) -> Self {
        Op { data, ld, trans: true, tri: Tri::Full }
    }
    /// Declares the operand (as used) lower triangular.
    pub fn lower(self) -> Self {
        Op { tri: Tri::Lower, ..self }
    }
    /// Declares the operand (as used) upper triangular.
    pub fn upper(self) -> Self {
        Op { tri: Tri::Upper, ..self }
    }
    /// Stored elements needed for a `rows × cols` operand (as used).
    fn span(&self, rows: usize, cols: usize) -> usize {
        let (r, c) = if self.trans { (cols, rows) } else { (rows, cols) };
        if r == 0 || c == 0 {
            0
        } else {
            (r - 1) * self.ld + c
        }
    }
}

/// Depth of a packed block of `B` (rows of `B`).
const KC: usize = 256;
/// Width of a packed block of `B` (columns): `KC × NC` f64 = 512 KiB, an L2's worth.
const NC: usize = 256;

/// One product `C[sc] += α A B` with `A: n × k`, `B: k × p` (`n` is implied by the rows asked for).
#[derive(Clone, Copy)]
struct Gemm<'a> {
    a: Op<'a>,
    b: Op<'a>,
    sc: Tri,
    k: usize,
    p: usize,
    alpha: f64,
}

impl Gemm<'_> {
    /// The part `[kb, ke)` of `[k0, k1)` that can contribute to the register tile at rows
    /// `i0..i0+mr`, columns `j0..j0+nr` (the rest multiplies stored zeros).
    #[inline]
    fn k_range(&self, i0: usize, mr: usize, j0: usize, nr: usize, k0: usize, k1: usize) -> (usize, usize) {
        let (mut kb, mut ke) = (k0, k1);
        match self.a.tri {
            Tri::Lower => ke = ke.min(i0 + mr),
            Tri::Upper => kb = kb.max(i0),
            Tri::Full => {}
        }
        match self.b.tri {
            Tri::Lower => kb = kb.max(j0),
            Tri::Upper => ke = ke.min(j0 + nr),
            Tri::Full => {}
        }
        (kb, ke)
    }

    /// Whether no entry of the register tile is wanted.
    #[inline]
    fn c_skips(&self, i0: usize, mr: usize, j0: usize, nr: usize) -> bool {
        match self.sc {
            Tri::Upper => j0 + nr <= i0,
            Tri::Lower => j0 > i0 + mr - 1,
            Tri::Full => false,
        }
    }

    /// Multiply-adds for the strip of rows `i0..i0+mr` (for load balancing).
    fn strip_work(&self, i0: usize, mr: usize) -> f64 {
        let mut w = 0usize;
        for j0 in (0..self.p).step_by(NR) {
            let nr = NR.min(self.p - j0);
            if !self.c_skips(i0, mr, j0, nr) {
                let (kb, ke) = self.k_range(i0, mr, j0, nr, 0, self.k);
                w += ke.saturating_sub(kb);
            }
        }
        (w * mr * NR) as f64
    }

    /// `A(i, kk)` as `(index of A(i, 0), row step, column step)` in the stored data.
    #[inline]
    fn a_index(&self, i: usize, kk: usize) -> (usize, usize, usize) {
        if self.a.trans {
            (kk * self.a.ld + i, 1, self.a.ld)
        } else {
            (i * self.a.ld + kk, self.a.ld, 1)
        }
    }

    /// Packs `B[k0..k0+kc, j0..j0+nr]` into `dst` (`kc` rows of `NR`, zero-padded).
    fn pack(&self, dst: &mut [f64], k0: usize, kc: usize, j0: usize, nr: usize) {
        let (b, ld) = (self.b.data, self.b.ld);
        if self.b.trans {
            dst.iter_mut().for_each(|x| *x = 0.0);
            for t in 0..nr {
                let src = &b[(j0 + t) * ld + k0..(j0 + t) * ld + k0 + kc];
                for (kk, v) in src.iter().enumerate() {
                    dst[kk * NR + t] = *v;
                }
            }
        } else {
            for (kk, d) in dst.chunks_exact_mut(NR).enumerate() {
                d[..nr].copy_from_slice(&b[(k0 + kk) * ld + j0..(k0 + kk) * ld + j0 + nr]);
                d[nr..].iter_mut().for_each(|x| *x = 0.0);
            }
        }
    }

    /// The rows `r0..r1` of `C`, held in `c` from row `r0` on (stride `ldc`).
    fn rows(&self, c: &mut [f64], ldc: usize, r0: usize, r1: usize) {
        let fma = use_avx2_fma();
        let mut pack = vec![0.0; KC.min(self.k) * NC.min(self.p).next_multiple_of(NR)];
        for jc in (0..self.p).step_by(NC) {
            let nc = NC.min(self.p - jc);
            let panels = nc.div_ceil(NR);
            for k0 in (0..self.k).step_by(KC) {
                let k1 = (k0 + KC).min(self.k);
                let kc = k1 - k0;
                // The whole block multiplying stored zeros, or outside the wanted C?
                let (kb, ke) = self.k_range(r0, r1 - r0, jc, nc, k0, k1);
                if kb >= ke || self.c_skips(r0, r1 - r0, jc, nc) {
                    continue;
                }
                for jp in 0..panels {
                    let j0 = jc + jp * NR;
                    self.pack(&mut pack[jp * kc * NR..(jp + 1) * kc * NR], k0, kc, j0, NR.min(self.p - j0));
                }
                let mut i0 = r0;
                while i0 < r1 {
                    let mr = MR.min(r1 - i0);
                    for jp in 0..panels {
                        let j0 = jc + jp * NR;
                        let nr = NR.min(self.p - j0);
                        if self.c_skips(i0, mr, j0, nr) {
                            continue;
                        }
                        let (kb, ke) = self.k_range(i0, mr, j0, nr, k0, k1);
                        if kb >= ke {
                            continue;
                        }
                        let panel = &pack[(jp * kc + (kb - k0)) * NR..(jp * kc + (ke - k0)) * NR];
                        let (a0, rs, cs) = self.a_index(i0, kb);
                        let (a, len) = (self.a.data, ke - kb);
                        match mr {
                            4 => self.store::<4>(c, ldc, r0, i0, j0, nr, tile::<4>(fma, a, a0, rs, cs, panel, len)),
                            3 => self.store::<3>(c, ldc, r0, i0, j0, nr, tile::<3>(fma, a, a0, rs, cs, panel, len)),
                            2 => self.store::<2>(c, ldc, r0, i0, j0, nr, tile::<2>(fma, a, a0, rs, cs, panel, len)),
                            _ => self.store::<1>(c, ldc, r0, i0, j0, nr, tile::<1>(fma, a, a0, rs, cs, panel, len)),
                        }
                    }
                    i0 += mr;
                }
            }
        }
    }

    /// `C[i0.., j0..] += α acc`, restricted to the wanted entries.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn store<const R: usize>(&self, c: &mut [f64], ldc: usize, r0: usize, i0: usize, j0: usize, nr: usize, acc: [[f64; NR]; R]) {
        for (r, acc_r) in acc.iter().enumerate() {
            let i = i0 + r;
            let (t0, t1) = match self.sc {
                Tri::Full => (0, nr),
                Tri::Upper => (i.saturating_sub(j0).min(nr), nr),
                Tri::Lower => (0, (i + 1).saturating_sub(j0).min(nr)),
            };
            let row = &mut c[(i - r0) * ldc + j0..(i - r0) * ldc + j0 + nr];
            if self.alpha == 1.0 {
                for t in t0..t1 {
                    row[t] += acc_r[t];
                }
            } else {
                for t in t0..t1 {
                    row[t] += self.alpha * acc_r[t];
                }
            }
        }
    }
}

/// `C += α A B` for `A: n × k`, `B: k × p` (see [`Op`]: either may be transposed and/or
/// declared triangular) and `C: n × p` with row stride `ldc`, restricted to the triangle `sc` of
/// `C` (for a symmetric result: about half the work; mirror it afterwards with
/// [`mirror_upper`]). The kernel behind every product here; threaded over rows of `C`.
///
/// Blocked as usual: `B` in packed `KC × NC` blocks (L2), `NR`-column panels of it (L1) swept by
/// `MR × NR` register tiles of `C`; each entry of `C` gets a fixed sequence of per-block sums,
/// so the result does not depend on the thread count.
#[allow(clippy::too_many_arguments)]
pub fn gemm(c: &mut [f64], ldc: usize, sc: Tri, alpha: f64, a: Op, b: Op, n: usize, k: usize, p: usize) {
    gemm_threads(c, ldc, sc, alpha, a, b, n, k, p, max_threads());
}

#[allow(clippy::too_many_arguments)]
pub(crate) fn gemm_threads(c: &mut [f64], ldc: usize, sc: Tri, alpha: f64, a: Op, b: Op, n: usize, k: usize, p: usize, threads: usize) {
    if n == 0 || p == 0 {
        return;
    }
    assert!(a.data.len() >= a.span(n, k) && a.ld >= if a.trans { n } else { k }, "gemm: A too short");
    assert!(b.data.len() >= b.span(k, p) && b.ld >= if b.trans { k } else { p }, "gemm: B too short");
    let c_span = (n - 1) * ldc + p;
    assert!(ldc >= p && c.len() >= c_span, "gemm: C too short");
    if k == 0 {
        return;
    }
    let g = Gemm { a, b, sc, k, p, alpha };
    par_row_units(
        &mut c[..c_span],
        ldc,
        n,
        MR,
        threads,
        &|u| g.strip_work(u * MR, MR.min(n - u * MR)),
        |u0, u1, rows| g.rows(rows, ldc, u0 * MR, (u1 * MR).min(n)),
    );
}

/// `C += A B` with `A: n × k`, `B: k × p`, `C: n × p`.
pub fn matmul_acc(c: &mut [f64], a: &[f64], b: &[f64], n: usize, k: usize, p: usize) {
    assert_eq!(a.len(), n * k, "matmul: A length");
    assert_eq!(b.len(), k * p, "matmul: B length");
    assert_eq!(c.len(), n * p, "matmul: C length");
    gemm(c, p, Tri::Full, 1.0, Op::new(a, k), Op::new(b, p), n, k, p);
}

/// `A B` with `A: n × k`, `B: k × p`.
pub fn matmul(a: &[f64], b: &[f64], n: usize, k: usize, p: usize) -> Vec<f64> {
    matmul_threads(a, b, n, k, p, max_threads())
}

pub(crate) fn matmul_threads(a: &[f64], b: &[f64], n: usize, k: usize, p: usize, threads: usize) -> Vec<f64> {
    assert_eq!(a.len(), n * k, "matmul: A length");
    assert_eq!(b.len(), k * p, "matmul: B length");
    let mut c = vec![0.0; n * p];
    gemm_threads(&mut c, p, Tri::Full, 1.0, Op::new(a, k), Op::new(b, p), n, k, p, threads);
    c
}

/// `Aᵀ B` with `A: n × k`, `B: n × p` (result `k × p`).
pub fn matmul_tn(a: &[f64], b: &[f64], n: usize, k: usize, p: usize) -> Vec<f64> {
    assert_eq!(a.len(), n * k, "matmul_tn: A length");
    assert_eq!(b.len(), n * p, "matmul_tn: B length");
    let mut c = vec![0.0; k * p];
    gemm(&mut c, p, Tri::Full, 1.0, Op::t(a, k), Op::new(b, p), k, n, p);
    c
}

/// `A Bᵀ` with `A: n × k`, `B: p × k` (result `n × p`).
pub fn matmul_nt(a: &[f64], b: &[f64], n: usize, k: usize, p: usize) -> Vec<f64> {
    assert_eq!(a.len(), n * k, "matmul_nt: A length");
    assert_eq!(b.len(), p * k, "matmul_nt: B length");
    let mut c = vec![0.0; n * p];
    gemm(&mut c, p, Tri::Full, 1.0, Op::new(a, k), Op::t(b, k), n, k, p);
    c
}

/// `A B` for `n × n` matrices whose product is known to be symmetric (e.g. `S (T S)` for
/// symmetric `S`, `T`): only the upper triangle is computed, then mirrored, so the result is
/// exactly symmetric, at half the cost of [`matmul`].
pub fn matmul_sym(a: &[f64], b: &[f64], n: usize) -> Vec<f64> {
    matmul_sym_threads(a, b, n, max_threads())
}

pub(crate) fn matmul_sym_threads(a: &[f64], b: &[f64], n: usize, threads: usize) -> Vec<f64> {
    assert_eq!(a.len(), n * n, "matmul_sym: A length");
    assert_eq!(b.len(), n * n, "matmul_sym: B length");
    let mut c = vec![0.0; n * n];
    gemm_threads(&mut c, n, Tri::Upper, 1.0, Op::new(a, n), Op::new(b, n), n, n, n, threads);
    mirror_upper(&mut c, n);
    c
}

/// `A Aᵀ` (`n × n`, exactly symmetric) of `A: n × k`: the upper triangle, mirrored.
pub fn gram_rows(a: &[f64], n: usize, k: usize) -> Vec<f64> {
    gram_rows_threads(a, n, k, max_threads())
}

pub(crate) fn gram_rows_threads(a: &[f64], n: usize, k: usize, threads: usize) -> Vec<f64> {
    assert_eq!(a.len(), n * k, "gram_rows: length");
    let mut c = vec![0.0; n * n];
    gemm_threads(&mut c, n, Tri::Upper, 1.0, Op::new(a, k), Op::t(a, k), n, k, n, threads);
    mirror_upper(&mut c, n);
    c
}

/// The Gram matrix `Aᵀ A` (`k × k`, exactly symmetric) of `A: n × k`. Half the work of
/// [`matmul_tn`]: only the upper triangle is computed, then mirrored.
pub fn gram(a: &[f64], n: usize, k: usize) -> Vec<f64> {
    assert_eq!(a.len(), n * k, "gram: length");
    let mut c = vec![0.0; k * k];
    gemm(&mut c, k, Tri::Upper, 1.0, Op::t(a, k), Op::new(a, k), k, n, k);
    mirror_upper(&mut c, k);
    c
}

/// Copy the upper triangle of an `n × n` matrix onto its lower triangle.
pub fn mirror_upper(a: &mut [f64], n: usize) {
    assert_eq!(a.len(), n * n, "mirror_upper: length");
    const T: usize = 32;
    for i0 in (0..n).step_by(T) {
        for j0 in (0..=i0).step_by(T) {
            for i in i0..(i0 + T).min(n) {
                for j in j0..(j0 + T).min(i) {
                    a[i * n + j] = a[j * n + i];
                }
            }
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

/// `Tr(A B) = Σ_ij A_ij B_ji` for `n × n` matrices, without forming the product. Where `A` or
/// `B` is symmetric, [`frobenius_dot`] gives the same and reads both row by row.
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

/// `Σ_ij A_ij B_ij = Tr(Aᵀ B)`, which is `Tr(A B)` when either is symmetric. Eight interleaved
/// partial sums (vectorisable, and no one long dependency chain), added at the end.
pub fn frobenius_dot(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len(), "frobenius_dot: length mismatch");
    let mut acc = [0.0; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail = dot(ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for t in 0..8 {
            acc[t] += x[t] * y[t];
        }
    }
    acc.iter().sum::<f64>() + tail
}

// ---------------------------------------------------------------------------------------------
// Cholesky, triangular solves and inverses

/// Columns per block of the blocked Cholesky factorisation.
const CHOL_NB: usize = 128;

/// Factors the `nb × nb` diagonal block at `(j0, j0)` of `l` (stride `n`) in place, reading its
/// lower triangle (already updated by the blocks to its left).
fn cholesky_diag_block(l: &mut [f64], n: usize, j0: usize, nb: usize, what: &'static str) -> Result<(), KrrError> {
    for i in j0..j0 + nb {
        for j in j0..=i {
            let s = l[i * n + j] - dot(&l[i * n + j0..i * n + j], &l[j * n + j0..j * n + j]);
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
    Ok(())
}

/// Cholesky factor `L` (lower triangular, upper part zero) of a symmetric `n × n` matrix, with
/// `A = L Lᵀ`. Only the lower triangle of `A` is read.
///
/// Errors with [`KrrError::NotPositiveDefinite`] (naming the matrix by `what`) when a pivot is
/// not strictly positive or not finite — that is, when `A` is not numerically SPD.
///
/// Blocked, right-looking: per block of `CHOL_NB` columns, the diagonal block directly, the
/// panel below it by forward substitution (threaded over rows), the trailing lower triangle by
/// one [`gemm`].
pub fn cholesky(a: &[f64], n: usize, what: &'static str) -> Result<Vec<f64>, KrrError> {
    cholesky_threads(a, n, what, max_threads())
}

pub(crate) fn cholesky_threads(a: &[f64], n: usize, what: &'static str, threads: usize) -> Result<Vec<f64>, KrrError> {
    assert_eq!(a.len(), n * n, "cholesky: length");
    let mut l = vec![0.0; n * n];
    for i in 0..n {
        l[i * n..i * n + i + 1].copy_from_slice(&a[i * n..i * n + i + 1]);
    }
    for j0 in (0..n).step_by(CHOL_NB) {
        let j1 = (j0 + CHOL_NB).min(n);
        let nb = j1 - j0;
        cholesky_diag_block(&mut l, n, j0, nb, what)?;
        let below = n - j1;
        if below == 0 {
            break;
        }
        // L11 (nb × nb, contiguous) and the panel A21 (below × nb).
        let mut l11 = vec![0.0; nb * nb];
        for r in 0..nb {
            l11[r * nb..(r + 1) * nb].copy_from_slice(&l[(j0 + r) * n + j0..(j0 + r) * n + j1]);
        }
        let mut panel = vec![0.0; below * nb];
        for r in 0..below {
            panel[r * nb..(r + 1) * nb].copy_from_slice(&l[(j1 + r) * n + j0..(j1 + r) * n + j1]);
        }
        // L21 = A21 L11⁻ᵀ, i.e. L11 L21ᵀ = A21ᵀ: forward substitution on transposed row chunks.
        const ROWS: usize = 32;
        par_row_units(&mut panel, nb, below, ROWS, threads, &|_| (ROWS * nb * nb / 2) as f64, |u0, u1, rows| {
            let cnt = (u1 * ROWS).min(below) - u0 * ROWS;
            let mut t = transpose(&rows[..cnt * nb], cnt, nb);
            solve_lower_in_place(&l11, nb, &mut t, cnt);
            rows[..cnt * nb].copy_from_slice(&transpose(&t, nb, cnt));
        });
        for r in 0..below {
            l[(j1 + r) * n + j0..(j1 + r) * n + j1].copy_from_slice(&panel[r * nb..(r + 1) * nb]);
        }
        // A22 −= L21 L21ᵀ, lower triangle.
        let trailing = &mut l[j1 * n + j1..];
        gemm_threads(trailing, n, Tri::Lower, -1.0, Op::new(&panel, nb), Op::t(&panel, nb), below, nb, below, threads);
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

/// Solve `Lᵀ X = B` in place for lower-triangular `L: n × n` and `B: n × p`. Column-oriented
/// (row `k` of `L` is column `k` of `Lᵀ`), so `L` is read row by row.
pub fn solve_lower_t_in_place(l: &[f64], n: usize, b: &mut [f64], p: usize) {
    assert_eq!(l.len(), n * n, "solve_lower_t: L length");
    assert_eq!(b.len(), n * p, "solve_lower_t: B length");
    for k in (0..n).rev() {
        let (head, tail) = b.split_at_mut(k * p);
        let xk = &mut tail[..p];
        let inv = 1.0 / l[k * n + k];
        xk.iter_mut().for_each(|x| *x *= inv);
        for i in 0..k {
            let lki = l[k * n + i];
            if lki != 0.0 {
                for (x, y) in head[i * p..(i + 1) * p].iter_mut().zip(xk.iter()) {
                    *x -= lki * y;
                }
            }
        }
    }
}

/// Solve `A X = B` given the Cholesky factor `L` of `A` (`B: n × p`, returns `X`).
pub fn cholesky_solve(l: &[f64], n: usize, b: &[f64], p: usize) -> Vec<f64> {
    let mut x = b.to_vec();
    solve_lower_in_place(l, n, &mut x, p);
    solve_lower_t_in_place(l, n, &mut x, p);
    x
}

/// `L⁻ᵀ` (upper triangular, lower part zero) of a lower-triangular `L: n × n` with non-zero
/// diagonal — i.e. `L⁻¹` transposed, its columns as rows.
///
/// Columns of `L⁻¹` are independent (`L x = e_j`), so each thread takes blocks of `NR` of them
/// (rows of the result) and solves for them by forward substitution over the rows of `L`, four
/// rows at a time through the register tile: `n³/6` multiply-adds, one parallel region.
pub fn tri_lower_inverse_t(l: &[f64], n: usize) -> Vec<f64> {
    tri_lower_inverse_t_threads(l, n, max_threads())
}

pub(crate) fn tri_lower_inverse_t_threads(l: &[f64], n: usize, threads: usize) -> Vec<f64> {
    assert_eq!(l.len(), n * n, "tri_lower_inverse_t: length");
    let mut xt = vec![0.0; n * n];
    if n == 0 {
        return xt;
    }
    let fma = use_avx2_fma();
    let work = |u: usize| {
        let rest = n - (u * NR).min(n);
        (rest * rest * NR / 2) as f64
    };
    par_row_units(&mut xt, n, n, NR, threads, &work, |u0, u1, out| {
        // The panel P = X[j0.., j0..j0+NR], row i − j0 at P[(i − j0)·NR..]: a packed panel.
        let mut p = vec![0.0; n * NR];
        for u in u0..u1 {
            let j0 = u * NR;
            let w = NR.min(n - j0);
            let rows = n - j0;
            let panel = &mut p[..rows * NR];
            panel.iter_mut().for_each(|v| *v = 0.0);
            let mut i0 = j0;
            while i0 < n {
                let mr = MR.min(n - i0);
                // Σ_{j0 ≤ k < i0} L[i][k] P[k] for the rows of the strip, then the strip itself.
                let mut acc = [[0.0; NR]; MR];
                if i0 > j0 {
                    let len = i0 - j0;
                    let done = &panel[..len * NR];
                    match mr {
                        4 => acc = tile::<4>(fma, l, i0 * n + j0, n, 1, done, len),
                        3 => acc[..3].copy_from_slice(&tile::<3>(fma, l, i0 * n + j0, n, 1, done, len)),
                        2 => acc[..2].copy_from_slice(&tile::<2>(fma, l, i0 * n + j0, n, 1, done, len)),
                        _ => acc[..1].copy_from_slice(&tile::<1>(fma, l, i0 * n + j0, n, 1, done, len)),
                    }
                }
                for (r, acc_r) in acc.iter().enumerate().take(mr) {
                    let i = i0 + r;
                    let mut v = [0.0; NR];
                    if i - j0 < w {
                        v[i - j0] = 1.0;
                    }
                    for t in 0..NR {
                        v[t] -= acc_r[t];
                    }
                    for q in i0..i {
                        let liq = l[i * n + q];
                        let pq = &panel[(q - j0) * NR..(q - j0 + 1) * NR];
                        for t in 0..NR {
                            v[t] -= liq * pq[t];
                        }
                    }
                    let inv = 1.0 / l[i * n + i];
                    for t in 0..NR {
                        panel[(i - j0) * NR + t] = v[t] * inv;
                    }
                }
                i0 += mr;
            }
            // Row j of the result is column j of L⁻¹.
            for t in 0..w {
                let row = &mut out[((u - u0) * NR + t) * n..((u - u0) * NR + t + 1) * n];
                for (i, v) in row.iter_mut().enumerate().skip(j0 + t) {
                    *v = panel[(i - j0) * NR + t];
                }
            }
        }
    });
    xt
}

/// `A⁻¹` from the Cholesky factor `L` of `A`, exactly symmetric: `U Uᵀ` with `U = L⁻ᵀ` from
/// [`tri_lower_inverse_t`], upper triangle only, mirrored (`n³/3` multiply-adds in all).
pub fn cholesky_inverse(l: &[f64], n: usize) -> Vec<f64> {
    cholesky_inverse_threads(l, n, max_threads())
}

pub(crate) fn cholesky_inverse_threads(l: &[f64], n: usize, threads: usize) -> Vec<f64> {
    let u = tri_lower_inverse_t_threads(l, n, threads);
    let mut inv = vec![0.0; n * n];
    gemm_threads(&mut inv, n, Tri::Upper, 1.0, Op::new(&u, n).upper(), Op::t(&u, n).lower(), n, n, n, threads);
    mirror_upper(&mut inv, n);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    fn uniform(len: usize, seed: u64) -> Vec<f64> {
        let mut rng = SplitMix64(seed);
        (0..len).map(|_| rng.unit() - 0.5).collect()
    }

    /// A random SPD matrix `R Rᵀ/n + shift·I`.
    fn spd(n: usize, seed: u64, shift: f64) -> Vec<f64> {
        let r = uniform(n * n, seed);
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                a[i * n + j] = (0..n).map(|k| r[i * n + k] * r[j * n + k]).sum::<f64>() / n as f64;
            }
            a[i * n + i] += shift;
        }
        a
    }

    fn naive_mul(a: &[f64], b: &[f64], n: usize, k: usize, p: usize) -> Vec<f64> {
        let mut c = vec![0.0; n * p];
        for i in 0..n {
            for j in 0..p {
                c[i * p + j] = (0..k).map(|t| a[i * k + t] * b[t * p + j]).sum();
            }
        }
        c
    }

    /// The naive Cholesky (dot-product form), the pre-blocking implementation.
    fn naive_cholesky(a: &[f64], n: usize) -> Vec<f64> {
        let mut l = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..=i {
                let s = a[i * n + j] - dot(&l[i * n..i * n + j], &l[j * n..j * n + j]);
                l[i * n + j] = if i == j { s.sqrt() } else { s / l[j * n + j] };
            }
        }
        l
    }

    fn max_abs(a: &[f64]) -> f64 {
        a.iter().fold(0.0f64, |m, v| m.max(v.abs()))
    }

    fn max_diff(a: &[f64], b: &[f64]) -> f64 {
        assert_eq!(a.len(), b.len());
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
    }

    fn tri(a: &mut [f64], n: usize, lower: bool) {
        for i in 0..n {
            for j in 0..n {
                if (lower && j > i) || (!lower && j < i) {
                    a[i * n + j] = 0.0;
                }
            }
        }
    }

    const SIZES: [usize; 6] = [1, 7, 63, 64, 65, 130];

    #[test]
    fn gemm_structures_match_naive_for_any_thread_count() {
        for &n in &SIZES {
            for (sa, sb, sc) in [
                (Tri::Full, Tri::Full, Tri::Full),
                (Tri::Lower, Tri::Full, Tri::Full),
                (Tri::Upper, Tri::Lower, Tri::Upper),
                (Tri::Full, Tri::Lower, Tri::Lower),
                (Tri::Full, Tri::Upper, Tri::Upper),
            ] {
                let mut a = uniform(n * n, 1 + n as u64);
                let mut b = uniform(n * n, 2 + n as u64);
                if sa != Tri::Full {
                    tri(&mut a, n, sa == Tri::Lower);
                }
                if sb != Tri::Full {
                    tri(&mut b, n, sb == Tri::Lower);
                }
                let c0 = uniform(n * n, 3);
                let prod = naive_mul(&a, &b, n, n, n);
                let mut want = c0.clone();
                for i in 0..n {
                    for j in 0..n {
                        let keep = match sc {
                            Tri::Full => true,
                            Tri::Upper => j >= i,
                            Tri::Lower => j <= i,
                        };
                        if keep {
                            want[i * n + j] -= 0.5 * prod[i * n + j];
                        }
                    }
                }
                let mut first: Option<Vec<f64>> = None;
                for threads in [1, 2, 3, 8] {
                    let mut c = c0.clone();
                    let op_a = Op { tri: sa, ..Op::new(&a, n) };
                    let op_b = Op { tri: sb, ..Op::new(&b, n) };
                    gemm_threads(&mut c, n, sc, -0.5, op_a, op_b, n, n, n, threads);
                    // The same through stored transposes.
                    let (at, bt) = (transpose(&a, n, n), transpose(&b, n, n));
                    let mut ct = c0.clone();
                    gemm_threads(&mut ct, n, sc, -0.5, Op { tri: sa, ..Op::t(&at, n) }, Op { tri: sb, ..Op::t(&bt, n) }, n, n, n, threads);
                    assert_eq!(ct, c, "transposed operands changed the result");
                    assert!(max_diff(&c, &want) < 1e-12, "n {n} {sa:?} {sb:?} {sc:?} threads {threads}");
                    match &first {
                        None => first = Some(c),
                        Some(f) => assert_eq!(f, &c, "thread count changed the result"),
                    }
                }
            }
        }
        // Rectangular and strided: a sub-block of a bigger matrix.
        let (n, k, p, ld) = (37, 300, 261, 400);
        let a = uniform(n * k, 4);
        let b = uniform(k * p, 5);
        let want = naive_mul(&a, &b, n, k, p);
        let mut big = vec![0.0; n * ld];
        gemm_threads(&mut big[3..], ld, Tri::Full, 1.0, Op::new(&a, k), Op::new(&b, p), n, k, p, 4);
        for i in 0..n {
            assert!(max_diff(&big[i * ld + 3..i * ld + 3 + p], &want[i * p..(i + 1) * p]) < 1e-12);
            assert!(big[i * ld..i * ld + 3].iter().chain(&big[i * ld + 3 + p..(i + 1) * ld]).all(|&v| v == 0.0));
        }
    }

    #[test]
    fn symmetric_products_match_naive() {
        for &n in &SIZES {
            let s = spd(n, 6, 0.1);
            let t = spd(n, 7, 0.0);
            let ts = naive_mul(&t, &s, n, n, n);
            let want = naive_mul(&s, &ts, n, n, n);
            let got = matmul_sym(&s, &ts, n);
            assert!(max_diff(&got, &want) < 1e-12 * max_abs(&want).max(1.0), "matmul_sym n {n}");
            let a = uniform(n * (n + 3), 8);
            let want = naive_mul(&a, &transpose(&a, n, n + 3), n, n + 3, n);
            assert!(max_diff(&gram_rows(&a, n, n + 3), &want) < 1e-12, "gram_rows n {n}");
            let at = transpose(&a, n, n + 3);
            assert!(max_diff(&gram(&at, n + 3, n), &want) < 1e-12, "gram n {n}");
            assert!((frobenius_dot(&s, &t) - trace_prod(&s, &t, n)).abs() < 1e-12 * n as f64);
        }
    }

    #[test]
    fn blocked_cholesky_matches_naive_for_any_thread_count() {
        for &n in &[1, 7, 63, 127, 128, 129, 130, 300] {
            let a = spd(n, 9 + n as u64, 1e-3);
            let want = naive_cholesky(&a, n);
            let l1 = cholesky_threads(&a, n, "a", 1).unwrap();
            assert!(max_diff(&l1, &want) < 1e-10 * max_abs(&want), "n {n}");
            assert!((0..n).all(|i| l1[i * n + i + 1..(i + 1) * n].iter().all(|&v| v == 0.0)), "upper part not zero");
            for threads in [2, 5] {
                assert_eq!(cholesky_threads(&a, n, "a", threads).unwrap(), l1, "thread count changed the factor");
            }
            // Reconstruction.
            let llt = naive_mul(&l1, &transpose(&l1, n, n), n, n, n);
            assert!(max_diff(&llt, &a) < 1e-12 * max_abs(&a), "n {n}");
        }
        // A failing pivot past the first block is reported at its global index.
        let n = 300;
        let mut a = spd(n, 3, 1e-3);
        a[260 * n + 260] = -5.0;
        match cholesky(&a, n, "bad") {
            Err(KrrError::NotPositiveDefinite { what: "bad", index: 260, .. }) => {}
            other => panic!("expected a failure at 260, got {:?}", other.map(|_| ())),
        }
    }

    #[test]
    fn triangular_and_spd_inverses_match_naive() {
        for &n in &[1, 7, 63, 64, 65, 130, 300] {
            let a = spd(n, 11 + n as u64, 0.05);
            let l = cholesky(&a, n, "a").unwrap();
            // L⁻ᵀ against the solve with the identity.
            let mut want = identity(n);
            solve_lower_in_place(&l, n, &mut want, n);
            let want = transpose(&want, n, n);
            let u = tri_lower_inverse_t_threads(&l, n, 1);
            assert!(max_diff(&u, &want) < 1e-10 * max_abs(&want), "L^-T n {n}");
            assert!((0..n).all(|i| u[i * n..i * n + i].iter().all(|&v| v == 0.0)), "lower part not zero");
            assert_eq!(tri_lower_inverse_t_threads(&l, n, 3), u);
            // A⁻¹ against the two solves, and against the identity.
            let mut want = identity(n);
            solve_lower_in_place(&l, n, &mut want, n);
            solve_lower_t_in_place(&l, n, &mut want, n);
            let inv = cholesky_inverse_threads(&l, n, 1);
            assert!(max_diff(&inv, &want) < 1e-10 * max_abs(&want), "A^-1 n {n}");
            assert_eq!(cholesky_inverse_threads(&l, n, 4), inv);
            assert!(max_diff(&naive_mul(&a, &inv, n, n, n), &identity(n)) < 1e-9, "A A^-1 n {n}");
            for i in 0..n {
                for j in 0..n {
                    assert_eq!(inv[i * n + j], inv[j * n + i]);
                }
            }
            // Lᵀ solve against the naive back substitution.
            let b = uniform(n * 3, 12);
            let mut x = b.clone();
            solve_lower_t_in_place(&l, n, &mut x, 3);
            let lt = transpose(&l, n, n);
            assert!(max_diff(&naive_mul(&lt, &x, n, n, 3), &b) < 1e-10, "L^T solve n {n}");
        }
    }

    /// `cargo test --release --lib -- --ignored --nocapture timing_linalg`
    #[test]
    #[ignore]
    fn timing_linalg() {
        for &n in &[500usize, 1000] {
            let a = uniform(n * n, 1);
            let b = uniform(n * n, 2);
            let s = gram(&a, n, n);
            let mut sp = s.clone();
            for i in 0..n {
                sp[i * n + i] += 1.0;
            }
            let time = |label: &str, f: &mut dyn FnMut()| {
                let mut best = f64::INFINITY;
                for _ in 0..3 {
                    let t = std::time::Instant::now();
                    f();
                    best = best.min(t.elapsed().as_secs_f64());
                }
                println!("n {n} {label}: {:.1} ms", best * 1e3);
            };
            for th in [1, 2] {
                let mut l = a.clone();
                for i in 0..n {
                    for j in i + 1..n {
                        l[i * n + j] = 0.0;
                    }
                }
                let lt = transpose(&l, n, n);
                let mut c = vec![0.0; n * n];
                time(&format!("gemm full t{th}"), &mut || gemm_threads(&mut c, n, Tri::Full, 1.0, Op::new(&a, n), Op::new(&b, n), n, n, n, th));
                time(&format!("gemm xtx t{th}"), &mut || gemm_threads(&mut c, n, Tri::Upper, 1.0, Op::new(&lt, n).upper(), Op::t(&lt, n).lower(), n, n, n, th));
                time(&format!("tri_inv t{th}"), &mut || drop(tri_lower_inverse_t_threads(&l, n, th)));
                time(&format!("chol t{th}"), &mut || drop(cholesky_threads(&sp, n, "s", th)));
            }
            time("matmul", &mut || drop(matmul(&a, &b, n, n, n)));
            time("matmul_sym", &mut || drop(matmul_sym(&a, &b, n)));
            time("cholesky", &mut || drop(cholesky(&sp, n, "s").unwrap()));
            let l = cholesky(&sp, n, "s").unwrap();
            time("tri_lower_inverse_t", &mut || drop(tri_lower_inverse_t(&l, n)));
            time("cholesky_inverse", &mut || drop(cholesky_inverse(&l, n)));
        }
    }
}
