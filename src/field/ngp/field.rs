//! The instant-ngp field ([`nerf_core::field::ngp`]): the hash grid runs in nerf-core, the two small
//! MLPs are burn parameters (checkpoints, burn's Adam) that run as [`FusedMlps`]: forward and
//! backward in plain Rust, no autodiff graph. The features' gradient from
//! [`FusedMlps::backward`] is scattered into the table, which is stepped with the sparse Adam of
//! [`super::adam`]. [`NgpMlps::forward`] is the same MLPs in burn, the reference the fused ones
//! are tested against.

use burn::module::{Module, Param, ParamId};
use burn::nn::Linear;
use burn::tensor::activation::{relu, sigmoid};
use super::appearance::RenderedAppearance;
use super::fused::FusedMlps;
use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::field::ngp::hash_grid::HashGrid;
use nerf_core::field::DenseLayer;
use nerf_core::Rng;
use nerf_core::field::ngp::{NgpSpec, PlainNgp};
use nerf_core::field::ngp::spherical_harmonics::sh4_all;

/// The density and colour MLPs, bias-free as tiny-cuda-nn's, layers in
/// [`NgpSpec::layer_shapes`] order.
#[derive(Module, Debug)]
pub struct NgpMlps {
    density: Vec<Linear>,
    color: Vec<Linear>,
}

impl NgpMlps {
    /// Fresh layers, weights U(±1/√fan_in) (burn's default for `Linear`) drawn from `rng`, so
    /// that a field's start depends on its seed alone (not on the device's shared generator,
    /// which concurrent users would interleave).
    pub fn new(spec: &NgpSpec, rng: &mut Rng, device: &Device) -> Self {
        let mut layers: Vec<Linear> = spec
            .layer_shapes()
            .into_iter()
            .map(|(_, i, o)| {
                let bound = 1.0 / (i as f32).sqrt();
                let weight: Vec<f32> = (0..i * o).map(|_| (rng.uniform() * 2.0 - 1.0) * bound).collect();
                Linear { weight: Param::from_tensor(Tensor::from_data(TensorData::new(weight, [i, o]), device)), bias: None }
            })
            .collect();
        let color = layers.split_off(2);
        NgpMlps { density: layers, color }
    }

    /// σ and colour from grid features and view harmonics, in burn (the reference of
    /// [`FusedMlps`], which training and rendering use). The colour MLP sees the density
    /// MLP's outputs after the first (σ's), then the harmonics.
    ///
    /// # Shapes
    /// `features`: `[n, L·F]`, `sh`: `[n, 16]` → (`rgb` `[n, 3]` in (0, 1), σ `[n]` ≥ 0).
    pub fn forward(&self, features: Tensor<2>, sh: Tensor<2>) -> (Tensor<2>, Tensor<1>) {
        let n = features.dims()[0];
        let out = self.density[1].forward(relu(self.density[0].forward(features)));
        let geometry = out.dims()[1] - 1;
        let sigma = trunc_exp(out.clone().narrow(1, 0, 1).reshape([n]));
        let c = Tensor::cat(vec![out.narrow(1, 1, geometry), sh], 1);
        let c = relu(self.color[0].forward(c));
        let c = relu(self.color[1].forward(c));
        (sigmoid(self.color[2].forward(c)), sigma)
    }
}

impl NgpMlps {
    /// The layers in [`NgpSpec::layer_shapes`] order.
    fn layers(&self) -> impl Iterator<Item = &Linear> {
        self.density.iter().chain(&self.color)
    }

    /// The five weight matrices as plain arrays `[in, out]`, in [`NgpSpec::layer_shapes`] order.
    pub fn weights(&self) -> [Vec<f32>; 5] {
        let mut layers = self.layers().map(|l| l.weight.val().into_data().try_to_vec::<f32>().expect("f32 weights"));
        [(); 5].map(|_| layers.next().expect("five layers"))
    }

    /// Each weight's parameter id and shape `[in, out]`, in the same order.
    pub fn weight_ids(&self) -> Vec<(ParamId, [usize; 2])> {
        self.layers().map(|l| (l.weight.id, l.weight.val().dims())).collect()
    }
}

/// `exp(x)` whose gradient is `exp(clamp(x, −15, 15))` (instant-ngp's `trunc_exp`: a large raw
/// density cannot blow the gradient up). Written with detached factors: the value is
/// `exp(x) + slope·(x − x)`, whose derivative is the detached slope.
pub fn trunc_exp<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    let slope = x.clone().clamp(-15.0, 15.0).exp().detach();
    let value = x.clone().exp().detach();
    value + slope * (x.clone() - x.detach())
}

