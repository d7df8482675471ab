//! Rendered frames: which views to render, writing them, and one render split across processes.
//! The files import one way, each only those above it in this list:
//!
//! - [`spec`]: what the others share: a frame to render, a part of a render (`--shard i/n`), the
//!   GIF, the names of the files in an output directory, what a render reports.
//! - [`views`]: which views (an orbit, a dataset's split, a bundle's poses);
//!   [`camera_path`]: nerfstudio's `camera_path.json` as views.
//! - [`raw`]: a frame's exact values as `.npy`, written and read back.
//! - [`manifest`]: the record each part of a render keeps of what it finished.
//! - [`merge`]: assembling the GIF, metrics and contact sheet from the parts' records.
//! - [`write`](mod@write): rendering a list of views to PNGs, depth maps, `.npy`, metrics and a GIF.

pub mod camera_path;
pub mod manifest;
pub mod merge;
pub mod raw;
pub mod spec;
pub mod views;
pub mod write;
