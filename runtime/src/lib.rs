//! The NeRF runtime: renders exported scene bundles (`coarse.onnx`, `fine.onnx`, `scene.json`,
//! `occupancy.bin`) through onnxruntime. Rays, sampling and compositing are the shared
//! `nerf_core` code, the same the burn trainer and `nerf render` use; onnxruntime only
//! evaluates the networks. No burn anywhere in this crate's dependencies.
//!
//! onnxruntime is loaded at run time (ort `load-dynamic`) from `$ORT_DYLIB_PATH` or the PyPI
//! wheel installed by `scripts/setup.sh`; see [`environment::library_path`].
#![warn(missing_docs)]

pub mod environment;
pub mod error;
pub mod field;
pub mod gpu;
pub mod lpips;
pub mod mesh;
pub mod network;
pub mod scene;
pub mod serve;
pub mod site;

pub use error::{Result, RuntimeError};
pub use field::OrtField;
pub use network::OrtNetwork;
pub use scene::{OpenOptions, OrtScene};
