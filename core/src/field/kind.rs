//! The one description of the built-in field kinds: their names ([`FieldKind`], what configs,
//! graph metadata and `scene.json` carry) and a trained field of each as plain data
//! ([`PlainField`]); and the roles graphs play in a bundle ([`Role`]), whatever the kind.

use serde::{Deserialize, Serialize};

use super::eval::Stage;
use super::mlp::PlainNetwork;
use super::ngp::PlainNgp;

/// Which kind of radiance field a run trains: the one name the training config (and with it
/// the checkpoints), graph metadata (`nerf.field`) and `scene.json` carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FieldKind {
    /// The NeRF MLPs (coarse and fine, positional encoding; [`super::mlp`]).
    #[default]
    Mlp,
    /// The instant-ngp field (hash grid and tiny MLPs; [`super::ngp`]), defined inside its box
    /// only and always marched.
    Ngp,
}

impl FieldKind {
    /// Whether its trainer composites each training ray on a colour of its own (`random`
    /// backgrounds); the others train on the render background.
    pub fn trains_on_random_backgrounds(self) -> bool {
        self == FieldKind::Ngp
    }

    /// The kind as written in configs and metadata.
    pub fn name(self) -> &'static str {
        match self {
            FieldKind::Mlp => "mlp",
            FieldKind::Ngp => "ngp",
        }
    }
}

/// What one graph of a bundle evaluates: the whole field, or one stage of the hierarchical
/// sampler. Bundle files are named after it (`field.onnx`, `coarse.onnx`, `fine.onnx`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Role {
    /// The whole field, whatever the stage.
    Field,
    /// The coarse network, on the stratified samples.
    Coarse,
    /// The fine network, on coarse ∪ importance samples.
    Fine,
}

impl Role {
    /// The role as written in `scene.json` and in file names.
    pub fn name(self) -> &'static str {
        match self {
            Role::Field => "field",
            Role::Coarse => "coarse",
            Role::Fine => "fine",
        }
    }

    /// Whether this graph answers for `stage`.
    pub fn serves(self, stage: Stage) -> bool {
        match self {
            Role::Field => true,
            Role::Coarse => stage == Stage::Coarse,
            Role::Fine => stage == Stage::Fine,
        }
    }
}

/// A trained field's shape and weights.
#[derive(Debug, Clone, PartialEq)]
pub enum PlainField {
    /// The NeRF MLPs: the coarse network and, for hierarchical sampling, the fine one.
    Mlp {
        /// The coarse network.
        coarse: PlainNetwork,
        /// The fine network, if any.
        fine: Option<PlainNetwork>,
    },
    /// The hash-grid field.
    Ngp(PlainNgp),
}

impl PlainField {
    /// Its kind.
    pub fn kind(&self) -> FieldKind {
        match self {
            PlainField::Mlp { .. } => FieldKind::Mlp,
            PlainField::Ngp(_) => FieldKind::Ngp,
        }
    }
}
