//! The one description of the built-in field kinds. [`field_kinds!`](crate::field_kinds) lists
//! each kind once (its name, its folder, its `config.toml` section, its shape and plain-data
//! types, what differs about it); [`FieldKind`], [`PlainField`] and [`FieldShapes`] here, and
//! each crate's dispatch to its kinds' folders, are expanded from that list. Adding a kind is a
//! line there and a folder of the same name in each crate's `field/`.

use serde::{Deserialize, Serialize};

/// The built-in field kinds, each once: calls `$callback!` with the list. Each crate expands
/// it where a [`FieldKind`] or a [`PlainField`] becomes its kind (folders named `folder` in
/// that crate's `field/`).
#[macro_export]
macro_rules! field_kinds {
    ($callback:ident) => {
        $callback! {
            /// The NeRF MLPs: coarse and fine networks with positional encoding.
            Mlp { folder: mlp, name: "mlp", section: network, shape: NetworkSpec, plain: PlainMlp, random_backgrounds: false, jittered_rays: false },
            /// The instant-ngp field: a hash grid and two tiny MLPs, defined inside its box only
            /// and always marched.
            Ngp { folder: ngp, name: "ngp", section: ngp, shape: NgpSpec, plain: PlainNgp, random_backgrounds: true, jittered_rays: true },
        }
    };
}

/// What the description asks of each kind's shape (its `config.toml` section).
pub trait KindShape {
    /// Check the shape; the problem, naming the key, when it is impossible.
    fn check(&self) -> Result<(), String>;
    /// The box the field is defined in (contracted or not), for a kind defined there only.
    fn field_box(&self) -> Option<crate::field::ngp::hash_grid::GridBound>;
}

macro_rules! describe {
    ($($(#[$doc:meta])* $kind:ident { folder: $folder:ident, name: $name:literal, section: $section:ident, shape: $shape:ident, plain: $plain:ident, random_backgrounds: $random:literal, jittered_rays: $jitter:literal },)*) => {
        /// Which kind of radiance field a run trains: the one name the training config (and
        /// with it the checkpoints), graph metadata (`nerf.field`) and `scene.json` carry.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
        #[serde(rename_all = "kebab-case")]
        pub enum FieldKind {
            $($(#[$doc])* $kind,)*
        }

        impl FieldKind {
            /// Every kind, the default first.
            pub const ALL: &[FieldKind] = &[$(FieldKind::$kind),*];

            /// The kind as written in configs and metadata.
            pub fn name(self) -> &'static str {
                match self {
                    $(FieldKind::$kind => $name,)*
                }
            }

            /// Whether its trainer composites each training ray on a colour of its own
            /// (`random` backgrounds); the others train on the render background.
            pub fn trains_on_random_backgrounds(self) -> bool {
                match self {
                    $(FieldKind::$kind => $random,)*
                }
            }

            /// Whether its trainer can send each training ray through a random point of its
            /// pixel (`jitter_pixels`); the others train through pixel centres.
            pub fn trains_on_jittered_rays(self) -> bool {
                match self {
                    $(FieldKind::$kind => $jitter,)*
                }
            }
        }

        /// A trained field's shape and weights, by kind.
        #[derive(Debug, Clone, PartialEq)]
        pub enum PlainField {
            $($(#[$doc])* $kind(super::$folder::$plain),)*
        }

        impl PlainField {
            /// Its kind.
            pub fn kind(&self) -> FieldKind {
                match self {
                    $(PlainField::$kind(_) => FieldKind::$kind,)*
                }
            }
        }

        /// Each kind's shape, as `config.toml` carries them (one section per kind, whatever
        /// kind a run trains; absent sections take the kind's defaults).
        #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
        pub struct FieldShapes {
            $(
                #[doc = concat!("The `", $name, "` field's shape.")]
                #[serde(default)]
                pub $section: super::$folder::$shape,
            )*
        }

        impl FieldShapes {
            /// Check `kind`'s shape; the problem names its section.
            pub fn check(&self, kind: FieldKind) -> Result<(), String> {
                match kind {
                    $(FieldKind::$kind => KindShape::check(&self.$section).map_err(|e| format!("{}: {e}", stringify!($section))),)*
                }
            }

            /// The box `kind`'s field is defined in, for a kind defined there only; with the
            /// section that says so.
            pub fn field_box(&self, kind: FieldKind) -> Option<(&'static str, crate::field::ngp::hash_grid::GridBound)> {
                match kind {
                    $(FieldKind::$kind => KindShape::field_box(&self.$section).map(|b| (stringify!($section), b)),)*
                }
            }
        }
    };
}

crate::field_kinds!(describe);

impl Default for FieldKind {
    fn default() -> Self {
        FieldKind::ALL[0]
    }
}
