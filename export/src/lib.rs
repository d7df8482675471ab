//! The ONNX compiler: turns plain NeRF networks ([`nerf_core::field::mlp::PlainNetwork`]) into
//! ONNX graphs written with our own prost messages, and writes scene bundles
//! (`coarse.onnx`, `fine.onnx`, `scene.json`) that a renderer needs nothing else to use.
//!
//! It does not depend on burn: any network given as plain data can be compiled. [`import`] reads
//! models trained elsewhere (nerf-pytorch checkpoints) into bundles.
#![warn(missing_docs)]

pub mod bundle;
pub mod graph;
pub mod hash_grid;
pub mod import;
pub mod ngp;
pub mod proto;

pub use bundle::{Bundle, NgpBundle, SceneDescription, read_bundle_network, read_occupancy, read_scene, write_bundle, write_ngp_bundle};
pub use graph::{DEFAULT_OPSET, check_contract, compile, read_network};

/// Why a network could not be compiled or a bundle written.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The network's description or weights are inconsistent.
    #[error("invalid network: {0}")]
    Network(String),
    /// A requested option is not supported.
    #[error("{0}")]
    Unsupported(String),
    /// Reading or writing a bundle file failed (the core's error names the file).
    #[error(transparent)]
    File(#[from] nerf_core::Error),
}
