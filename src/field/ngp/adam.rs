//! tiny-cuda-nn's Adam for the hash table, applied sparsely.
//!
//! For every parameter with a non-zero gradient this step (untouched entries, and touched
//! features whose gradient is exactly 0, are skipped, as tiny-cuda-nn skips non-matrix
//! parameters with `gradient == 0`):
//!
//! ```text
//! m ← β₁m + (1 − β₁)g        v ← β₂v + (1 − β₂)g²        t ← t + 1   (this parameter's own count)
//! θ ← θ − lr · √(1 − β₂ᵗ)/(1 − β₁ᵗ) / (√v + ε) · m
//! ```
//!
//! Bias correction uses each parameter's own step count `t` (tiny-cuda-nn's `param_steps`): an
//! entry first touched at step 1000 gets the full first-step correction, and its moments have
//! not decayed in the steps it was absent (they are not updated at all then). ε is added to
//! √v before the correction, as there (ε = 1e-15 makes that moot).

use nerf_core::field::ngp::hash_grid::{HashGrid, HashGridGradient};
use nerf_core::error::{Error, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Adam's hyper-parameters for the table (instant-ngp's: lr 1e-2, β 0.9/0.99, ε 1e-15).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SparseAdamConfig {
    /// Learning rate.
    #[serde(default = "default_lr")]
    pub learning_rate: f32,
    /// First-moment decay β₁.
    #[serde(default = "default_beta1")]
    pub beta1: f32,
    /// Second-moment decay β₂.
    #[serde(default = "default_beta2")]
    pub beta2: f32,
    /// ε added to √v.
    #[serde(default = "default_epsilon")]
    pub epsilon: f32,
}

fn default_lr() -> f32 {
    1e-2
}
fn default_beta1() -> f32 {
    0.9
}
fn default_beta2() -> f32 {
    0.99
}
fn default_epsilon() -> f32 {
    1e-15
}

impl Default for SparseAdamConfig {
    fn default() -> Self {
        SparseAdamConfig { learning_rate: default_lr(), beta1: default_beta1(), beta2: default_beta2(), epsilon: default_epsilon() }
    }
}

/// Adam state for one [`HashGrid`]: first and second moments and a step count per parameter.
#[derive(Debug, Clone, PartialEq)]
pub struct SparseAdam {
    /// Hyper-parameters (the learning rate may be changed between steps).
    pub config: SparseAdamConfig,
    first: Vec<f32>,
    second: Vec<f32>,
    steps: Vec<u32>,
    /// `√(1 − β₂ᵗ)/(1 − β₁ᵗ)` for t = 0 (unused), 1, …, `horizon`.
    corrections: Vec<f32>,
    /// No parameter's step count exceeds this.
    horizon: u32,
}

impl SparseAdam {
    /// Zero moments and step counts for `grid`'s parameters.
    pub fn new(config: SparseAdamConfig, grid: &HashGrid) -> Self {
        let n = grid.params().len();
        SparseAdam { config, first: vec![0.0; n], second: vec![0.0; n], steps: vec![0; n], corrections: vec![f32::NAN], horizon: 0 }
    }

    /// Restore saved state (`first`, `second`, `steps` as [`state`](Self::state) gave them).
    pub fn from_state(config: SparseAdamConfig, grid: &HashGrid, first: Vec<f32>, second: Vec<f32>, steps: Vec<u32>) -> Result<Self> {
        let n = grid.params().len();
        if first.len() != n || second.len() != n || steps.len() != n {
            return Err(Error::Argument(format!(
                "sparse Adam state: {}/{}/{} values for a table of {n}",
                first.len(),
                second.len(),
                steps.len()
            )));
        }
        let horizon = steps.iter().copied().max().unwrap_or(0);
        Ok(SparseAdam { config, first, second, steps, corrections: vec![f32::NAN], horizon })
    }

    /// First moments, second moments and step counts, one per table parameter.
    pub fn state(&self) -> (&[f32], &[f32], &[u32]) {
        (&self.first, &self.second, &self.steps)
    }

