//! Each field kind's ONNX lowering, in its own folder; this file is the one place that picks
//! the lowering for a [`PlainField`].
//!
//! - [`mlp`]: the NeRF MLPs (positional encoding inside the graph), and the nerf-pytorch import.
//! - [`ngp`]: the hash-grid field (the whole encoding in standard operators).

pub mod mlp;
pub mod ngp;

use crate::ExportError;
use crate::builder::scene_metadata;
use crate::proto::ModelProto;
use ngp::hash_grid::HashOps;
use nerf_bundle::scene::SceneDescription;
use nerf_core::field::{FieldKind, PlainField, Role};

/// The opset used when none is asked for: [`crate::DEFAULT_OPSET`], or for the hash-grid field
/// the lowest with BitwiseXor (18; 17 lowers the hash without bitwise operators).
pub fn default_opset(kind: FieldKind) -> i64 {
    match kind {
        FieldKind::Mlp => crate::DEFAULT_OPSET,
        FieldKind::Ngp => HashOps::Bitwise.min_opset(),
    }
}

/// Each graph of `field` by role, its metadata from `scene` (which learns what only the field
/// knows: the encodings of the MLPs, no fine stage for the hash grid).
pub(crate) fn compile_field(field: &PlainField, scene: &mut SceneDescription, opset: i64) -> Result<Vec<(Role, ModelProto)>, ExportError> {
    match field {
        PlainField::Mlp { coarse, fine } => {
            if (scene.sampling.n_fine > 0) != fine.is_some() {
                return Err(ExportError::Network("sampling.n_fine and the networks disagree about a fine network".into()));
            }
            scene.position_encoding = Some(mlp::encoding_description(&coarse.spec.position_encoding));
            scene.direction_encoding = Some(mlp::encoding_description(&coarse.spec.direction_encoding));
            let mut graphs = vec![(Role::Coarse, mlp::compile(coarse, "coarse", opset, &scene_metadata(scene, Role::Coarse))?)];
            if let Some(fine) = fine {
                graphs.push((Role::Fine, mlp::compile(fine, "fine", opset, &scene_metadata(scene, Role::Fine))?));
            }
            Ok(graphs)
        }
        PlainField::Ngp(plain) => {
            scene.sampling.n_fine = 0;
            let ops = if opset >= HashOps::Bitwise.min_opset() { HashOps::Bitwise } else { HashOps::Arithmetic };
            Ok(vec![(Role::Field, ngp::compile_ngp(plain, "field", opset, ops, &scene_metadata(scene, Role::Field))?)])
        }
    }
}

