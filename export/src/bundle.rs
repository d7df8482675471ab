//! A trained field of any kind as a scene bundle: its graphs compiled by role, then written
//! with `scene.json` and the occupancy grid by [`nerf_bundle::write_bundle`] (whole or not at
//! all).

use crate::{CompileOptions, ExportError};
use crate::field::CompileField;
use nerf_bundle::scene::SceneDescription;
use nerf_bundle::WrittenFile;
use nerf_core::field::PlainField;
use nerf_core::sample::occupancy::OccupancyGrid;
use prost::Message;
use std::path::Path;

/// A trained field and its description (`F`: any kind the compiler can lower; the built-in
/// kinds as [`PlainField`]).
#[derive(Debug, Clone)]
pub struct Bundle<F = PlainField> {
    /// The field.
    pub field: F,
    /// `scene.json` (its graphs, occupancy and field kind are filled in when writing).
    pub scene: SceneDescription,
    /// The occupancy grid it is marched through, if any (required for bounded kinds).
    pub occupancy: Option<OccupancyGrid>,
}

/// Compile the field and write the bundle to `dir` (replacing an existing bundle only once the
/// new one is complete), compiled as `options` ask. A bounded field needs a grid.
pub fn write_bundle<F: CompileField>(dir: &Path, bundle: &Bundle<F>, options: &CompileOptions) -> Result<Vec<WrittenFile>, ExportError> {
    let field = &bundle.field;
    let mut scene = bundle.scene.clone();
    scene.field = field.kind().to_string();
    scene.bounded = field.bounded().is_some();
    if scene.bounded && bundle.occupancy.is_none() {
        return Err(ExportError::Network(format!("a {} field is defined inside its box only: the bundle needs its occupancy grid", scene.field)));
    }
    scene.set_contraction(field.contraction());
    if let Some(grid) = &bundle.occupancy
        && grid.contraction() != scene.contraction
    {
        let problem = format!("the field's contraction is {:?}, its occupancy grid's {:?}", scene.contraction, grid.contraction());
        return Err(ExportError::Network(problem));
    }
    let graphs = field.compile(&mut scene, options)?;
    let graphs = graphs.into_iter().map(|(role, model)| (role, model.encode_to_vec())).collect();
    Ok(nerf_bundle::write_bundle(dir, &scene, graphs, bundle.occupancy.as_ref())?)
}
