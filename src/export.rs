//! `nerf export`: a trained run → a scene bundle through the burn-free compiler
//! ([`nerf_export`]).

use crate::error::{Error, Result};
use crate::evaluate::LoadedRun;
use crate::field::TrainedField;
use crate::config::TrainConfig;
use nerf_bundle::scene::{FixedAppearance, NamedPose, SceneDescription};
use nerf_bundle::{WrittenFile, pose_matrix};
use nerf_core::PinholeCamera;
use nerf_core::camera::{ORBIT_FRAMES, Pose};
use crate::run_dir::RunSource;
use nerf_core::dataset::{Background, CaptureFormat, CaptureSplit, ScenePlacement};
use nerf_core::frames::views::{Images, SplitChoice, split_views};
use nerf_core::sample::occupancy::OccupancyGrid;
use nerf_export::{Bundle, CompileField, CompileOptions, TablePrecision, write_bundle};
use std::path::Path;

/// What a run's bundle records beside its field: the test poses of its dataset (when recorded
/// and still there), its orbit and a capture's placement. Read once per run: live snapshots
/// reuse it.
#[derive(Debug, Clone, Default)]
pub struct RunScene {
    test: Vec<NamedPose>,
    orbit: Vec<[[f32; 4]; 4]>,
    placement: Option<ScenePlacement>,
}

impl RunScene {
    /// Read from the run's recorded source (`None`: an older run, Blender as it is).
    pub fn read(source: Option<&RunSource>) -> Self {
        let placement = source.and_then(|s| s.placement.as_ref());
        let test = match source {
            Some(source) => {
                let choice = SplitChoice { dir: source.data.clone(), format: placement.map(|p| p.format), split: CaptureSplit::Test, downscale: source.downscale };
                // The background does not matter: no images are read.
                match split_views(&choice, RunSource::transform_of(Some(source)), Background::from_white(true), Images::Skip) {
                    Ok(test) => test.iter().map(|v| NamedPose { name: v.name.clone(), transform_matrix: pose_matrix(&v.pose) }).collect(),
                    Err(_) => vec![],
                }
            }
            None => vec![],
        };
        let orbit = RunSource::orbit_of(source, ORBIT_FRAMES).iter().map(pose_matrix).collect();
        // A capture's placement; Blender scenes are used as they are.
        RunScene { test, orbit, placement: placement.filter(|p| p.format != CaptureFormat::Blender).cloned() }
    }

    /// Record it in `scene`.
    pub fn apply(&self, scene: &mut SceneDescription) {
        scene.poses.test = self.test.clone();
        scene.poses.orbit = self.orbit.clone();
        scene.placement = self.placement.clone();
    }
}

/// The bundle of `field` trained with `config` on images from `camera` (the reference orbit,
/// no test poses), marched through `occupancy` (a bounded field without one: its whole box).
pub fn field_bundle<'a>(field: &'a dyn TrainedField, config: &TrainConfig, camera: &PinholeCamera, occupancy: Option<OccupancyGrid>) -> Bundle<Box<dyn CompileField + 'a>> {
    let mut scene = SceneDescription::new(camera, &config.sampling, config.white_background, config.render_steps());
    scene.appearance = field.appearance().cloned();
    scene.poses.orbit = Pose::orbit(ORBIT_FRAMES).iter().map(pose_matrix).collect();
    Bundle { field: field.lowering(), scene, occupancy: field.marching_grid(occupancy) }
}

/// Compile the latest checkpoint of `run` into a bundle at `out` as `options` ask, rendering
/// with the `appearance` code (default: the mean) when the field has per-image codes.
pub fn export_run(run: &Path, out: &Path, options: &CompileOptions, appearance: Option<&FixedAppearance>) -> Result<Vec<WrittenFile>> {
    let mut loaded = LoadedRun::open(run)?;
    if let Some(fixed) = appearance {
        let path = run.join("config.toml");
        loaded.model.fix_appearance(fixed).map_err(|problem| Error::Invalid { path, problem: format!("--appearance: {problem}") })?;
    }
    let mut bundle = field_bundle(loaded.model.as_ref(), &loaded.config, &loaded.camera, loaded.occupancy.clone());
    RunScene::read(loaded.source.as_ref()).apply(&mut bundle.scene);
    Ok(write_bundle(out, &bundle, options)?)
}

/// The hash-grid field of the bundle at `dir` read back (its table and MLPs from `field.onnx`,
/// its scene and grid as they are), with its table's precision, to compile again with other
/// options: another lowering or table precision of the same field, the same pixels.
pub fn ngp_bundle(dir: &Path) -> Result<(Bundle<nerf_core::field::ngp::PlainNgp>, TablePrecision)> {
    let scene = nerf_bundle::read_scene(dir)?;
    if scene.field != nerf_core::field::FieldKind::Ngp.name() {
        let problem = format!("field {:?}: only hash-grid bundles (field \"ngp\") compile again from their graph; export the run instead (nerf export --run)", scene.field);
        return Err(Error::Invalid { path: dir.join(nerf_bundle::SCENE_FILE), problem });
    }
    let graph = nerf_bundle::bundle_file(dir, scene.graph_files()[0].file, "graphs")?;
    let model = nerf_bundle::read_model(&graph)?;
    let invalid = |problem| Error::Invalid { path: graph.clone(), problem };
    let plain = nerf_export::field::ngp::read_ngp(&model).map_err(invalid)?;
    let precision = nerf_bundle::ngp::table_precision(&model).map_err(invalid)?;
    let occupancy = nerf_bundle::read_occupancy(dir, &scene)?;
    Ok((Bundle { field: plain, scene, occupancy }, precision))
}

/// Compile the hash-grid bundle at `bundle` again into `out` ([`ngp_bundle`]) as `options`
/// ask, its table kept in its precision unless `tables` says otherwise.
pub fn export_bundle(bundle: &Path, out: &Path, options: &CompileOptions, tables: Option<TablePrecision>) -> Result<Vec<WrittenFile>> {
    let (read, precision) = ngp_bundle(bundle)?;
    Ok(write_bundle(out, &read, &CompileOptions { tables: tables.unwrap_or(precision), ..options.clone() })?)
}
