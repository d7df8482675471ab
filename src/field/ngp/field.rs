//! The instant-ngp field in burn ([`nerf_core::field::ngp`]): the hash grid runs in nerf-core, outside
//! the autodiff graph, and its features enter burn as a leaf tensor that requires a gradient;
//! after `backward`, that leaf's gradient is scattered into the table
//! ([`NgpField::accumulate_grid_gradient`]) and the table is stepped with
//! [`nerf_core::field::ngp::hash_grid::SparseAdam`]. Only the two small MLPs are burn parameters.

use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::{Device, Gradients, Tensor, TensorData};
use nerf_core::field::ngp::hash_grid::{HashGrid, HashGridGradient};
use nerf_core::field::DenseLayer;
use nerf_core::Rng;
use nerf_core::field::ngp::{NgpSpec, PlainNgp};
use nerf_core::field::ngp::spherical_harmonics::{SH4_DIM, sh4_all};

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

    /// σ and colour from grid features and view harmonics. The colour MLP sees the density
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
    /// σ alone (the density MLP), for the occupancy grid's updates.
    ///
    /// # Shapes
    /// `features`: `[n, L·F]` → σ `[n]`.
    pub fn density(&self, features: Tensor<2>) -> Tensor<1> {
        let n = features.dims()[0];
        let out = self.density[1].forward(relu(self.density[0].forward(features)));
        out.narrow(1, 0, 1).reshape([n]).exp()
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
}

/// What one training evaluation keeps for the grid's backward pass.
#[derive(Debug)]
pub struct GridInputs {
    unit: Vec<[f32; 3]>,
    features: Tensor<2>,
    /// Seconds the grid's forward pass took (for the step's timing).
    pub encode_s: f64,
}

impl NgpField {
    /// A fresh field: table U(±1e-4) from `seed`, MLPs from a generator forked from it.
    pub fn new(spec: NgpSpec, seed: u64, device: &Device) -> Result<Self, String> {
        spec.validate().map_err(|e| e.to_string())?;
        let grid = HashGrid::new(spec.grid, seed).map_err(|e| e.to_string())?;
        Ok(NgpField { spec, grid, mlps: NgpMlps::new(&spec, &mut Rng::new(seed).fork(), device) })
    }

    /// World points in the unit cube, and their grid features `[n, L·F]`.
    fn grid_features(&self, points: &[[f32; 3]], device: &Device) -> (Vec<[f32; 3]>, Tensor<2>) {
        let unit: Vec<[f32; 3]> = points.iter().map(|&p| self.spec.bound.to_unit(p)).collect();
        let features = Tensor::<2>::from_data(TensorData::new(self.grid.forward(&unit), [points.len(), self.grid.output_dim()]), device);
        (unit, features)
    }

    fn encode(&self, points: &[[f32; 3]], viewdirs: &[[f32; 3]], device: &Device) -> (Vec<[f32; 3]>, Tensor<2>, Tensor<2>) {
        assert_eq!(points.len(), viewdirs.len(), "one view direction per point");
        let (unit, features) = self.grid_features(points, device);
        let sh = Tensor::<2>::from_data(TensorData::new(sh4_all(viewdirs), [points.len(), SH4_DIM]), device);
        (unit, features, sh)
    }

    /// Evaluate at world points with unit view directions (no gradient for the table).
    ///
    /// # Shapes
    /// `points`, `viewdirs`: `[n, 3]` → (`rgb` `[n, 3]`, σ `[n]`).
    pub fn forward(&self, points: &[[f32; 3]], viewdirs: &[[f32; 3]], device: &Device) -> (Tensor<2>, Tensor<1>) {
        let (_, features, sh) = self.encode(points, viewdirs, device);
        self.mlps.forward(features, sh)
    }

    /// σ at world points (the density MLP only; no gradient).
    pub fn density(&self, points: &[[f32; 3]], device: &Device) -> Vec<f32> {
        let (_, features) = self.grid_features(points, device);
        self.mlps.density(features).into_data().try_to_vec::<f32>().expect("f32 densities")
    }

