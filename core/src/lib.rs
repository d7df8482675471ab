//! The burn-free core of the NeRF system.
//!
//! Everything here is plain Rust over `f32` slices, shared by the burn trainer, the ONNX
//! export checks and the onnxruntime renderer, so that rays, samples and compositing are
//! written once:
//!
//! - [`camera`]: intrinsics, camera-to-world poses, pixel → ray (OpenGL convention).
//! - [`camera_model`]: the full pinhole camera of real captures (fx, fy, cx, cy, pixel
//!   convention, OpenCV distortion undone on the rays); [`ndc`]: NDC rays for forward-facing
//!   scenes; [`scene_transform`]: the recorded normalisation of a capture's poses.
//! - [`sampling`]: stratified samples along rays and inverse-CDF (`sample_pdf`) resampling.
//! - [`compositing`]: α from density, transmittance, weights, rgb/depth/acc, white background.
//! - [`dataset`]: the Blender (`transforms_*.json`) parser, downscaling, a generated scene, and
//!   the parsers of real captures (instant-ngp/nerfstudio, LLFF) into one `Capture` type.
//! - [`npy`]: NumPy `.npy` reading (LLFF's `poses_bounds.npy`).
//! - [`network`]: the NeRF MLP described as plain data (sizes, skips, encodings, weights).
//! - [`hash_grid`]: the multiresolution hash encoding (tiny-cuda-nn's), its backward pass and
//!   sparse Adam; [`spherical_harmonics`]: the degree-4 direction encoding; [`ngp`]: the
//!   instant-ngp field (grid + two small MLPs) as plain data.
//! - [`occupancy`]: the occupancy grid for empty-space skipping and its file format.
//! - [`render`]: the inference renderers (dense hierarchical, marching through the grid) over
//!   one front-to-back accumulator; the field that evaluates the networks is a trait.
//! - [`metrics`], [`imageio`]: PSNR/SSIM, PNG/GIF output and depth colouring.
//! - [`atomic`]: files and directories written whole or not at all (crash-safe).
//! - [`limits`]: bounds on sizes read from files and options, file names inside a directory.
//! - [`frames`]: rendering a list of views to PNGs, depth maps, `.npy`, metrics and a GIF.
#![warn(missing_docs)]

pub mod atomic;
pub mod camera;
pub mod camera_model;
pub mod compositing;
pub mod dataset;
pub mod error;
pub mod frames;
pub mod hash_grid;
pub mod imageio;
pub mod limits;
pub mod metrics;
pub mod ndc;
pub mod network;
pub mod ngp;
pub mod npy;
pub mod occupancy;
pub mod rng;
pub mod render;
pub mod sampling;
pub mod scene_transform;
pub mod spherical_harmonics;

pub use camera::{Intrinsics, Pose, Rays};
pub use camera_model::{OpenCvDistortion, PinholeCamera, PixelCenter};
pub use compositing::{Composited, composite};
pub use error::{Error, Result};
pub use rng::Rng;
pub use sampling::{DenseSamples, SamplingConfig};
pub use scene_transform::SceneTransform;
