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

#[wasm_bindgen(start)]
pub fn start() {
    console_error_panic_hook::set_once();
}
