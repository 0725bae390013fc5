//! Reading clouds and meshes, writing meshes. Every reader returns a `Result` whose error says
//! what is wrong and where; none of them panics or allocates more than the input can justify.

#[cfg(not(target_arch = "wasm32"))]
pub mod atomic;
mod builder;
mod bytes;
pub mod gltf;
pub mod mesh_out;
pub mod meshopt_codec;
#[cfg(all(feature = "read-glb", not(target_arch = "wasm32")))]
pub mod gltf_read;
pub mod e57;
pub mod las;
pub mod obj;
pub mod ply;
pub mod scan;
mod scan_file;
pub mod text;

pub use scan::{read_cloud, ScanError, ScanFile, ScanFormat};
pub use scan_file::FEW_POINTS;
