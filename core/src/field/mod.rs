//! Radiance fields: what every renderer asks of one ([`Field`]) and each kind as plain data.
//!
//! - [`eval`]: the [`Field`] trait the renderers call, one batch of points at a time.
//! - [`kind`]: the one description of the kinds ([`FieldKind`], [`Role`], [`PlainField`]).
//! - [`layer`]: a dense layer as plain data ([`DenseLayer`]).
//! - [`mlp`]: the NeRF MLP (positional encoding, coarse and fine networks).
//! - [`ngp`]: the instant-ngp field (hash grid, spherical harmonics, two tiny MLPs).

pub mod eval;
pub mod kind;
pub mod layer;
pub mod mlp;
pub mod ngp;

pub use eval::{Field, FieldOutput, Stage};
pub use kind::{FieldKind, PlainField, Role};
pub use layer::DenseLayer;
