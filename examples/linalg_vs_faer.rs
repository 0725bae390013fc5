//! The m × m algebra of a tuning step, `krr::linalg` (ours) against faer, natively: the Cholesky
//! factor, a solve and the inverse of a symmetric positive-definite m × m matrix, as the
//! objective needs them (`krr::mm::mm_forward`). Prints median seconds per operation and a hash
//! of each result's bits, so that two runs with other thread counts show whether the result
//! depends on them:
//!
//!     NKRR_THREADS=1 cargo run --release --features faer-bench --example linalg_vs_faer -- 1
//!     NKRR_THREADS=2 cargo run --release --features faer-bench --example linalg_vs_faer -- 2
//!
//! The argument is faer's thread count (1: sequential); NKRR_THREADS is ours.

use std::time::Instant;

use faer::Par;
use nkrr::krr::linalg;

#[path = "shared/linalg_compare.rs"]
mod compare;

fn main() {
    let faer_threads: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(1);
    let par = if faer_threads <= 1 { Par::Seq } else { Par::rayon(faer_threads) };
    faer::set_global_parallelism(par);
    println!("ours: {} threads (NKRR_THREADS); faer: {faer_threads}", linalg::max_threads());
    let start = Instant::now();
    print!("{}", compare::table(&|| start.elapsed().as_secs_f64()));
}
