//! The trainable radiance fields: the NeRF MLPs with positional encoding, and the hash-grid
//! field with tiny MLPs.

mod encoding;
mod mlp;
mod model;
pub mod ngp;
mod trained;

pub use encoding::encode;
pub use mlp::NerfMlp;
pub use model::NerfModel;
pub use ngp::{GridInputs, NgpField, NgpMlps, trunc_exp};
pub use trained::TrainedField;
