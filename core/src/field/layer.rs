//! One dense layer as plain data, the unit every field's MLPs are written in.

use serde::{Deserialize, Serialize};

/// One dense layer: `y = x·W + b`.
///
/// # Shapes
/// `weight`: `[in_dim, out_dim]` row-major; `bias`: `[out_dim]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DenseLayer {
    /// Layer name from its network's `layer_shapes`.
    pub name: String,
    /// Input width.
    pub in_dim: usize,
    /// Output width.
    pub out_dim: usize,
    /// Weights, `[in_dim, out_dim]` row-major.
    pub weight: Vec<f32>,
    /// Bias, `[out_dim]`.
    pub bias: Vec<f32>,
}

impl DenseLayer {
    pub(crate) fn apply(&self, x: &[f32], relu: bool) -> Vec<f32> {
        let mut y = self.bias.clone();
        for (i, &xi) in x.iter().enumerate() {
            let row = &self.weight[i * self.out_dim..(i + 1) * self.out_dim];
            for (yo, w) in y.iter_mut().zip(row) {
                *yo += xi * w;
            }
        }
        if relu {
            y.iter_mut().for_each(|v| *v = v.max(0.0));
        }
        y
    }
}
