//! Adam on plain values as burn's optimiser steps the MLPs (bias-corrected moments, ε outside
//! the root), for the small per-image parameters: appearance codes and camera corrections. The
//! hash table has its own sparse variant, tiny-cuda-nn's ([`crate::field::ngp::adam`]).

/// Adam's moment decays and ε.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DenseAdam {
    /// First-moment decay β₁.
    pub beta1: f32,
    /// Second-moment decay β₂.
    pub beta2: f32,
    /// ε added to the corrected √v.
    pub epsilon: f32,
}

impl DenseAdam {
    /// Step `values` against `grad` at learning rate `lr`, `t` being the moments' step count
    /// after this one (1 for the first).
    pub fn update(&self, values: &mut [f32], first: &mut [f32], second: &mut [f32], grad: &[f32], t: u64, lr: f32) {
        assert!(first.len() == values.len() && second.len() == values.len() && grad.len() == values.len(), "Adam: one moment and one gradient per value");
        let DenseAdam { beta1, beta2, epsilon } = *self;
        let t = t.min(i32::MAX as u64) as i32;
        let (c1, c2) = (1.0 - beta1.powi(t), 1.0 - beta2.powi(t));
        for (((x, m), v), &g) in values.iter_mut().zip(first).zip(second).zip(grad) {
            *m = beta1 * *m + (1.0 - beta1) * g;
            *v = beta2 * *v + (1.0 - beta2) * g * g;
            *x -= lr * (*m / c1) / ((*v / c2).sqrt() + epsilon);
        }
    }
}
