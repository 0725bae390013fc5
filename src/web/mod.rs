//! The browser entry points (wasm32 only): cloud parsing (every format of [`crate::io::scan`]), the 3D viewer and the reconstruction
//! (`worker_api`, run in a Web Worker by `web/worker.js`; `page_api` for the page's own calls), exposed to JavaScript through wasm-bindgen.
//! The DOM (drop zone, panels, events) stays in `web/app.js`; Rust owns the data and the GPU.

mod options;
mod page_api;
mod worker_api;
mod cxx_alloc;
mod cloud;
mod js;
mod viewer;

pub use page_api::{parse_setting, preflight, settings_table};
pub use worker_api::{prepare_engine, reconstruct, simulate_device_loss};
pub use cloud::{cloud_extensions, parse_cloud, Cloud};
pub use viewer::Viewer;

use wasm_bindgen::prelude::*;

/// The threaded build's pool of Web Workers: `initThreadPool(n)` (wasm-bindgen-rayon) starts it
/// and `usePoolThreads(n)` hands it to the kernels (`web/worker.js` calls both, in that order).
#[cfg(feature = "wasm-threads")]
pub use wasm_bindgen_rayon::init_thread_pool;

/// After `initThreadPool(n)` has resolved: the loops and the linear algebra split over the pool.
#[cfg(feature = "wasm-threads")]
#[wasm_bindgen(js_name = usePoolThreads)]
pub fn use_pool_threads(n: usize) {
    crate::par::set_pool_threads(n);
}

/// Threads the kernels of this instance split over: the pool's, or 1 (the plain build, or the
/// threaded one before its pool is up).
#[wasm_bindgen(js_name = poolThreads)]
pub fn pool_threads() -> usize {
    crate::par::threads()
}

#[wasm_bindgen(start)]
pub fn start() {
    console_error_panic_hook::set_once();
}
