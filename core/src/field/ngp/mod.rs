//! The instant-ngp field as plain data: a hash grid on the positions, degree-4 spherical
//! harmonics on the view directions, and two small MLPs (tiny-cuda-nn's, bias-free):
//!
//! - density: grid features `[L·F]` → `density_hidden` (ReLU) → `1 + geometry_features`;
//!   σ = exp of the first output ("trunc_exp": its gradient is clamped when training);
//! - colour: `[the other geometry_features outputs, SH(d)]` → `color_hidden` (ReLU) →
//!   `color_hidden` (ReLU) → 3, sigmoid.
//!
//! The burn trainer builds its modules from [`NgpSpec`]; the ONNX compiler turns a
//! [`PlainNgp`] into one graph with the graph contract of the NeRF networks.

pub mod hash_grid;
pub mod spherical_harmonics;

use hash_grid::{GridBound, HashGridConfig};
use crate::field::DenseLayer;
use spherical_harmonics::SH4_DIM;
use serde::{Deserialize, Serialize};

/// The field's shape.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NgpSpec {
    /// The position encoding.
    pub grid: HashGridConfig,
    /// The world box the grid covers.
    pub bound: GridBound,
    /// Hidden width of the density MLP (64).
    pub density_hidden: usize,
    /// Outputs of the density MLP besides σ, passed to the colour MLP (15).
    pub geometry_features: usize,
    /// Hidden width of the colour MLP's two layers (64).
    pub color_hidden: usize,
}

impl Default for NgpSpec {
    /// instant-ngp's NeRF sizes in the Blender scenes' box [−1.5, 1.5]³.
    fn default() -> Self {
        NgpSpec { grid: HashGridConfig::default(), bound: GridBound::cube(1.5), density_hidden: 64, geometry_features: 15, color_hidden: 64 }
    }
}

impl NgpSpec {
    /// Every dense layer as (name, input width, output width), density first.
    pub fn layer_shapes(&self) -> Vec<(String, usize, usize)> {
        let (h, g, c) = (self.density_hidden, self.geometry_features, self.color_hidden);
        vec![
            ("density.0".into(), self.grid.output_dim(), h),
            ("density.1".into(), h, 1 + g),
            ("color.0".into(), g + SH4_DIM, c),
            ("color.1".into(), c, c),
            ("color.2".into(), c, 3),
        ]
    }

    /// Check the grid, the bound and the widths.
    pub fn validate(&self) -> crate::Result<()> {
        self.grid.validate()?;
        self.bound.validate()?;
        if self.density_hidden == 0 || self.color_hidden == 0 {
            return Err(crate::Error::Argument(format!("ngp field: hidden widths {} and {} must be positive", self.density_hidden, self.color_hidden)));
        }
        Ok(())
    }
}

impl crate::field::KindShape for NgpSpec {
    fn check(&self) -> Result<(), String> {
        self.validate().map_err(|e| e.to_string())
    }

    fn field_box(&self) -> Option<GridBound> {
        Some(self.bound)
    }
}

/// A trained field as plain data: spec, hash table and dense layers (bias all zero: the
/// networks are bias-free, the zeros keep one layer type for the compiler).
#[derive(Debug, Clone, PartialEq)]
pub struct PlainNgp {
    /// The shape.
    pub spec: NgpSpec,
    /// The hash table, `[total_entries, F]` row-major.
    pub table: Vec<f32>,
    /// The layers in [`NgpSpec::layer_shapes`] order.
    pub layers: Vec<DenseLayer>,
}

impl PlainNgp {
    /// Check that the table and every layer have the sizes the spec implies.
    pub fn validate(&self) -> crate::Result<()> {
        self.spec.validate()?;
        let want = self.spec.grid.total_entries()? * self.spec.grid.features_per_level;
        if self.table.len() != want {
            return Err(crate::Error::Argument(format!("ngp field: table has {} values, the grid needs {want}", self.table.len())));
        }
        let shapes = self.spec.layer_shapes();
        if shapes.len() != self.layers.len() {
            return Err(crate::Error::Argument(format!("ngp field: {} layers, expected {}", self.layers.len(), shapes.len())));
        }
        for ((name, i, o), l) in shapes.iter().zip(&self.layers) {
            if (&l.name, l.in_dim, l.out_dim, l.weight.len(), l.bias.len()) != (name, *i, *o, i * o, *o) {
                return Err(crate::Error::Argument(format!("ngp field: layer {} is {}×{} ({} weights), expected {name} {i}×{o}", l.name, l.in_dim, l.out_dim, l.weight.len())));
            }
        }
        Ok(())
    }
}

impl PlainNgp {
    /// Reference evaluation (slow, obviously correct; the oracle of the export checks).
    ///
    /// # Shapes
    /// `points`, `viewdirs`: `[n, 3]` → (`rgb` `[n, 3]`, σ `[n]`).
    pub fn forward(&self, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> crate::Result<(Vec<[f32; 3]>, Vec<f32>)> {
        self.validate()?;
        let grid = crate::field::ngp::hash_grid::HashGrid::from_params(self.spec.grid, self.table.clone())?;
        let unit: Vec<[f32; 3]> = points.iter().map(|&p| self.spec.bound.to_unit(p)).collect();
        let features = grid.forward(&unit);
        let dense = |l: &DenseLayer, x: &[f32], relu: bool| -> Vec<f32> {
            (0..l.out_dim)
                .map(|o| {
                    let v = l.bias[o] + (0..l.in_dim).map(|i| x[i] * l.weight[i * l.out_dim + o]).sum::<f32>();
                    if relu { v.max(0.0) } else { v }
                })
                .collect()
        };
        let (mut rgb, mut sigma) = (Vec::new(), Vec::new());
        for (x, &d) in features.chunks_exact(grid.output_dim()).zip(viewdirs) {
            let out = dense(&self.layers[1], &dense(&self.layers[0], x, true), false);
            sigma.push(out[0].exp());
            let mut c = out[1..].to_vec();
            c.extend(crate::field::ngp::spherical_harmonics::sh4(d));
            let c = dense(&self.layers[3], &dense(&self.layers[2], &c, true), true);
            let c = dense(&self.layers[4], &c, false);
            rgb.push([0, 1, 2].map(|i| 1.0 / (1.0 + (-c[i]).exp())));
        }
        Ok((rgb, sigma))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layer_shapes_follow_the_spec() {
        let spec = NgpSpec::default();
        let shapes = spec.layer_shapes();
        assert_eq!(shapes[0], ("density.0".to_string(), 32, 64));
        assert_eq!(shapes[1].2, 16);
        assert_eq!(shapes[2].1, 31, "15 geometry features + 16 harmonics");
        assert_eq!(shapes[4].2, 3);
        let json = serde_json::to_string(&spec).unwrap();
        assert_eq!(serde_json::from_str::<NgpSpec>(&json).unwrap(), spec);
        assert!(NgpSpec { color_hidden: 0, ..spec }.validate().is_err());
    }
}
