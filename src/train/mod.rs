//! Training: configuration and presets, the learning-rate schedule, checkpoints, one step of
//! either field ([`Trainer`] for the NeRF MLPs, [`NgpTrainer`] for the hash-grid field) and the
//! run loop ([`train`]), which drives them through [`FieldTrainer`].

mod packed;
mod ngp;
mod run;
mod schedule;
mod step;

pub use crate::config::{DEFAULT_TARGET_SAMPLES, Preset, TrainConfig};
pub use crate::run_dir::{Checkpoint, CheckpointState, GRID_FILE};
pub use ngp::NgpTrainer;
pub use run::{NDC_MARCH_STEPS, TrainOptions, TrainSummary, train};
pub use schedule::learning_rate;
pub use step::{StepStats, StepTiming, Trainer};

use crate::error::Result;
use crate::run_dir::RunDir;
use nerf_core::dataset::SplitData;
use nerf_core::sample::occupancy::OccupancyGrid;

/// What the run loop needs of a field's trainer.
pub trait FieldTrainer {
    /// The configuration in force.
    fn config(&self) -> &TrainConfig;
    /// Steps completed.
    fn steps_done(&self) -> usize;
    /// One optimisation step on a fresh random batch.
    fn step(&mut self) -> StepStats;
    /// Save a checkpoint of the current state into `run`.
    fn save(&self, run: &RunDir, elapsed_s: f64) -> Result<Checkpoint>;
    /// Restore weights, optimizer, step and RNG from a checkpoint; returns the seconds trained.
    fn resume(&mut self, checkpoint: &Checkpoint) -> Result<f64>;
    /// PSNR of the current field on one view, rendered deterministically.
    fn view_psnr(&self, data: &SplitData, index: usize) -> f32;
    /// The occupancy grid, when there is one.
    fn occupancy(&self) -> Option<&OccupancyGrid>;
}

/// A trainer for `config.field` on `train` data.
pub fn field_trainer(config: TrainConfig, train: SplitData) -> Result<Box<dyn FieldTrainer>> {
    Ok(match config.field {
        nerf_core::field::FieldKind::Mlp => Box::new(Trainer::new(config, train, crate::backend::cpu_autodiff())?),
        nerf_core::field::FieldKind::Ngp => Box::new(NgpTrainer::new(config, train, burn::tensor::Device::flex().autodiff())?),
    })
}
