//! A bundle's field meshed through onnxruntime by the shared core ([`nerf_core::mesh`]): the
//! same extraction as a burn run's, so imported nerf-pytorch bundles mesh too.

use crate::error::{Result, RuntimeError};
use crate::scene::{OpenOptions, OrtScene};
use nerf_bundle::SCENE_FILE;
use nerf_core::mesh::{BoundSource, MeshOptions, MeshReport, MeshRequest, extract_mesh, kind_named, scene_transform};
use std::path::Path;

/// Mesh the bundle in `dir` into the PLY file `out` (`threads`: onnxruntime sessions side by
/// side, `None`: one per core): the report, the options used and where the cube came from.
pub fn mesh_bundle(dir: &Path, out: &Path, request: &MeshRequest, threads: Option<usize>, progress: bool) -> Result<(MeshReport, MeshOptions, BoundSource)> {
    let mut scene = OrtScene::open(dir, &OpenOptions { threads, ..OpenOptions::default() })?;
    let source = dir.join(SCENE_FILE);
    let d = &scene.description;
    let transform = scene_transform(d.placement.as_ref(), d.sampling.ndc.is_some(), &source)?;
    // A bounded field's box is its grid's cube (`scene.json` checks it has one).
    let field_box = if d.is_bounded() { d.occupancy.as_ref().map(|o| o.bound) } else { None };
    let (options, from) = request.options(kind_named(&d.field), field_box, scene.occupancy.as_ref(), &source)?;
    let report = extract_mesh::<_, RuntimeError>(&mut scene.field, scene.occupancy.as_ref(), &options, &transform, out, progress)?;
    Ok((report, options, from))
}