/// A hash-grid field: the table (plain data) and the MLPs (burn).
#[derive(Debug)]
pub struct NgpField {
    /// The shape.
    pub spec: NgpSpec,
    /// The hash table.
    pub grid: HashGrid,
    /// The networks.
    pub mlps: NgpMlps,
    /// Per-image appearance codes and the one the field renders with (color.0's bias), for a
    /// field trained with them.
    pub appearance: Option<RenderedAppearance>,
}

impl NgpField {
    /// A fresh field: table U(±1e-4) from `seed`, MLPs from a generator forked from it.
    pub fn new(spec: NgpSpec, seed: u64, device: &Device) -> Result<Self, String> {
        spec.validate().map_err(|e| e.to_string())?;
        let grid = HashGrid::new(spec.grid, seed).map_err(|e| e.to_string())?;
        Ok(NgpField { spec, grid, mlps: NgpMlps::new(&spec, &mut Rng::new(seed).fork(), device), appearance: None })
    }

    /// World points in the unit cube, and their grid features `[n, L·F]` (what the grid's
    /// backward pass and the MLPs take).
    pub fn encode(&self, points: &[[f32; 3]]) -> (Vec<[f32; 3]>, Vec<f32>) {
        let unit: Vec<[f32; 3]> = points.iter().map(|&p| self.spec.bound.to_unit(p)).collect();
        let features = self.grid.forward(&unit);
        (unit, features)
    }

    /// The MLPs as [`FusedMlps`] (a copy of their weights), with the fixed appearance's code
    /// as color.0's bias.
    pub fn fused(&self) -> FusedMlps {
        let fused = FusedMlps::from_mlps(&self.spec, &self.mlps);
        match &self.appearance {
            Some(a) => fused.with_color_bias(a.code().to_vec()),
            None => fused,
        }
    }

