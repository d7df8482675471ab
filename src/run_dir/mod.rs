//! A training run's directory: the one place that knows its layout and reads or writes its
//! files (each written whole or not at all, [`nerf_core::io::atomic`]).
//!
//! | path | written | content |
//! |---|---|---|
//! | `config.toml` | at the start | the resolved [`TrainConfig`] (a resumed run keeps it) |
//! | `camera.json` | at the start | the training camera ([`PinholeCamera`]; older runs: `focal` only) |
//! | `source.json` | at the start | the dataset, downscale and the scene's placement in the field ([`RunSource`]) |
//! | `curve.csv` | while training | step, minutes, train PSNR, val PSNR ([`Curve`]) |
//! | `curve.png` | with each `curve.csv` row | the curve drawn ([`crate::plot::write_run_curve`]) |
//! | `checkpoints/step-NNNNNNN/` | every `checkpoint_every` steps | weights, optimizer, state, grid ([`Checkpoint`]) |
//! | `checkpoints/latest` | after each checkpoint | the name of the newest complete checkpoint |
//! | `progress.json` | every 2 s while training | step, time, remaining, recent loss and PSNR ([`crate::live::Progress`]) |
//! | `live/<step>/` | `nerf train --serve`, `nerf view` | the field's bundle at that step, the last one kept ([`crate::live`]) |

use crate::error::{Error, Result};
mod checkpoint;

pub use checkpoint::{Checkpoint, CheckpointState, read};

use crate::config::TrainConfig;
use nerf_core::io::atomic::{remove_stale_temporaries, write_atomic, write_dir_atomic};
use nerf_core::PinholeCamera;
use nerf_core::SceneTransform;
use nerf_core::dataset::ScenePlacement;
use nerf_core::io::limits;
use nerf_core::sample::occupancy::{self, OccupancyGrid};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

/// `source.json`: the dataset a run was trained on and where its scene sits in the field.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunSource {
    /// Scene directory (absolute when it could be made so).
    pub data: PathBuf,
    /// Downscale factor used.
    pub downscale: u32,
    /// The format, the transform from the data's world into the field (decided when the run
    /// started; every later `--data` goes through it), near/far and orbit of a capture.
    /// Absent in runs written before: the Blender format as it is.
    #[serde(default)]
    pub placement: Option<ScenePlacement>,
}

impl RunSource {
    /// The transform from the data's world into the field (identity for older runs).
    pub fn transform(&self) -> SceneTransform {
        self.placement.as_ref().map_or_else(SceneTransform::identity, |p| p.transform)
    }

    /// [`RunSource::transform`] of a run's source, identity for a run without one.
    pub fn transform_of(source: Option<&RunSource>) -> SceneTransform {
        source.map_or_else(SceneTransform::identity, RunSource::transform)
    }

    /// A run's orbit of `frames` poses: around a capture's cameras (its recorded placement),
    /// else the reference orbit.
    pub fn orbit_of(source: Option<&RunSource>, frames: usize) -> Vec<nerf_core::camera::Pose> {
        nerf_core::frames::views::orbit_poses(source.and_then(|s| s.placement.as_ref()).and_then(|p| p.orbit.as_ref()), frames)
    }
}

/// A run directory.
#[derive(Debug, Clone)]
pub struct RunDir {
    root: PathBuf,
}

impl RunDir {
    /// The run at `root`, creating the directory (for `nerf train`).
    pub fn create(root: &Path) -> Result<Self> {
        std::fs::create_dir_all(root).map_err(|e| Error::io(root, e))?;
        Ok(RunDir { root: root.to_path_buf() })
    }

    /// An existing run (for eval, render, export): `config.toml` must be there.
    pub fn open(root: &Path) -> Result<Self> {
        let run = RunDir { root: root.to_path_buf() };
        if !run.config_path().is_file() {
            let problem = format!("no such file: is {} a training run directory (written by `nerf train`)?", root.display());
            return Err(Error::invalid(&run.config_path(), problem));
        }
        Ok(run)
    }

    /// The directory.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// `config.toml`.
    pub fn config_path(&self) -> PathBuf {
        self.root.join("config.toml")
    }

    /// `camera.json`.
    pub fn camera_path(&self) -> PathBuf {
        self.root.join("camera.json")
    }

    /// `source.json`.
    pub fn source_path(&self) -> PathBuf {
        self.root.join("source.json")
    }

    /// `curve.csv`.
    pub fn curve_path(&self) -> PathBuf {
        self.root.join("curve.csv")
    }

    /// `curve.png`: the curve drawn.
    pub fn curve_plot_path(&self) -> PathBuf {
        self.root.join("curve.png")
    }

    /// `progress.json`: the trainer's progress, for a server in another process.
    pub fn progress_path(&self) -> PathBuf {
        self.root.join("progress.json")
    }

    /// `live/`: the field's latest snapshot, for the viewer.
    pub fn live_dir(&self) -> PathBuf {
        self.root.join("live")
    }

    /// `checkpoints/`.
    pub fn checkpoints_dir(&self) -> PathBuf {
        self.root.join("checkpoints")
    }

    /// `checkpoints/latest`.
    pub fn latest_path(&self) -> PathBuf {
        self.checkpoints_dir().join("latest")
    }

    /// The run's configuration.
    pub fn read_config(&self) -> Result<TrainConfig> {
        TrainConfig::from_run_toml(&self.config_path())
    }

    /// Record the configuration in force.
    pub fn write_config(&self, config: &TrainConfig) -> Result<()> {
        Ok(write_atomic(&self.config_path(), config.to_toml().as_bytes())?)
    }

