//! The burn-free core of the NeRF system.
//!
//! Everything here is plain Rust over `f32` slices, shared by the burn trainer, the ONNX
//! compiler and the onnxruntime renderer, so that rays, samples and compositing are written
//! once. The folders read in the order data flows:
//!
//! - [`camera`]: intrinsics, camera-to-world poses, pixel → ray (OpenGL convention), the full
//!   pinhole model of real captures, NDC rays, the recorded placement transform.
//! - [`dataset`]: the Blender (`transforms_*.json`) parser, downscaling, a generated scene, and
//!   the parsers of real captures (instant-ngp/nerfstudio, LLFF) into one `Capture` type.
//! - [`sample`]: stratified and inverse-CDF samples along rays; the occupancy grid.
//! - [`field`]: what a renderer asks of a field ([`field::Field`]), and each kind as plain data
//!   (the NeRF MLP, the instant-ngp hash-grid field).
//! - [`render`]: compositing, the inference renderers (dense hierarchical, marching through the
//!   grid) over one front-to-back accumulator, PSNR/SSIM.
//! - [`frames`]: which views to render, the frames written (PNG, depth, `.npy`, metrics, GIF),
//!   a render split across processes and its merge.
//! - [`io`]: crash-safe writes, limits on what is read, `.npy`, images.
//! - [`mesh`]: a field's surface by marching cubes, written as a binary PLY.
#![warn(missing_docs)]

pub mod camera;
pub mod dataset;
pub mod error;
pub mod field;
pub mod frames;
pub mod io;
pub mod mesh;
pub mod render;
pub mod rng;
pub mod sample;

pub use camera::{
    Intrinsics, OpenCvDistortion, PinholeCamera, PixelCenter, Pose, Rays, SceneTransform,
};
pub use error::{Error, Result};
pub use render::compositing::{Composited, composite};
pub use rng::Rng;
pub use sample::{DenseSamples, SamplingConfig};
