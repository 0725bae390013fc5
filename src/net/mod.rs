//! The network prior: a reduced ConvONet (triplane variant), inference only.
//!
//! `docs/network.md` is the contract with the PyTorch training code; this module implements it
//! twice — [`cpu`], a plain f32 reference written to be read, and [`gpu`], WGSL compute kernels
//! for real workloads — and `tests/net.rs` checks both against fixtures exported by PyTorch.
//!
//! Shape of the module: [`weights`] turns a safetensors file into a validated [`Weights`] whose
//! [`NetConfig`] comes from the file's metadata (so a retrain at other sizes needs no code
//! change); the geometry shared by both implementations (plane coordinates, cell indices, the
//! cell → points lists the encoder pools over) lives once, in `geometry`, because it is where the
//! two must agree bit for bit: a point moved across a cell boundary changes the result
//! discontinuously, everything else only by rounding.

pub mod cpu;
mod geometry;
pub mod gpu;
mod json;
pub mod weights;

pub use gpu::{Decoder, GpuNet, GpuPlanes};
pub use geometry::{cell_index, plane_uv, Cells, Planes, PLANES, UV_MAX};
pub use weights::{NetConfig, NetError, Weights, ENCODER_BLOCKS, FORMAT, PRIOR};
