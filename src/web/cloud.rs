//! A parsed point cloud on the Rust side, and the entry points that make one from a file's bytes
//! (every format of [`crate::io::scan`]).

use wasm_bindgen::prelude::*;

use super::js::set;
use crate::io::scan::{self, ScanFile};

/// A parsed cloud, held on the Rust side; the page reads its summary through getters.
#[wasm_bindgen]
pub struct Cloud {
    pub(crate) parsed: ScanFile,
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
        self.parsed.layout.clone()
    }

    /// The format recognised from the content: "PLY", "text (XYZ/PTS/CSV)", "LAS/LAZ", "E57".
    #[wasm_bindgen(getter)]
    pub fn format(&self) -> String {
        self.parsed.format.name().to_string()
    }

    /// Points whose normal is all zero (0 without normals; normals are never needed).
    #[wasm_bindgen(getter)]
    pub fn zero_normals(&self) -> usize {
        self.parsed.zero_normals()
    }

    /// The cloud's offset from the origin in the file's coordinates (far-off clouds are read
    /// relative to it; the GLB keeps it as the root translation): [x, y, z].
    #[wasm_bindgen(getter)]
    pub fn origin(&self) -> Vec<f64> {
        self.parsed.cloud.origin.to_vec()
    }

    /// What the cloud's size suggests about its units: `{ units: "mm" | "m" | null, stated:
    /// bool, warn: bool, reason }`; `warn` means millimetres are likely and no units were given.
    #[wasm_bindgen(getter)]
    pub fn units_guess(&self) -> JsValue {
        let g = self.parsed.units_guess();
        let o = js_sys::Object::new();
        set(&o, "units", g.units.map_or(JsValue::NULL, |u| u.code().into()));
        set(&o, "stated", self.parsed.stated_units.is_some());
        set(&o, "warn", g.warn);
        set(&o, "reason", g.reason);
        o.into()
    }
}

/// Parses a point cloud in any supported format (PLY, XYZ/PTS/CSV text, LAS/LAZ, E57), told
/// apart by content; `name` (the file's name, optional) only adds a note when its extension
/// disagrees. The error message says what is wrong and where.
#[wasm_bindgen]
pub fn parse_cloud(bytes: &[u8], name: Option<String>) -> Result<Cloud, JsError> {
    scan::read_cloud(bytes, name.as_deref()).map(|parsed| Cloud { parsed }).map_err(|e| JsError::new(&e.to_string()))
}

/// The file extensions the readers accept, for a file picker's `accept`.
#[wasm_bindgen]
pub fn cloud_extensions() -> Vec<String> {
    scan::EXTENSIONS.iter().map(|e| format!(".{e}")).collect()
}
