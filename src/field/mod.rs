//! Fields on burn, behind one seam ([`seam`]: [`TrainedField`], [`FieldTrainer`]). Each kind
//! lives in its own folder (burn modules, trainer, checkpoint parts, evaluator); this file is
//! the one place that turns a configuration's [`FieldKind`] into a kind.
//!
//! - [`mlp`]: the NeRF MLPs with positional encoding (coarse and fine).
//! - [`ngp`]: the hash-grid field with tiny MLPs.

pub mod mlp;
pub mod ngp;
pub mod seam;

pub use seam::{FieldTrainer, StepStats, StepTiming, TrainedField};

use crate::config::TrainConfig;
use crate::error::{Error, Result};
use crate::run_dir::{CheckpointState, RunDir};
use burn::tensor::Device;
use nerf_core::dataset::SplitData;
use nerf_core::field::FieldKind;
use nerf_core::sample::occupancy::OccupancyGrid;

/// A fresh trainer for `config.field` on `train` data.
pub fn trainer(config: TrainConfig, train: SplitData) -> Result<Box<dyn FieldTrainer>> {
    match config.field {
        FieldKind::Mlp => mlp::trainer(config, train),
        FieldKind::Ngp => ngp::trainer(config, train),
    }
}

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
}

/// The configuration and the latest checkpoint's field (and grid) of `run`, on `device`.
pub fn load_latest(run: &RunDir, device: &Device) -> Result<RunCheckpoint> {
    let config = run.read_config()?;
    let checkpoint = run.latest_checkpoint()?.ok_or_else(|| Error::invalid(&run.checkpoints_dir(), "the run has no checkpoint yet"))?;
    let state = checkpoint.state()?;
    let model = match config.field {
        FieldKind::Mlp => mlp::load(&config, &checkpoint, device)?,
        FieldKind::Ngp => ngp::load(&config, &checkpoint, device)?,
    };
    let occupancy = if config.skip_empty_space { checkpoint.load_occupancy()? } else { None };
    Ok(RunCheckpoint { config, model, state, occupancy })
}
