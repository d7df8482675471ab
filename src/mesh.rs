//! `nerf mesh --run`: a trained run's field meshed through the shared core
//! ([`nerf_core::mesh`]), the same extraction `nerf mesh --bundle` runs through onnxruntime.

use crate::error::{Error, Result};
use crate::evaluate::LoadedRun;
use nerf_core::field::{Field, FieldOutput, Stage};
use nerf_core::mesh::{BoundSource, MeshOptions, MeshReport, MeshRequest, extract_mesh, scene_transform};
use std::convert::Infallible;
use std::path::Path;

/// What was meshed and how.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshSummary {
    /// Counts and the largest density seen.
    pub report: MeshReport,
    /// Resolution, threshold and cube used.
    pub options: MeshOptions,
    /// Where the cube came from.
    pub bound_from: BoundSource,
}

/// Mesh the latest checkpoint of `run` into the PLY file `out` (see [`nerf_core::mesh`]).
pub fn mesh_run(run: &Path, out: &Path, request: &MeshRequest, progress: bool) -> Result<MeshSummary> {
    let loaded = LoadedRun::open(run)?;
    let source = run.join("config.toml");
    let transform = scene_transform(loaded.placement(), loaded.config.sampling.ndc.is_some(), &source)?;
    let (options, bound_from) = request.options(Some(loaded.config.field), loaded.model.bounded(), loaded.occupancy.as_ref(), &source)?;
    let mut field = Burn(loaded.model.evaluator(&crate::backend::cpu()));
    let report = extract_mesh::<_, Error>(&mut field, loaded.occupancy.as_ref(), &options, &transform, out, progress)?;
    Ok(MeshSummary { report, options, bound_from })
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
