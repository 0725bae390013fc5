//! Reading clouds and meshes, writing meshes. Every reader returns a `Result` whose error says
//! what is wrong and where; none of them panics or allocates more than the input can justify.

pub mod gltf;
pub mod mesh_out;
#[cfg(all(feature = "read-glb", not(target_arch = "wasm32")))]
pub mod gltf_read;
pub mod obj;
pub mod ply;
mod summary;

pub use summary::FEW_POINTS;
