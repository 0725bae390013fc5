//! The browser entry points (wasm32 only): PLY parsing, the 3D viewer and the reconstruction
//! (`api`, run in a Web Worker by `web/worker.js`), exposed to JavaScript through wasm-bindgen.
//! The DOM (drop zone, panels, events) stays in `web/app.js`; Rust owns the data and the GPU.

mod api;
mod viewer;

pub use api::{prepare_engine, reconstruct, simulate_device_loss};
pub use viewer::Viewer;

use wasm_bindgen::prelude::*;

use crate::io::ply;

#[wasm_bindgen(start)]
pub fn start() {
    console_error_panic_hook::set_once();
}

/// A parsed cloud, held on the Rust side; the page reads its summary through getters.
#[wasm_bindgen]
pub struct Cloud {
    pub(crate) parsed: ply::PlyCloud,
}

#[wasm_bindgen]
impl Cloud {
    /// Number of points kept (after dropping non-finite ones).
    #[wasm_bindgen(getter)]
    pub fn count(&self) -> usize {
        self.parsed.cloud.len()
    }

    /// [min x, min y, min z, max x, max y, max z].
    #[wasm_bindgen(getter)]
    pub fn bounds(&self) -> Vec<f32> {
        match self.parsed.cloud.bounds() {
            Some(b) => vec![b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2]],
            None => vec![],
        }
    }

    #[wasm_bindgen(getter)]
    pub fn has_colors(&self) -> bool {
        self.parsed.cloud.colors.is_some()
    }

    #[wasm_bindgen(getter)]
    pub fn has_normals(&self) -> bool {
        self.parsed.cloud.normals.is_some()
    }

    /// One line per thing the user should know (dropped points, ignored properties…).
    #[wasm_bindgen(getter)]
    pub fn warnings(&self) -> Vec<String> {
        self.parsed.warnings()
    }

    /// An even subsample (every k-th point) of at most `max` positions, xyz flat: what the page
    /// keeps of a cloud after drawing it, for the live trim.
    pub fn sample_positions(&self, max: usize) -> Vec<f32> {
        let p = &self.parsed.cloud.positions;
        let step = p.len().div_ceil(max.max(1)).max(1);
        p.iter().step_by(step).flatten().copied().collect()
    }

    /// A one-line description of the file's layout (format, properties).
    #[wasm_bindgen(getter)]
    pub fn layout(&self) -> String {
        self.parsed.describe_layout()
    }
}

/// Parses PLY bytes; the error message says what is wrong and where.
#[wasm_bindgen]
pub fn parse_ply(bytes: &[u8]) -> Result<Cloud, JsError> {
    ply::read_ply(bytes).map(|parsed| Cloud { parsed }).map_err(|e| JsError::new(&e.to_string()))
}
