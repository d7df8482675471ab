//! Files in and out.
//!
//! - [`atomic`]: files and directories written whole or not at all (crash-safe).
//! - [`limits`]: bounds on sizes read from files and options, file names inside a directory.
//! - [`npy`]: NumPy `.npy` reading (LLFF's `poses_bounds.npy`).
//! - [`image`]: PNG/GIF output and depth colouring.
//! - [`frames`]: rendering a list of views to PNGs, depth maps, `.npy`, metrics and a GIF;
//!   [`views`]: which views (an orbit, a dataset's split, a bundle's poses);
//!   [`camera_path`]: nerfstudio's `camera_path.json` as views.
//! - [`shard`]: one render split across processes (`--shard i/n`) and what each part finished;
//!   [`merge`]: assembling the GIF, metrics and contact sheet from the parts.

pub mod atomic;
pub mod camera_path;
pub mod frames;
pub mod image;
pub mod limits;
pub mod merge;
pub mod npy;
pub mod shard;
pub mod views;
