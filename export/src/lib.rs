//! The ONNX compiler: turns trained fields ([`CompileField`]; the built-in kinds as
//! [`nerf_core::field::PlainField`]) into ONNX graphs written with our own prost messages
//! ([`nerf_bundle::proto`]), and writes scene bundles ([`nerf_bundle`]) that a renderer needs
//! nothing else to use.
//!
//! It does not depend on burn: any field given as plain data can be compiled. Each kind's
//! lowering is in its folder of [`field`] (the NeRF MLPs' also reads nerf-pytorch checkpoints).
#![warn(missing_docs)]

pub mod builder;
pub mod bundle;
pub mod field;
pub mod lpips;
pub mod options;

/// The ONNX messages, shared with the bundle reader.
pub use nerf_bundle::proto;

pub use builder::DEFAULT_OPSET;
pub use bundle::{Bundle, write_bundle};
pub use field::CompileField;
pub use options::{CompileOptions, TablePrecision};

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
