//! Rendered frames: which views to render, writing them, and one render split across processes.
//!
//! - [`views`]: which views (an orbit, a dataset's split, a bundle's poses);
//!   [`camera_path`]: nerfstudio's `camera_path.json` as views.
//! - [`write`]: rendering a list of views to PNGs, depth maps, `.npy`, metrics and a GIF.
//! - [`shard`]: one render split across processes (`--shard i/n`) and what each part finished;
//!   [`merge`]: assembling the GIF, metrics and contact sheet from the parts.

pub mod camera_path;
pub mod merge;
pub mod shard;
pub mod views;
pub mod write;
