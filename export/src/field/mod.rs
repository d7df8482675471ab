//! The compiler's field seam: what a field gives the compiler ([`CompileField`]: its kind's
//! name, whether it is bounded, its graphs by role), and each built-in kind's lowering in its
//! own folder (named as in [`nerf_core::field_kinds!`], which also expands the choice of
//! lowering for a [`PlainField`] here).

use crate::{CompileOptions, ExportError};
use crate::proto::ModelProto;
use nerf_bundle::scene::SceneDescription;
use nerf_core::field::{PlainField, Role};

/// A trained field as the compiler sees it. A kind that implements this (and the contract its
/// graphs follow: `points`, `viewdirs` in; `rgb`, `sigma` out) is written as a bundle every
/// renderer reads, without the compiler or the renderers learning its name.
pub trait CompileField {
    /// The kind's name (`scene.json` `field`).
    fn kind(&self) -> &str;
    /// Half the side of the origin-centred cube the field is defined in, for a field defined
    /// there only (always marched; `scene.json` `bounded`); `None`: defined everywhere.
    fn bounded(&self) -> Option<f32>;
    /// How points are contracted before the field reads them (`scene.json` `contraction`).
    fn contraction(&self) -> Option<nerf_core::sample::Contraction> {
        None
    }
    /// The opset used when none is asked for.
    fn default_opset(&self) -> i64 {
        crate::DEFAULT_OPSET
    }
    /// Its graphs by role as `options` ask (opset, portable operators, table precision; what
    /// does not concern the kind is ignored), each carrying the contract metadata of `scene`
    /// ([`crate::builder::scene_metadata`]); `scene` learns what only the field knows (the
    /// MLPs' encodings, no fine stage for a one-graph field).
    fn compile(&self, scene: &mut SceneDescription, options: &CompileOptions) -> Result<Vec<(Role, ModelProto)>, ExportError>;
}

impl<T: CompileField + ?Sized> CompileField for Box<T> {
    fn kind(&self) -> &str {
        (**self).kind()
    }
    fn bounded(&self) -> Option<f32> {
        (**self).bounded()
    }
    fn contraction(&self) -> Option<nerf_core::sample::Contraction> {
        (**self).contraction()
    }
    fn default_opset(&self) -> i64 {
        (**self).default_opset()
    }
    fn compile(&self, scene: &mut SceneDescription, options: &CompileOptions) -> Result<Vec<(Role, ModelProto)>, ExportError> {
        (**self).compile(scene, options)
    }
}

macro_rules! lowerings {
    ($($(#[$doc:meta])* $kind:ident { folder: $folder:ident, $($rest:tt)* },)*) => {
        $(pub mod $folder;)*

        /// The built-in kinds, each lowered by its folder.
        impl CompileField for PlainField {
            fn kind(&self) -> &str {
                PlainField::kind(self).name()
            }

            fn bounded(&self) -> Option<f32> {
                match self {
                    $(PlainField::$kind(plain) => plain.bounded(),)*
                }
            }

            fn contraction(&self) -> Option<nerf_core::sample::Contraction> {
                match self {
                    $(PlainField::$kind(plain) => plain.contraction(),)*
                }
            }

            fn default_opset(&self) -> i64 {
                match self {
                    $(PlainField::$kind(plain) => plain.default_opset(),)*
                }
            }

            fn compile(&self, scene: &mut SceneDescription, options: &CompileOptions) -> Result<Vec<(Role, ModelProto)>, ExportError> {
                match self {
                    $(PlainField::$kind(plain) => plain.compile(scene, options),)*
                }
            }
        }
    };
}
nerf_core::field_kinds!(lowerings);