    /// The training camera.
    pub fn read_camera(&self) -> Result<PinholeCamera> {
        let path = self.camera_path();
        let text = limits::read_json_text(&path)?;
        let camera = serde_json::from_str(&text).map_err(|e| nerf_core::Error::Json { path: path.clone(), source: e })?;
        limits::check_camera(&camera, limits::Origin::Field(&path, "camera"))?;
        Ok(camera)
    }

    /// Record the training camera (orbits render at its resolution).
    pub fn write_camera(&self, camera: &PinholeCamera) -> Result<()> {
        Ok(write_atomic(&self.camera_path(), serde_json::to_string_pretty(camera).expect("a camera serialises").as_bytes())?)
    }

    /// Where the run's data came from and how its scene is placed; `None` when the run has no
    /// `source.json`. A malformed file, or a transform that is not a finite similarity with a
    /// positive scale, is an error naming the file.
    pub fn read_source(&self) -> Result<Option<RunSource>> {
        let path = self.source_path();
        if !path.is_file() {
            return Ok(None);
        }
        let text = limits::read_json_text(&path)?;
        let source: RunSource = serde_json::from_str(&text).map_err(|e| nerf_core::Error::Json { path: path.clone(), source: e })?;
        let t = source.transform();
        let finite = t.rotation.iter().flatten().chain(&t.translation).all(|v| v.is_finite());
        if !(t.scale.is_finite() && t.scale > 0.0 && finite) {
            return Err(Error::invalid(&path, format!("placement.transform {t:?}: needs a positive finite scale and finite entries")));
        }
        Ok(Some(source))
    }

    /// The transform from the data's world into the run's field (identity for a run without
    /// a recorded placement).
    pub fn scene_transform(&self) -> Result<SceneTransform> {
        Ok(RunSource::transform_of(self.read_source()?.as_ref()))
    }

    /// Record where the data came from.
    pub fn write_source(&self, source: &RunSource) -> Result<()> {
        Ok(write_atomic(&self.source_path(), serde_json::to_string_pretty(source).expect("a source serialises").as_bytes())?)
    }

    /// Write `files` (name, content: `model.bpk`, `optim.bpk`, the field's extras) and the state
    /// for `state.step` (the directory whole or not at all), then point `latest` at it and
    /// remove all but the previous checkpoint.
    pub fn save_checkpoint(&self, files: &[(&str, Vec<u8>)], occupancy: Option<&OccupancyGrid>, state: &CheckpointState) -> Result<Checkpoint> {
        let name = format!("{}{:07}", checkpoint::PREFIX, state.step);
        let dir = self.checkpoints_dir().join(&name);
        write_dir_atomic(&dir, |tmp| {
            let write = |file: &str, bytes: &[u8]| {
                let p = tmp.join(file);
                std::fs::write(&p, bytes).map_err(|e| nerf_core::Error::io(&p, e))
            };
            for (file, bytes) in files {
                write(file, bytes)?;
            }
            if let Some(grid) = occupancy {
                write(occupancy::FILE_NAME, &grid.to_bytes())?;
            }
            write("state.json", serde_json::to_string_pretty(state).expect("state serialises").as_bytes())
        })?;
        write_atomic(&self.latest_path(), name.as_bytes())?;
        // Keep the newest two (the one just written and its predecessor), and remove what saves
        // that were killed left behind.
        remove_stale_temporaries(&self.checkpoints_dir());
        if let Ok(entries) = std::fs::read_dir(self.checkpoints_dir()) {
            let mut old: Vec<PathBuf> = entries
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.is_dir() && p.file_name().is_some_and(|n| Checkpoint::is_name(&n.to_string_lossy())))
                .collect();
            old.sort();
            old.retain(|p| p != &dir);
            for p in old.iter().rev().skip(1) {
                let _ = std::fs::remove_dir_all(p);
            }
        }
        Ok(Checkpoint { dir })
    }

    /// The checkpoint `latest` names, or `None` for a run that has none yet.
    pub fn latest_checkpoint(&self) -> Result<Option<Checkpoint>> {
        let latest = self.latest_path();
        match std::fs::read_to_string(&latest) {
            Ok(name) => {
                let name = name.trim();
                if !Checkpoint::is_name(name) {
                    return Err(Error::invalid(&latest, format!("names {name:?}, not a checkpoint (step-NNNNNNN)")));
                }
                let dir = self.checkpoints_dir().join(name);
                if !dir.is_dir() {
                    return Err(Error::invalid(&latest, format!("names {}, which does not exist", dir.display())));
                }
                Ok(Some(Checkpoint { dir }))
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(Error::io(&latest, e)),
        }
    }

    /// `curve.csv`, opened for appending (with its header if new).
    pub fn open_curve(&self) -> Result<Curve> {
        let path = self.curve_path();
        let mut file = std::fs::OpenOptions::new().create(true).append(true).open(&path).map_err(|e| Error::io(&path, e))?;
        if file.metadata().map(|m| m.len() == 0).unwrap_or(false) {
            writeln!(file, "step,minutes,train_psnr,val_psnr").map_err(|e| Error::io(&path, e))?;
        }
        Ok(Curve { file, path })
    }
}

/// The PSNR curve of a run (`curve.csv`), appended to as training goes.
pub struct Curve {
    file: std::fs::File,
    path: PathBuf,
}

impl Curve {
    /// Append a row: `step,minutes,train_psnr,val_psnr` (val empty when not measured).
    pub fn record(&mut self, step: usize, minutes: f64, train_psnr: f32, val_psnr: Option<f32>) -> Result<()> {
        let val = val_psnr.map(|p| format!("{p:.3}")).unwrap_or_default();
        writeln!(self.file, "{step},{minutes:.2},{train_psnr:.3},{val}").map_err(|e| Error::io(&self.path, e))
    }
}
