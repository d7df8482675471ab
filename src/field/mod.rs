//! The trainable radiance field: positional encoding and the NeRF MLP.

mod encoding;
mod mlp;

pub use encoding::encode;
pub use mlp::{NerfMlp, NerfModel};