    /// Update the parameters of `grid` that `grad` touched, then clear `grad` for the next step.
    pub fn step(&mut self, grid: &mut HashGrid, grad: &mut HashGridGradient) {
        assert_eq!(self.first.len(), grid.params().len(), "sparse Adam: made for another grid");
        // Each step advances any parameter's count by at most one.
        self.horizon += 1;
        let SparseAdamConfig { learning_rate, beta1, beta2, epsilon } = self.config;
        let known = self.corrections.len() as u32;
        self.corrections.extend((known..=self.horizon).map(|t| {
            let t = t as i32;
            ((1.0 - (beta2 as f64).powi(t)).sqrt() / (1.0 - (beta1 as f64).powi(t))) as f32
        }));
        let f = grid.config().features_per_level;
        let bounds: Vec<usize> = grid.levels().iter().map(|l| (l.offset + l.entries) as usize * f).collect();
        let corrections = &self.corrections;
        let params = split_at_bounds(grid.params_mut(), &bounds);
        let first = split_at_bounds(&mut self.first, &bounds);
        let second = split_at_bounds(&mut self.second, &bounds);
        let steps = split_at_bounds(&mut self.steps, &bounds);
        grad.levels_mut().zip(params).zip(first).zip(second).zip(steps).for_each(|(((((values, touched), theta), m), v), t)| {
            for (w, word) in touched.iter_mut().enumerate() {
                let mut bits = std::mem::take(word);
                while bits != 0 {
                    let e = w * 64 + bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    for i in e * f..(e + 1) * f {
                        let g = values[i];
                        if g == 0.0 {
                            continue;
                        }
                        m[i] = beta1 * m[i] + (1.0 - beta1) * g;
                        v[i] = beta2 * v[i] + (1.0 - beta2) * g * g;
                        t[i] += 1;
                        let rate = learning_rate * corrections[t[i] as usize] / (v[i].sqrt() + epsilon);
                        theta[i] -= rate * m[i];
                    }
                }
            }
        });
    }
}

