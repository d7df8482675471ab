//! A bundle's field meshed through onnxruntime by the shared core ([`nerf_core::mesh`]): the
//! same extraction as a burn run's, so imported nerf-pytorch bundles mesh too. A bundle holds no
//! training views, so it carves only with `--data` (a dataset's train views, rendered here
//! through onnxruntime).

use crate::error::{Result, RuntimeError};
use crate::scene::{OpenOptions, OrtScene};
use nerf_bundle::SCENE_FILE;
use nerf_core::mesh::carve::{CarveViews, carving_views, render_depth_views};
use nerf_core::mesh::{MeshRequest, MeshSummary, extract_mesh, kind_named, scene_transform};
use std::path::Path;

/// Mesh the bundle in `dir` into the PLY file `out` (`threads`: onnxruntime sessions side by
/// side, `None`: one per core), carving with the views `carve` names ([`CarveViews::Own`]: none,
/// see the module docs).
pub fn mesh_bundle(dir: &Path, out: &Path, request: &MeshRequest, carve: &CarveViews, threads: Option<usize>, progress: bool) -> Result<MeshSummary> {
    let mut scene = OrtScene::open(dir, &OpenOptions { threads, ..OpenOptions::default() })?;
    let source = dir.join(SCENE_FILE);
    let d = &scene.description;
    let transform = scene_transform(d.placement.as_ref(), d.sampling.ndc.is_some(), &source)?;
    // A bounded field's box is its grid's cube (`scene.json` checks it has one).
    let field_box = if d.is_bounded() { d.occupancy.as_ref().map(|o| o.bound) } else { None };
    let (options, bound_from) = request.options(kind_named(&d.field), field_box, scene.occupancy.as_ref(), &source)?;
    // The placement maps the dataset's poses into the field, as it maps vertices back.
    let (frames, carving) = carving_views(carve, request.keep_cavities, transform, || {
        Ok((vec![], "not carved: a bundle holds no training views (give --data DIR to carve with a dataset's)".into()))
    })?;
    let near_far = (d.sampling.near, d.sampling.far);
    let views = render_depth_views(&frames, near_far, |k, pose| scene.render(k, pose, &mut |_, _| {}), progress)?;
    let report = extract_mesh::<_, RuntimeError>(&mut scene.field, scene.occupancy.as_ref(), &views, &options, &transform, out, progress)?;
    Ok(MeshSummary { report, options, bound_from, carving })
}
