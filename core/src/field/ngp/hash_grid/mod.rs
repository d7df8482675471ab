//! The multiresolution hash encoding of instant-ngp, as tiny-cuda-nn defines it, in plain Rust:
//!
//! - [`config`]: [`HashGridConfig`] (L, F, T, N_min, N_max) and the per-level layout (scale,
//!   resolution, dense or hashed, offset into the table); [`GridBound`], the world box mapped
//!   onto the unit cube.
//! - [`grid`]: the table ([`HashGrid`]), its forward pass `[n, 3] → [n, L·F]` and its backward
//!   pass into a sparse, reusable [`HashGridGradient`].
//!
//! The table is not a burn parameter: its features enter the network as a leaf tensor, and the
//! gradient read back for that leaf is scattered here by [`HashGrid::backward`].

pub mod config;
pub mod grid;

pub use config::{GridBound, HashGridConfig, LevelLayout, spatial_hash};
pub use grid::{HashGrid, HashGridGradient, corners};
