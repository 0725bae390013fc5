//! Reading clouds and writing meshes. Every reader returns a `Result` whose error says what is
//! wrong and where; none of them panics or allocates more than the input can justify.

pub mod gltf;
pub mod mesh_out;
pub mod ply;
mod summary;

pub use summary::FEW_POINTS;
