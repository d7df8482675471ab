//! `nerf mesh --run`: a trained run's field meshed through the shared core
//! ([`nerf_core::mesh`]), the same extraction `nerf mesh --bundle` runs through onnxruntime;
//! carved by default with the run's training views, rendered as `nerf eval` renders.

use crate::error::{Error, Result};
use crate::evaluate::LoadedRun;
use nerf_core::field::{Field, FieldOutput, Stage};
use nerf_core::mesh::carve::{CarveViews, carving_views, dataset_views, render_depth_views};
use nerf_core::mesh::{MeshRequest, MeshSummary, extract_mesh, scene_transform};
use std::convert::Infallible;
use std::path::Path;

/// Mesh the latest checkpoint of `run` into the PLY file `out` (see [`nerf_core::mesh`]),
/// carving with the views `carve` names: [`CarveViews::Own`] is the train split of the dataset
/// the run recorded (`source.json`), when it is still there.
pub fn mesh_run(run: &Path, out: &Path, request: &MeshRequest, carve: &CarveViews, progress: bool) -> Result<MeshSummary> {
    let loaded = LoadedRun::open(run)?;
    let source = run.join("config.toml");
    let transform = scene_transform(loaded.placement(), loaded.config.sampling.ndc.is_some(), &source)?;
    let (options, bound_from) = request.options(Some(loaded.config.field), loaded.model.bounded(), loaded.occupancy.as_ref(), &source)?;
    // The placement maps the dataset's poses into the field, as it maps vertices back.
    let (frames, carving) = carving_views(carve, request.keep_cavities, transform, || match &loaded.source {
        Some(s) if s.data.is_dir() => dataset_views(&s.data, s.placement.as_ref().map(|p| p.format), transform),
        Some(s) => Ok((vec![], format!("not carved: the run's dataset {} is not here (give --data DIR to carve)", s.data.display()))),
        None => Ok((vec![], format!("not carved: {} records no dataset (give --data DIR to carve)", run.display()))),
    })?;
    let s = &loaded.config.sampling;
    let views = render_depth_views(&frames, (s.near, s.far), |k, pose| Ok::<_, Error>(loaded.render(k, pose, &mut |_, _| {})), progress)?;
    let mut field = Burn(loaded.model.evaluator(&crate::backend::cpu()));
    let report = extract_mesh::<_, Error>(&mut field, loaded.occupancy.as_ref(), &views, &options, &transform, out, progress)?;
    Ok(MeshSummary { report, options, bound_from, carving })
}

/// A burn evaluator (which cannot fail) as a field with the library's error.
struct Burn<'a>(Box<dyn Field<Error = Infallible> + 'a>);

impl Field for Burn<'_> {
    type Error = Error;
    fn evaluate(&mut self, stage: Stage, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> Result<FieldOutput> {
        let Ok(out) = self.0.evaluate(stage, points, viewdirs);
        Ok(out)
    }
}
