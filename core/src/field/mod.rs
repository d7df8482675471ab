//! Radiance fields: what every renderer asks of one ([`Field`]) and each kind as plain data.
//!
//! - [`eval`]: the [`Field`] trait the renderers call, one batch of points at a time.
//! - [`kind`]: the one description of the kinds ([`crate::field_kinds!`]: [`FieldKind`],
//!   [`PlainField`], [`FieldShapes`]); [`role`]: the roles of a bundle's graphs.
//! - [`layer`]: a dense layer as plain data ([`DenseLayer`]).
//! - one folder per kind (its shape, its weights as plain data, what renders them without burn).

pub mod eval;
pub mod kind;
pub mod layer;
pub mod role;

macro_rules! folders {
    ($($(#[$doc:meta])* $kind:ident { folder: $folder:ident, $($rest:tt)* },)*) => {
        $(pub mod $folder;)*
    };
}
crate::field_kinds!(folders);

pub use eval::{Field, FieldOutput, Stage};
pub use kind::{FieldKind, FieldShapes, KindShape, PlainField};
pub use layer::DenseLayer;
pub use role::Role;
