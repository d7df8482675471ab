//! Where along each ray the field is evaluated.
//!
//! - [`stratified`]: stratified samples over [near, far] and inverse-CDF (`sample_pdf`)
//!   resampling ([`SamplingConfig`], [`DenseSamples`]).
//! - [`occupancy`]: the occupancy grid for empty-space skipping and its file format.
//! - [`contraction`]: the scene contraction of unbounded captures (what the grids see).

pub mod contraction;
pub mod occupancy;
pub mod stratified;

pub use contraction::Contraction;
pub use occupancy::OccupancyGrid;
pub use stratified::{DenseSamples, SamplingConfig};
