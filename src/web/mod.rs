//! The browser entry points (wasm32 only): cloud parsing (every format of [`crate::io::scan`]), the 3D viewer and the reconstruction
//! (`api`, run in a Web Worker by `web/worker.js`), exposed to JavaScript through wasm-bindgen.
//! The DOM (drop zone, panels, events) stays in `web/app.js`; Rust owns the data and the GPU.

mod api;
mod cxx_alloc;
mod cloud;
mod js;
mod viewer;

pub use api::{preflight, prepare_engine, reconstruct, settings_table, simulate_device_loss};
pub use cloud::{cloud_extensions, parse_cloud, Cloud};
pub use viewer::Viewer;

use wasm_bindgen::prelude::*;

#[wasm_bindgen(start)]
pub fn start() {
    console_error_panic_hook::set_once();
}
