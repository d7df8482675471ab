//! Learning-rate schedules: the reference exponential decay by step count (with an optional
//! final anneal over the run's last fraction), and a schedule planned over the run's length
//! (its steps, or its time budget when it has one).

use serde::{Deserialize, Serialize};

/// How the learning rate moves over a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LrSchedule {
    /// `lr · 0.1^(step / (lr_decay_ksteps · 1000))`, whatever the run's length
    /// (nerf-pytorch's `lrate_decay`).
    #[default]
    Exponential,
    /// Planned over the run, as nerfacc trains its hash grids: a linear warm-up from lr/100
    /// over [`WARMUP_STEPS`], then lr, × [`PLANNED_GAMMA`] at each of [`PLANNED_MILESTONES`]
    /// of the run. The run's length is its time budget when it has one (so a slow machine
    /// still ends at a small learning rate), else its `iters`.
    Planned,
}

/// Steps of [`LrSchedule::Planned`]'s linear warm-up.
pub const WARMUP_STEPS: usize = 100;
/// The fractions of a run where [`LrSchedule::Planned`] lowers the learning rate.
pub const PLANNED_MILESTONES: [f64; 3] = [0.5, 0.75, 0.9];
/// What [`LrSchedule::Planned`] multiplies the learning rate by at each milestone.
pub const PLANNED_GAMMA: f64 = 0.33;

/// `lr · 0.1^(step / (decay_ksteps · 1000))`: exponential decay by 10× every `decay_ksteps`
/// thousand steps (nerf-pytorch's `lrate_decay`).
pub fn learning_rate(base_lr: f64, decay_ksteps: f64, step: usize) -> f64 {
    base_lr * 0.1f64.powf(step as f64 / (decay_ksteps * 1000.0))
}

/// The factor of a final anneal over the last `fraction` of a run, `done` (in [0, 1]) of the
/// way through it: 1 before, then 0.1^((done − (1 − fraction)) / fraction), 0.1 at the end.
pub fn final_anneal(fraction: f64, done: f64) -> f64 {
    if fraction <= 0.0 {
        return 1.0;
    }
    let into = ((done - (1.0 - fraction)) / fraction).clamp(0.0, 1.0);
    0.1f64.powf(into)
}

/// [`LrSchedule::Planned`]'s rate at `step`, `done` (in [0, 1]) of the way through the run.
///
/// Example: lr 1e-2 → 1e-4 at step 0, 5.05e-3 at step 50, 1e-2 from step 100 until half-way,
/// 3.3e-3 to three quarters, 1.089e-3 to 90%, 3.594e-4 after.
pub fn planned_learning_rate(base_lr: f64, step: usize, done: f64) -> f64 {
    let warm = (0.01 + 0.99 * step as f64 / WARMUP_STEPS as f64).min(1.0);
    let passed = PLANNED_MILESTONES.iter().filter(|&&m| done >= m).count();
    base_lr * warm * PLANNED_GAMMA.powi(passed as i32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decays_tenfold_every_decay_period() {
        assert_eq!(learning_rate(5e-4, 500.0, 0), 5e-4);
        assert!((learning_rate(5e-4, 500.0, 500_000) - 5e-5).abs() < 1e-12);
        assert!((learning_rate(5e-4, 500.0, 250_000) - 5e-4 / 10f64.sqrt()).abs() < 1e-12);
        assert!((learning_rate(1e-3, 2.0, 4_000) - 1e-5).abs() < 1e-12);
    }

    #[test]
    fn the_final_anneal_falls_tenfold_over_the_last_fraction() {
        assert_eq!(final_anneal(0.0, 1.0), 1.0);
        assert_eq!(final_anneal(0.1, 0.5), 1.0);
        assert!((final_anneal(0.1, 0.9) - 1.0).abs() < 1e-12);
        assert!((final_anneal(0.1, 0.95) - 0.1f64.sqrt()).abs() < 1e-12);
        assert!((final_anneal(0.2, 0.9) - 0.1f64.sqrt()).abs() < 1e-12);
        assert!((final_anneal(0.1, 1.0) - 0.1).abs() < 1e-12);
        // A run past its end (the last step of a budget) stays at the end's factor.
        assert!((final_anneal(0.1, 1.2) - 0.1).abs() < 1e-12);
    }

    #[test]
    fn planned_warms_up_then_steps_down_at_the_milestones() {
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12 * b.max(1e-300);
        assert!(close(planned_learning_rate(1e-2, 0, 0.0), 1e-4));
        assert!(close(planned_learning_rate(1e-2, 50, 0.0), 5.05e-3));
        for done in [0.0, 0.3, 0.4999] {
            assert!(close(planned_learning_rate(1e-2, 100, done), 1e-2), "{done}");
        }
        assert!(close(planned_learning_rate(1e-2, 5000, 0.5), 3.3e-3));
        assert!(close(planned_learning_rate(1e-2, 5000, 0.8), 1.089e-3));
        assert!(close(planned_learning_rate(1e-2, 5000, 0.95), 3.5937e-4));
        assert!(close(planned_learning_rate(1e-2, 5000, 1.0), 3.5937e-4));
        // The warm-up counts steps, wherever the run is (a resumed run is past it).
        assert!(close(planned_learning_rate(1e-2, 10, 0.9), 1e-2 * 0.109 * 0.33f64.powi(3)));
    }
}
