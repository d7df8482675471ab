//! Files in and out, below everything that renders: what the other folders build their files
//! from. Nothing here knows of frames or shards ([`crate::frames`] writes those).
//!
//! - [`atomic`]: files and directories written whole or not at all (crash-safe).
//! - [`limits`]: bounds on sizes read from files and options, file names inside a directory.
//! - [`npy`]: NumPy `.npy` reading (LLFF's `poses_bounds.npy`).
//! - [`image`]: PNG/JPEG decoding, PNG/GIF output and depth colouring.

pub mod atomic;
pub mod image;
pub mod limits;
pub mod npy;
