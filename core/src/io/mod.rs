//! Files in and out.
//!
//! - [`atomic`]: files and directories written whole or not at all (crash-safe).
//! - [`limits`]: bounds on sizes read from files and options, file names inside a directory.
//! - [`npy`]: NumPy `.npy` reading (LLFF's `poses_bounds.npy`).
//! - [`image`]: PNG/GIF output and depth colouring.
//! - [`frames`]: rendering a list of views to PNGs, depth maps, `.npy`, metrics and a GIF;
//!   [`views`]: which views (an orbit, a dataset's split, a bundle's poses).

pub mod atomic;
pub mod frames;
pub mod image;
pub mod limits;
pub mod npy;
pub mod views;
