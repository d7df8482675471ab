//! Neural radiance fields on burn: the trainable fields behind one seam, training with
//! checkpoints, and evaluation/rendering through the shared burn-free core
//! ([`nerf_core`], re-exported as [`core`]).
#![warn(missing_docs)]

pub use nerf_core as core;

pub mod backend;
pub mod bench;
pub mod config;
pub mod error;
pub mod evaluate;
pub mod export;
pub mod field;
pub mod inference;
pub mod live;
pub mod lpips;
pub mod mesh;
pub mod plot;
pub mod process_data;
pub mod run_dir;
pub mod train;

pub use error::{Error, Result};
