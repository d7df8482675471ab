//! A trained field as plain data, whatever its kind: what the trainer and the nerf-pytorch
//! import hand to the ONNX compiler.

use super::kind::FieldKind;
use super::mlp::PlainNetwork;
use super::ngp::PlainNgp;

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
