//! A trained field of any kind as a scene bundle: its graphs compiled by role, then written
//! with `scene.json` and the occupancy grid by [`nerf_bundle::write_bundle`] (whole or not at
//! all).

use crate::ExportError;
use crate::field::{compile_field, default_opset};
use nerf_bundle::scene::SceneDescription;
use nerf_bundle::WrittenFile;
use nerf_core::field::PlainField;
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

/// Compile the field and write the bundle to `dir` (replacing an existing bundle only once the
/// new one is complete); `opset` `None`: [`crate::default_opset`].
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
