//! Radiance fields: what every renderer asks of one ([`Field`]) and each kind as plain data.
//!
//! - [`eval`]: the [`Field`] trait the renderers call, one batch of points at a time.
//! - [`kind`]: which kinds there are ([`FieldKind`]) and the roles of their graphs ([`Role`]).
//! - [`layer`]: a dense layer as plain data ([`DenseLayer`]).
//! - [`mlp`]: the NeRF MLP (positional encoding, coarse and fine networks).
//! - [`ngp`]: the instant-ngp field (hash grid, spherical harmonics, two tiny MLPs).
//! - [`plain`]: a trained field of any kind as plain data ([`PlainField`]).

pub mod eval;
pub mod kind;
pub mod layer;
pub mod mlp;
pub mod ngp;
pub mod plain;

pub use eval::{Field, FieldOutput, Stage};
pub use kind::{FieldKind, Role};
pub use layer::DenseLayer;
pub use plain::PlainField;
