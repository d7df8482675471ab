//! The trainable radiance field: positional encoding and the NeRF MLP.

mod encoding;
mod mlp;
mod model;
mod ngp;

pub use encoding::encode;
pub use mlp::NerfMlp;
pub use model::NerfModel;
pub use ngp::{GridInputs, NgpField, NgpMlps, trunc_exp};