    /// rgb and σ at world points with unit view directions (no gradient), through the
    /// [`FusedMlps`].
    ///
    /// # Shapes
    /// `points`, `viewdirs`: `[n, 3]` → (`rgb` `[n, 3]`, σ `[n]`).
    pub fn forward(&self, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> (Vec<[f32; 3]>, Vec<f32>) {
        assert_eq!(points.len(), viewdirs.len(), "one view direction per point");
        let (_, features) = self.encode(points);
        self.fused().forward(&features, &sh4_all(viewdirs))
    }

    /// σ at world points (the density MLP only; no gradient).
    pub fn density(&self, points: &[[f32; 3]]) -> Vec<f32> {
        let (_, features) = self.encode(points);
        self.fused().density(&features)
    }

    /// The field as plain data for the ONNX compiler: zero biases, but color.0's, which is the
    /// fixed appearance's code when the field has one.
    pub fn to_plain(&self) -> PlainNgp {
        let layers = self
            .mlps
            .weights()
            .into_iter()
            .zip(self.spec.layer_shapes())
            .map(|(weight, (name, in_dim, out_dim))| {
                let bias = match &self.appearance {
                    Some(a) if name == "color.0" => a.code().to_vec(),
                    _ => vec![0.0; out_dim],
                };
                DenseLayer { name, in_dim, out_dim, weight, bias }
            })
            .collect();
        PlainNgp { spec: self.spec, table: self.grid.params().to_vec(), layers }
    }

    /// A field from plain data (biases must be zero: the MLPs have none, and a fixed
    /// appearance is not read back as codes).
    pub fn from_plain(plain: &PlainNgp, device: &Device) -> Result<Self, String> {
        plain.validate().map_err(|e| e.to_string())?;
        if let Some(l) = plain.layers.iter().find(|l| l.bias.iter().any(|&b| b != 0.0)) {
            return Err(format!("ngp field: layer {} has a non-zero bias, the MLPs are bias-free", l.name));
        }
        let grid = HashGrid::from_params(plain.spec.grid, plain.table.clone()).map_err(|e| e.to_string())?;
        let mut layers: Vec<Linear> = plain
            .layers
            .iter()
            .map(|l| Linear { weight: Param::from_tensor(Tensor::from_data(TensorData::new(l.weight.clone(), [l.in_dim, l.out_dim]), device)), bias: None })
            .collect();
        let color = layers.split_off(2);
        Ok(NgpField { spec: plain.spec, grid, mlps: NgpMlps { density: layers, color }, appearance: None })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::optim::AdamConfig;
    use nerf_core::Rng;
    use nerf_core::field::ngp::hash_grid::HashGridGradient;
    use crate::field::ngp::adam::{SparseAdam, SparseAdamConfig};
    use nerf_core::field::ngp::hash_grid::{GridBound, HashGridConfig};

    #[test]
    fn trunc_exp_has_a_clamped_gradient() {
        let device = crate::backend::cpu_autodiff();
        let x = Tensor::<1>::from_data(TensorData::new(vec![0.0f32, 2.0, 20.0, -20.0], [4]), &device).require_grad();
        let y = trunc_exp(x.clone());
        let value = y.clone().into_data().try_to_vec::<f32>().unwrap();
        let grads = y.sum().backward();
        let grad = x.grad(&grads).unwrap().into_data().try_to_vec::<f32>().unwrap();
        for (i, (&v, &xv)) in value.iter().zip(&[0.0f32, 2.0, 20.0, -20.0]).enumerate() {
            assert!((v / xv.exp() - 1.0).abs() < 1e-6, "value {i}: {v}");
        }
        let want = [1.0f32, 2f32.exp(), 15f32.exp(), (-15f32).exp()];
        for (g, w) in grad.iter().zip(want) {
            assert!((g / w - 1.0).abs() < 1e-5, "gradient {g} vs {w}");
        }
    }

    fn small_spec() -> NgpSpec {
        NgpSpec {
            grid: HashGridConfig { levels: 8, features_per_level: 2, log2_table_size: 12, base_resolution: 4, max_resolution: 64 },
            bound: GridBound::cube(1.0),
            density_hidden: 32,
            geometry_features: 15,
            color_hidden: 32,
        }
    }

    #[test]
    fn training_steps_reduce_the_loss_and_move_the_table() {
        let device = crate::backend::cpu_autodiff();
        let mut field = NgpField::new(small_spec(), 1, &device).unwrap();
        let mut rng = Rng::new(2);
        let n = 1024;
        let points: Vec<[f32; 3]> = (0..n).map(|_| [0; 3].map(|_: i32| rng.uniform() * 2.0 - 1.0)).collect();
        let sh = sh4_all(&vec![[0.0, 0.6, 0.8]; n]);
        // A colour that only the position can explain.
        let target: Vec<[f32; 3]> = points.iter().map(|p| [0.5 + 0.4 * (3.0 * p[0]).sin(), 0.5 + 0.4 * (3.0 * p[1]).cos(), 0.5 + 0.4 * p[2]]).collect();
        let mut optim = AdamConfig::new().with_beta_2(0.99).with_epsilon(1e-15).init();
        let mut table_adam = SparseAdam::new(SparseAdamConfig::default(), &field.grid);
        let mut grad = HashGridGradient::new(&field.grid);
        let initial_table = field.grid.params().to_vec();
        let mut losses = Vec::new();
        for _ in 0..40 {
            let fused = field.fused();
            let (unit, features) = field.encode(&points);
            let ((rgb, _), saved) = fused.forward_train(&features, &sh, None);
            let count = (3 * n) as f32;
            let mut loss = 0.0;
            let grad_rgb: Vec<[f32; 3]> = rgb.iter().zip(&target).map(|(c, t)| [0, 1, 2].map(|k| {
                loss += (c[k] - t[k]).powi(2) / count;
                2.0 * (c[k] - t[k]) / count
            })).collect();
            losses.push(loss);
            let (mlp_grads, grad_features) = fused.backward(&features, &sh, None, &saved, &grad_rgb, &vec![0.0; n], None);
            field.grid.backward(&unit, &grad_features, &mut grad);
            assert!(grad.touched_entries() > 0 && grad.to_dense().iter().any(|&g| g != 0.0), "the table gets gradients");
            table_adam.step(&mut field.grid, &mut grad);
            let params = mlp_grads.to_params(&field.mlps, &crate::backend::cpu());
            field.mlps = optim.step(1e-2, field.mlps, params);
        }
        println!("loss {:.5} → {:.5}", losses[0], losses[losses.len() - 1]);
        assert!(losses[39] < 0.3 * losses[0], "loss {:?}", losses);
        let moved = field.grid.params().iter().zip(&initial_table).filter(|(a, b)| a != b).count();
        assert!(moved > field.grid.params().len() / 10, "only {moved} table parameters moved");
    }

    #[test]
    fn plain_round_trip() {
        let device = crate::backend::cpu();
        device.seed(5);
        let field = NgpField::new(small_spec(), 3, &device).unwrap();
        let plain = field.to_plain();
        plain.validate().unwrap();
        let again = NgpField::from_plain(&plain, &device).unwrap();
        assert_eq!(again.to_plain(), plain);
        let mut biased = plain.clone();
        biased.layers[3].bias[0] = 1.0;
        assert!(NgpField::from_plain(&biased, &device).unwrap_err().contains("color.1"));
    }
}
