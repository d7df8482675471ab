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
//! - [`occupancy`]: the occupancy grid for empty-space skipping.
//! - [`metrics`], [`imageio`]: PSNR/SSIM, PNG/GIF output and depth colouring.
//! - [`frames`]: rendering a list of views to PNGs, depth maps, `.npy`, metrics and a GIF.
#![warn(missing_docs)]

pub mod camera;
pub mod camera_model;
pub mod compositing;
pub mod dataset;
pub mod error;
pub mod frames;
pub mod imageio;
pub mod metrics;
pub mod ndc;
pub mod network;
pub mod npy;
pub mod occupancy;
pub mod rng;
pub mod render;
pub mod sampling;
pub mod scene_transform;

pub use camera::{Intrinsics, Pose, Rays};
pub use camera_model::{OpenCvDistortion, PinholeCamera, PixelCenter};
pub use scene_transform::SceneTransform;
pub use compositing::{Composited, composite};
pub use error::{Error, Result};
pub use rng::Rng;
pub use sampling::{DenseSamples, SamplingConfig};
