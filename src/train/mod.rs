//! Training: the run loop ([`train`]) that drives any field's trainer through the seam
//! ([`crate::field::FieldTrainer`]), and what the kinds' trainers share: the learning-rate
//! schedule, the occupancy grid's updates, the compositing gradient of packed samples and the
//! training cameras' corrections.

pub mod adam;
pub mod cameras;
pub mod distortion;
pub mod occupancy;
pub mod packed;
mod run;
mod schedule;

pub use run::{NDC_MARCH_STEPS, TrainOptions, TrainSummary, train, train_live};
pub use schedule::{LrSchedule, final_anneal, learning_rate, planned_learning_rate};
