//! The reference learning-rate schedule.

/// `lr · 0.1^(step / (decay_ksteps · 1000))`: exponential decay by 10× every `decay_ksteps`
/// thousand steps (nerf-pytorch's `lrate_decay`).
pub fn learning_rate(base_lr: f64, decay_ksteps: f64, step: usize) -> f64 {
    base_lr * 0.1f64.powf(step as f64 / (decay_ksteps * 1000.0))
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
}
