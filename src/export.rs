//! `nerf export`: a trained run → a scene bundle through the burn-free compiler
//! ([`nerf_export`]).

use crate::error::Result;
use crate::evaluate::LoadedRun;
use crate::field::{NerfModel, NgpField, TrainedField};
use crate::run_dir::RunDir;
use crate::train::TrainConfig;
use nerf_core::PinholeCamera;
use nerf_core::camera::Pose;
use nerf_core::dataset::ScenePlacement;
use nerf_core::dataset::{CaptureFormat, CaptureSplit};
use nerf_core::sample::occupancy::OccupancyGrid;
use nerf_export::bundle::{NamedPose, WrittenFile, pose_matrix};
use nerf_core::field::FieldKind;
use nerf_export::{Bundle, NgpBundle, SceneDescription, write_bundle, write_ngp_bundle};
use std::path::Path;

/// Frames of the orbit stored in `scene.json`.
pub const ORBIT_FRAMES: usize = 40;

/// The test poses of the run's dataset, in the field's frame, when it is recorded and still there.
fn test_poses(run: &RunDir, loaded: &LoadedRun) -> Result<Vec<NamedPose>> {
    let Some(source) = run.read_source()? else { return Ok(vec![]) };
    let format = source.placement.as_ref().map(|p| p.format);
    Ok(match loaded.load_split(&source.data, format, CaptureSplit::Test, source.downscale, false) {
        Ok(test) => test.views.iter().map(|v| NamedPose { name: v.name.clone(), transform_matrix: pose_matrix(&v.pose) }).collect(),
        Err(_) => vec![],
    })
}

/// What a bundle records of the run's placement: a capture's, not Blender's identity.
fn bundle_placement(loaded: &LoadedRun) -> Option<ScenePlacement> {
    loaded.placement.clone().filter(|p| p.format != CaptureFormat::Blender)
}

/// The bundle of `model` trained with `config` on images from `camera` (orbit poses included,
/// no test poses).
pub fn model_bundle(model: &NerfModel, config: &TrainConfig, camera: &PinholeCamera, occupancy: Option<OccupancyGrid>) -> Bundle {
    let coarse = model.coarse.to_plain();
    let fine = model.fine.as_ref().map(|f| f.to_plain());
    let mut scene = SceneDescription::new(camera, &config.sampling, config.white_background, &coarse, fine.is_some());
    scene.poses.orbit = Pose::orbit(ORBIT_FRAMES).iter().map(pose_matrix).collect();
    Bundle { coarse, fine, scene, occupancy }
}

/// The bundle of a hash-grid `field` trained with `config` (orbit poses included, no test
/// poses), marched through `occupancy`.
pub fn ngp_bundle(field: &NgpField, config: &TrainConfig, camera: &PinholeCamera, occupancy: OccupancyGrid) -> NgpBundle {
    let mut scene = SceneDescription::ngp(camera, &config.sampling, config.white_background, config.march_steps);
    scene.poses.orbit = Pose::orbit(ORBIT_FRAMES).iter().map(pose_matrix).collect();
    NgpBundle { field: field.to_plain(), scene, occupancy }
}

/// The opset `nerf export` uses when none is given: [`nerf_export::DEFAULT_OPSET`] for the
/// NeRF MLPs, 18 for the hash-grid field (its hash uses BitwiseXor; 17 lowers it without).
pub fn default_opset(kind: FieldKind) -> i64 {
    match kind {
        FieldKind::Mlp => nerf_export::DEFAULT_OPSET,
        FieldKind::Ngp => nerf_export::hash_grid::HashOps::Bitwise.min_opset(),
    }
}

/// Compile the latest checkpoint of `run` into a bundle at `out` (`opset`: see [`default_opset`]).
pub fn export_run(run: &Path, out: &Path, opset: Option<i64>) -> Result<Vec<WrittenFile>> {
    let loaded = LoadedRun::open(run)?;
    let test = test_poses(&RunDir::open(run)?, &loaded)?;
    let opset = opset.unwrap_or(default_opset(loaded.model.kind()));
    let orbit: Vec<_> = loaded.orbit(ORBIT_FRAMES).iter().map(pose_matrix).collect();
    match &loaded.model {
        TrainedField::Mlp(model) => {
            let mut bundle = model_bundle(model, &loaded.config, &loaded.camera, loaded.occupancy.clone());
            (bundle.scene.poses.test, bundle.scene.poses.orbit, bundle.scene.placement) = (test, orbit, bundle_placement(&loaded));
            Ok(write_bundle(out, &bundle, opset)?)
        }
        TrainedField::Ngp(field) => {
            let grid = loaded.occupancy.clone().unwrap_or_else(|| field.whole_box());
            let mut bundle = ngp_bundle(field, &loaded.config, &loaded.camera, grid);
            (bundle.scene.poses.test, bundle.scene.poses.orbit, bundle.scene.placement) = (test, orbit, bundle_placement(&loaded));
            Ok(write_ngp_bundle(out, &bundle, opset)?)
        }
    }
}
