//! `krr::linalg` (ours) against faer 0.24 in the wasm32 build, the wasm half of
//! `examples/linalg_vs_faer.rs` (same matrices, same hash, same table): the Cholesky factor, a
//! single-right-hand-side solve and the inverse of a symmetric positive-definite m × m matrix,
//! on one thread (wasm32 has none). Timed with `performance.now()` (`std::time::Instant`
//! panics on wasm32-unknown-unknown).

use faer::Par;
use nkrr::krr::linalg;
use wasm_bindgen::prelude::*;

fn now_s() -> f64 {
    let perf = js_sys::Reflect::get(&js_sys::global(), &JsValue::from_str("performance")).expect("performance");
    let now = js_sys::Reflect::get(&perf, &JsValue::from_str("now")).expect("performance.now");
    let now: js_sys::Function = now.into();
    now.call0(&perf).expect("performance.now()").as_f64().expect("a number") / 1e3
}

#[path = "../../../examples/shared/linalg_compare.rs"]
mod compare;

/// The table rows (markdown), as the native example prints them.
#[wasm_bindgen]
pub fn run() -> String {
    faer::set_global_parallelism(Par::Seq);
    let simd = if cfg!(target_feature = "simd128") { "simd128" } else { "no simd128" };
    format!("ours: {} thread (wasm32, {simd}); faer: 1 (Par::Seq)\n{}", linalg::max_threads(), compare::table(&now_s))
}