/// `slice` cut into consecutive pieces ending at each of `bounds` (increasing).
fn split_at_bounds<'a, T>(mut slice: &'a mut [T], bounds: &[usize]) -> Vec<&'a mut [T]> {
    let mut start = 0;
    let mut pieces = Vec::with_capacity(bounds.len());
    for &end in bounds {
        let (head, tail) = std::mem::take(&mut slice).split_at_mut(end - start);
        pieces.push(head);
        slice = tail;
        start = end;
    }
    pieces
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::field::ngp::hash_grid::HashGridConfig;

    /// One dense level of 8 entries, F = 1, all parameters 0; a point at the cube's origin has
    /// pos 0.5 on every axis, so each of the 8 entries gets weight 1/8.
    fn tiny() -> (HashGrid, HashGridGradient) {
        let config = HashGridConfig { levels: 1, features_per_level: 1, log2_table_size: 3, base_resolution: 2, max_resolution: 2 };
        let grid = HashGrid::from_params(config, vec![0.0; 8]).unwrap();
        let grad = HashGridGradient::new(&grid);
        (grid, grad)
    }

    #[test]
    fn steps_match_hand_computed_values() {
        let (mut grid, mut grad) = tiny();
        let mut adam = SparseAdam::new(SparseAdamConfig::default(), &grid);
        // Point (0.25, 0.25, 0.25): pos 0.75 on each axis, cell 0, corner (1,1,1) = entry 7 has
        // weight 0.75³, corner (0,0,0) = entry 0 weight 0.25³. ∂L/∂y = 0.5/0.75³ gives entry 7
        // g = 0.5 exactly (up to rounding), entry 0 g = 0.5/27.
        let x = [[0.25f32, 0.25, 0.25]];
        grid.backward(&x, &[0.5 / 0.421875], &mut grad);
        let g7 = grad.to_dense()[7];
        assert!((g7 - 0.5).abs() < 1e-7);
        adam.step(&mut grid, &mut grad);
        // Step 1: m = 0.05, v = 0.0025, lr·√0.01/0.1 = lr, so θ₇ = −lr·0.05/0.05 = −0.01:
        // Adam's first step is lr·sign(g) for every touched parameter, whatever |g|.
        let p = grid.params().to_vec();
        assert!((p[7] + 0.01).abs() < 1e-7, "{}", p[7]);
        assert!((p[0] + 0.01).abs() < 1e-7, "{}", p[0]);
        assert_eq!(grad.touched_entries(), 0, "the step consumes the gradient");
        // Step 2, g₇ = −0.5: m = 0.9·0.05 − 0.05 = −0.005, v = 0.99·0.0025 + 0.0025 = 0.004975
        // = 0.0199/4; rate = lr·√0.0199/0.19 / (√0.0199/2) = 0.02/0.19; Δθ = −rate·m = +1/1900.
        grid.backward(&x, &[-0.5 / 0.421875], &mut grad);
        adam.step(&mut grid, &mut grad);
        let q = grid.params();
        assert!((q[7] - (p[7] + 1.0 / 1900.0)).abs() < 1e-7, "{} vs {}", q[7], p[7] + 1.0 / 1900.0);
        assert_eq!(adam.state().2[7], 2);
    }

    #[test]
    fn untouched_and_zero_gradient_parameters_keep_their_state() {
        let (mut grid, mut grad) = tiny();
        let mut adam = SparseAdam::new(SparseAdamConfig::default(), &grid);
        // pos (0.5, 0.5, 0.5) with x = 0: all 8 corners, weight 1/8 each; a zero ∂L/∂y touches
        // them all with gradient 0 — no parameter moves and no step count advances.
        grid.backward(&[[0.0, 0.0, 0.0]], &[0.0], &mut grad);
        assert_eq!(grad.touched_entries(), 8);
        adam.step(&mut grid, &mut grad);
        assert!(grid.params().iter().all(|&p| p == 0.0));
        assert!(adam.state().2.iter().all(|&t| t == 0));
        // Then three steps on a point in cell (0,0,0) with frac (0.5, 0, 0) (x = (0, 1/2, 1/2)
        // gives pos (0.5, 1, 1): cell (0, 1, 1), frac (0.5, 0, 0)): entries 6 and 7 (x = 0, 1 at
        // y = z = 1) get weight ½, the rest 0 — only their counts advance.
        for _ in 0..3 {
            grid.backward(&[[0.0, 0.5, 0.5]], &[1.0], &mut grad);
            adam.step(&mut grid, &mut grad);
        }
        let steps = adam.state().2.to_vec();
        assert_eq!(steps, [0, 0, 0, 0, 0, 0, 3, 3]);
        // An entry first touched at step 5 gets a first step's update: −lr·sign(g).
        grid.backward(&[[0.25, 0.25, 0.25]], &[1.0], &mut grad);
        let before = grid.params()[0];
        adam.step(&mut grid, &mut grad);
        assert!((grid.params()[0] - (before - 0.01)).abs() < 1e-7, "{} → {}", before, grid.params()[0]);
        assert_eq!(adam.state().2[0], 1);
    }

    #[test]
    fn state_round_trips_and_bad_state_is_named() {
        let (grid, _) = tiny();
        let adam = SparseAdam::new(SparseAdamConfig::default(), &grid);
        let (m, v, t) = adam.state();
        let back = SparseAdam::from_state(adam.config, &grid, m.to_vec(), v.to_vec(), t.to_vec()).unwrap();
        assert_eq!(back.state(), adam.state());
        // Restored counts beyond this session's steps still find their bias correction.
        let (mut grid, mut grad) = tiny();
        let mut resumed = SparseAdam::from_state(adam.config, &grid, vec![0.0; 8], vec![0.0; 8], vec![500; 8]).unwrap();
        grid.backward(&[[0.25, 0.25, 0.25]], &[1.0], &mut grad);
        resumed.step(&mut grid, &mut grad);
        assert!(grid.params().iter().all(|p| p.is_finite()) && resumed.state().2[7] == 501);
        let err = SparseAdam::from_state(adam.config, &grid, vec![0.0; 3], v.to_vec(), t.to_vec()).unwrap_err().to_string();
        assert!(err.contains("3/8/8") && err.contains("table of 8"), "{err}");
    }
}
