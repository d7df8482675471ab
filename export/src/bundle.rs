//! A trained field of any kind as a scene bundle: its graphs compiled by role, then written
//! with `scene.json` and the occupancy grid by [`nerf_bundle::write_bundle`] (whole or not at
//! all).

use crate::ExportError;
use crate::graph::{compile, read_network};
use crate::hash_grid::HashOps;
use crate::ngp::compile_ngp;
use nerf_bundle::scene::{CAMERA_CONVENTION, SceneDescription};
use nerf_bundle::{WrittenFile, bundle_file, read_model};
use nerf_core::field::mlp::PlainNetwork;
use nerf_core::field::{FieldKind, PlainField, Role};
use nerf_core::sample::occupancy::OccupancyGrid;
use prost::Message;
use std::path::Path;

/// A trained field and its description.
#[derive(Debug, Clone)]
pub struct Bundle {
    /// The field.
    pub field: PlainField,
    /// `scene.json` (its graphs, occupancy and field kind are filled in when writing).
    pub scene: SceneDescription,
    /// The occupancy grid it is marched through, if any (required for bounded kinds).
    pub occupancy: Option<OccupancyGrid>,
}

/// The opset used when none is asked for: [`crate::DEFAULT_OPSET`], or for the hash-grid field
/// the lowest with BitwiseXor (18; 17 lowers the hash without bitwise operators).
pub fn default_opset(kind: FieldKind) -> i64 {
    match kind {
        FieldKind::Mlp => crate::DEFAULT_OPSET,
        FieldKind::Ngp => HashOps::Bitwise.min_opset(),
    }
}

/// Compile the field and write the bundle to `dir` (replacing an existing bundle only once the
/// new one is complete); `opset` `None`: [`default_opset`].
pub fn write_bundle(dir: &Path, bundle: &Bundle, opset: Option<i64>) -> Result<Vec<WrittenFile>, ExportError> {
    let mut scene = bundle.scene.clone();
    scene.field = bundle.field.kind();
    let opset = opset.unwrap_or(default_opset(scene.field));
    let graphs = compile_field(&bundle.field, &mut scene, opset)?;
    if scene.field.bounded() && bundle.occupancy.is_none() {
        return Err(ExportError::Network(format!("a {} field is marched through its occupancy grid: the bundle needs one", scene.field.name())));
    }
    let graphs = graphs.into_iter().map(|(role, model)| (role, model.encode_to_vec())).collect();
    Ok(nerf_bundle::write_bundle(dir, &scene, graphs, bundle.occupancy.as_ref())?)
}

/// Each graph of `field` by role, its metadata from `scene` (which learns what only the field
/// knows: the encodings of the MLPs, no fine stage for the hash grid).
fn compile_field(field: &PlainField, scene: &mut SceneDescription, opset: i64) -> Result<Vec<(Role, crate::proto::ModelProto)>, ExportError> {
    match field {
        PlainField::Mlp { coarse, fine } => {
            if (scene.sampling.n_fine > 0) != fine.is_some() {
                return Err(ExportError::Network("sampling.n_fine and the networks disagree about a fine network".into()));
            }
            scene.position_encoding = Some((&coarse.spec.position_encoding).into());
            scene.direction_encoding = Some((&coarse.spec.direction_encoding).into());
            let mut graphs = vec![(Role::Coarse, compile(coarse, "coarse", opset, &scene_metadata(scene, Role::Coarse))?)];
            if let Some(fine) = fine {
                graphs.push((Role::Fine, compile(fine, "fine", opset, &scene_metadata(scene, Role::Fine))?));
            }
            Ok(graphs)
        }
        PlainField::Ngp(plain) => {
            scene.sampling.n_fine = 0;
            let ops = if opset >= HashOps::Bitwise.min_opset() { HashOps::Bitwise } else { HashOps::Arithmetic };
            Ok(vec![(Role::Field, compile_ngp(plain, "field", opset, ops, &scene_metadata(scene, Role::Field))?)])
        }
    }
}

/// The contract metadata every graph of a scene carries.
fn scene_metadata(scene: &SceneDescription, role: Role) -> Vec<(String, String)> {
    let s = &scene.sampling;
    let mut metadata = vec![
        ("nerf.stage".into(), role.name().into()),
        ("nerf.near".into(), s.near.to_string()),
        ("nerf.far".into(), s.far.to_string()),
        ("nerf.n_coarse".into(), s.n_coarse.to_string()),
        ("nerf.n_fine".into(), s.n_fine.to_string()),
        ("nerf.lindisp".into(), s.lindisp.to_string()),
        ("nerf.white_background".into(), scene.white_background.to_string()),
        ("nerf.camera".into(), CAMERA_CONVENTION.into()),
    ];
    if let Some(n) = &s.ndc {
        let ndc = format!("width {} height {} fx {} fy {} near {}", n.width, n.height, n.fx, n.fy, n.near);
        metadata.push(("nerf.ndc".into(), ndc));
    }
    metadata
}

/// The plain network stored in a bundle's MLP graph file `file` (`coarse.onnx`, `fine.onnx`).
pub fn read_bundle_network(dir: &Path, file: &str) -> nerf_core::Result<PlainNetwork> {
    let path = bundle_file(dir, file, "graphs")?;
    read_network(&read_model(&path)?).map_err(|e| nerf_core::Error::invalid(&path, e))
}
