//! The kinds of radiance field.

use serde::{Deserialize, Serialize};

/// Which kind of radiance field a run trains and a bundle holds: the one description the
/// training config, checkpoints, graph metadata (`nerf.field`) and `scene.json` carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FieldKind {
    /// The NeRF MLPs (coarse and fine, positional encoding; [`NetworkSpec`]).
    #[default]
    Mlp,
    /// The instant-ngp field (hash grid and tiny MLPs; [`crate::field::ngp::NgpSpec`]), rendered by
    /// marching through the occupancy grid.
    Ngp,
}

impl FieldKind {
    /// The kind as written in configs and metadata.
    pub fn name(self) -> &'static str {
        match self {
            FieldKind::Mlp => "mlp",
            FieldKind::Ngp => "ngp",
        }
    }
}