    /// [`forward`](Self::forward) on an autodiff device, the grid features a leaf that requires a
    /// gradient; pass the returned [`GridInputs`] to
    /// [`accumulate_grid_gradient`](Self::accumulate_grid_gradient) after `backward`.
    pub fn forward_train(&self, points: &[[f32; 3]], viewdirs: &[[f32; 3]], device: &Device) -> (Tensor<2>, Tensor<1>, GridInputs) {
        let start = std::time::Instant::now();
        let (unit, features, sh) = self.encode(points, viewdirs, device);
        let encode_s = start.elapsed().as_secs_f64();
        let features = features.require_grad();
        let (rgb, sigma) = self.mlps.forward(features.clone(), sh);
        (rgb, sigma, GridInputs { unit, features, encode_s })
    }

    /// Take the features' gradient out of `grads` and add its scatter into the table to `grad`.
    pub fn accumulate_grid_gradient(&self, inputs: &GridInputs, grads: &mut Gradients, grad: &mut HashGridGradient) -> Result<(), String> {
        let g = inputs.features.grad_remove(grads).ok_or("the grid features got no gradient (not an autodiff device, or not in the loss)")?;
        let g = g.into_data().try_to_vec::<f32>().map_err(|e| format!("grid feature gradient: {e:?}"))?;
        self.grid.backward(&inputs.unit, &g, grad);
        Ok(())
    }

    /// The field as plain data for the ONNX compiler.
    pub fn to_plain(&self) -> PlainNgp {
        let layers = self
            .mlps
            .density
            .iter()
            .chain(&self.mlps.color)
            .zip(self.spec.layer_shapes())
            .map(|(l, (name, in_dim, out_dim))| DenseLayer {
                name,
                in_dim,
                out_dim,
                weight: l.weight.val().into_data().try_to_vec::<f32>().expect("f32 weights"),
                bias: vec![0.0; out_dim],
            })
            .collect();
        PlainNgp { spec: self.spec, table: self.grid.params().to_vec(), layers }
    }

    /// A field from plain data (biases must be zero: the MLPs have none).
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
        Ok(NgpField { spec: plain.spec, grid, mlps: NgpMlps { density: layers, color } })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::optim::{AdamConfig, GradientsParams};
    use nerf_core::Rng;
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
        device.seed(4);
        let mut field = NgpField::new(small_spec(), 1, &device).unwrap();
        let mut rng = Rng::new(2);
        let n = 1024;
        let points: Vec<[f32; 3]> = (0..n).map(|_| [0; 3].map(|_: i32| rng.uniform() * 2.0 - 1.0)).collect();
        let dirs: Vec<[f32; 3]> = (0..n).map(|_| [0.0, 0.6, 0.8]).collect();
        // A colour that only the position can explain.
        let target: Vec<f32> = points.iter().flat_map(|p| [0.5 + 0.4 * (3.0 * p[0]).sin(), 0.5 + 0.4 * (3.0 * p[1]).cos(), 0.5 + 0.4 * p[2]]).collect();
        let target = Tensor::<2>::from_data(TensorData::new(target, [n, 3]), &device);
        let mut optim = AdamConfig::new().with_beta_2(0.99).with_epsilon(1e-15).init();
        let mut table_adam = SparseAdam::new(SparseAdamConfig::default(), &field.grid);
        let mut grad = HashGridGradient::new(&field.grid);
        let initial_table = field.grid.params().to_vec();
        let mut losses = Vec::new();
        for _ in 0..40 {
            let (rgb, _, inputs) = field.forward_train(&points, &dirs, &device);
            let loss = (rgb - target.clone()).square().mean();
            losses.push(loss.clone().into_scalar::<f32>());
            let mut grads = loss.backward();
            field.accumulate_grid_gradient(&inputs, &mut grads, &mut grad).unwrap();
            assert!(grad.touched_entries() > 0 && grad.to_dense().iter().any(|&g| g != 0.0), "the table gets gradients");
            table_adam.step(&mut field.grid, &mut grad);
            let params = GradientsParams::from_grads(grads, &field.mlps);
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
