//! Training: configuration and presets, the learning-rate schedule, checkpoints, one step
//! ([`Trainer`]) and the run loop ([`train`]).

mod checkpoint;
mod config;
mod run;
mod schedule;
mod step;

pub use checkpoint::{Checkpoint, CheckpointState};
pub use config::{Preset, TrainConfig};
pub use run::{TrainOptions, TrainSummary, train};
pub use schedule::learning_rate;
pub use step::{StepStats, StepTiming, Trainer};
