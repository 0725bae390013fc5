//! nkrr: surface reconstruction from raw point clouds, in the browser, on WebGPU.
//!
//! Data flows one way through one module per stage (see `docs/architecture.md`):
//! `io` (every scan format) → `cloud` → `net` → `sample` → `krr` → `field` → `mesh` → `io::gltf`;
//! [`pipeline`] strings the stages together, [`plan`] sizes them for the machine, and every
//! setting is defined once in [`settings`].
//! [`eval`] measures a reconstruction against a ground-truth mesh (the paper's protocol).
//! The same code builds natively (tests, the `nkrr` CLI) and for `wasm32-unknown-unknown`.

pub mod cloud;
pub mod eigen3;
pub mod eval;
pub mod field;
pub mod gpu;
pub mod io;
pub mod krr;
pub mod mesh;
pub mod net;
pub mod orient;
pub mod outliers;
pub(crate) mod par;
pub mod pipeline;
pub mod plan;
pub mod poisson;
pub mod reconstruction;
pub mod rng;
pub mod sample;
pub mod scene;
pub mod settings;
pub mod units;

#[cfg(target_arch = "wasm32")]
pub mod web;

pub use cloud::PointCloud;
