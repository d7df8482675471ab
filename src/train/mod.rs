//! Training: configuration and presets, the learning-rate schedule, checkpoints, the loop.

mod checkpoint;
mod config;
mod schedule;
mod trainer;

pub use checkpoint::{Checkpoint, CheckpointState, latest_checkpoint, load_model};
pub use config::{Preset, TrainConfig};
pub use schedule::learning_rate;
pub use trainer::{StepStats, StepTiming, TrainOptions, TrainSummary, Trainer, render_options, train};
