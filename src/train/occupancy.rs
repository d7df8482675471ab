//! The occupancy grid's updates while training, the same for every field kind: after the
//! warm-up, every `update_every` steps, re-measure σ at one random point per cell, decay the
//! old values and, with `threshold_at_most_mean`, lower the threshold to the mean density.

use nerf_core::Rng;
use nerf_core::sample::occupancy::{OccupancyConfig, OccupancyGrid};

/// Points per density call.
const CHUNK: usize = 1 << 16;

/// Whether the grid is due an update before step `step`.
pub fn due(config: &OccupancyConfig, step: usize) -> bool {
    step >= config.warmup_steps && (step - config.warmup_steps) % config.update_every == 0
}

/// Update `grid` with `density` (σ at world points) measured at one random point per cell.
pub fn update(grid: &mut OccupancyGrid, config: &OccupancyConfig, rng: &mut Rng, mut density: impl FnMut(&[[f32; 3]]) -> Vec<f32>) {
    let points = grid.random_cell_points(rng);
    let mut sigma = Vec::with_capacity(points.len());
    for chunk in points.chunks(CHUNK) {
        sigma.extend(density(chunk));
    }
    grid.update(&sigma, config.decay);
    if config.threshold_at_most_mean {
        let threshold = config.threshold.min(grid.mean_density());
        grid.set_threshold(threshold);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn updates_follow_the_schedule_and_the_threshold_follows_the_mean() {
        let config = OccupancyConfig { resolution: 4, bound: 1.0, threshold: 10.0, decay: 0.5, update_every: 16, warmup_steps: 64, threshold_at_most_mean: true, contraction: None, min_views: 0 };
        assert!(!due(&config, 63) && due(&config, 64) && !due(&config, 65) && due(&config, 80));
        let mut grid = OccupancyGrid::from_config(&config);
        // σ = 4 inside x < 0, 0 elsewhere: half the cells occupied, mean density 2 after one
        // update from zero (decay keeps the max of the decayed old value and the new one).
        update(&mut grid, &config, &mut Rng::new(1), |p| p.iter().map(|q| if q[0] < 0.0 { 4.0 } else { 0.0 }).collect());
        assert!((grid.mean_density() - 2.0).abs() < 1e-6, "mean {}", grid.mean_density());
        assert!((grid.occupied_fraction() - 0.5).abs() < 1e-6, "threshold lowered to the mean: {}", grid.occupied_fraction());
    }
}
