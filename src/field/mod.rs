//! Fields on burn, behind one seam ([`seam`]: [`TrainedField`], [`FieldTrainer`]). Each kind
//! lives in its own folder (burn modules, trainer, checkpoint parts, evaluator), named as in
//! [`nerf_core::field_kinds!`], which expands the one turn from a configuration's
//! [`FieldKind`] to its folder here.

pub mod seam;

pub use seam::{FieldTrainer, StepStats, StepTiming, TrainedField};

use crate::config::TrainConfig;
use crate::error::{Error, Result};
use crate::run_dir::{Checkpoint, CheckpointState, RunDir};
use burn::tensor::Device;
use nerf_core::dataset::SplitData;
use nerf_core::field::FieldKind;
use nerf_core::sample::occupancy::OccupancyGrid;
use crate::train::cameras::CameraCorrections;

macro_rules! kinds {
    ($($(#[$doc:meta])* $kind:ident { folder: $folder:ident, $($rest:tt)* },)*) => {
        $(pub mod $folder;)*

        /// A fresh trainer for `config.field` on `train` data.
        pub fn trainer(config: TrainConfig, train: SplitData) -> Result<Box<dyn FieldTrainer>> {
            match config.field {
                $(FieldKind::$kind => $folder::trainer(config, train),)*
            }
        }

        /// The field of `config.field`, weights from `checkpoint`, on `device`.
        fn load(config: &TrainConfig, checkpoint: &Checkpoint, device: &Device) -> Result<Box<dyn TrainedField>> {
            match config.field {
                $(FieldKind::$kind => $folder::load(config, checkpoint, device),)*
            }
        }
    };
}
nerf_core::field_kinds!(kinds);

/// The latest checkpoint of a run, loaded.
pub struct RunCheckpoint {
    /// The run's configuration.
    pub config: TrainConfig,
    /// Its field (no autodiff).
    pub model: Box<dyn TrainedField>,
    /// Step, RNG and elapsed time.
    pub state: CheckpointState,
    /// The occupancy grid, for runs that skip empty space.
    pub occupancy: Option<OccupancyGrid>,
    /// The training cameras' corrections, for runs that refine them.
    pub cameras: Option<CameraCorrections>,
}

/// The configuration and the latest checkpoint's field (and grid) of `run`, on `device`.
pub fn load_latest(run: &RunDir, device: &Device) -> Result<RunCheckpoint> {
    let config = run.read_config()?;
    let checkpoint = run.latest_checkpoint()?.ok_or_else(|| Error::invalid(&run.checkpoints_dir(), "the run has no checkpoint yet"))?;
    let state = checkpoint.state()?;
    let model = load(&config, &checkpoint, device)?;
    let occupancy = if config.skip_empty_space { checkpoint.load_occupancy()? } else { None };
    let cameras = if config.refine_cameras { Some(CameraCorrections::read(&checkpoint.dir)?) } else { None };
    Ok(RunCheckpoint { config, model, state, occupancy, cameras })
}
