//! The NeRF MLP (nerf-pytorch's `NeRF`), built from a plain [`NetworkSpec`].

use burn::module::{Module, Param};
use burn::nn::{Linear, LinearConfig};
use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::field::mlp::{NetworkSpec, PlainNetwork};
use nerf_core::field::DenseLayer;

use super::encode;

/// One NeRF network: encoded position through `depth` ReLU layers (input concatenated back
/// after each skip), then either a σ head, a feature layer, the encoded view direction and a
/// W/2 ReLU layer to sigmoid RGB (`use_viewdirs`), or a single 4-wide output.
///
/// Layers are kept in [`NetworkSpec::layer_shapes`] order so they map one-to-one onto the plain
/// description used by the ONNX compiler.
#[derive(Module, Debug)]
pub struct NerfMlp {
    trunk: Vec<Linear>,
    heads: Vec<Linear>,
    #[module(skip)]
    spec: NetworkSpec,
}

impl NerfMlp {
    /// A freshly initialised network (PyTorch-style uniform ±1/√fan_in, burn's default).
    pub fn new(spec: &NetworkSpec, device: &Device) -> Self {
        let mut layers = spec
            .layer_shapes()
            .into_iter()
            .map(|(_, i, o)| LinearConfig::new(i, o).init(device))
            .collect::<Vec<_>>();
        let heads = layers.split_off(spec.depth);
        NerfMlp { trunk: layers, heads, spec: spec.clone() }
    }

    /// The network's shape.
    pub fn spec(&self) -> &NetworkSpec {
        &self.spec
    }

    /// Evaluate on points and unit view directions.
    ///
    /// # Shapes
    /// `points`, `viewdirs`: `[n, 3]` → (`rgb` `[n, 3]` in [0, 1], raw σ `[n]` before ReLU).
    pub fn forward(&self, points: Tensor<2>, viewdirs: Tensor<2>) -> (Tensor<2>, Tensor<1>) {
        let x = encode(&self.spec.position_encoding, points);
        let d = encode(&self.spec.direction_encoding, viewdirs);
        self.forward_encoded(x, d, 1)
    }

    /// Evaluate on already-encoded inputs, with one view direction shared by each run of
    /// `samples_per_direction` consecutive points (the samples of one ray).
    ///
    /// Concatenations (the skip input, the view direction) are written as split matrix products
    /// `[a, b]·W = a·W_a + b·W_b`, so no concatenated copy is made, and the direction's product is
    /// computed once per ray rather than once per sample.
    ///
    /// # Shapes
    /// `encoded_points`: `[n, position_dim]`; `encoded_dirs`: `[n / samples_per_direction, direction_dim]`
    /// (ignored without view directions) → (`rgb` `[n, 3]`, raw σ `[n]`).
    pub fn forward_encoded(
        &self,
        encoded_points: Tensor<2>,
        encoded_dirs: Tensor<2>,
        samples_per_direction: usize,
    ) -> (Tensor<2>, Tensor<1>) {
        let h = self.trunk_forward(encoded_points);
        let n = h.dims()[0];
        if self.spec.use_viewdirs {
            let sigma = self.heads[0].forward(h.clone()).reshape([n]);
            let v = relu(self.view_layer_on_trunk(h, encoded_dirs, samples_per_direction));
            (sigmoid(self.heads[3].forward(v)), sigma)
        } else {
            let out = self.heads[0].forward(h);
            let rgb = sigmoid(out.clone().narrow(1, 0, 3));
            (rgb, out.narrow(1, 3, 1).reshape([n]))
        }
    }

    /// Raw σ (before ReLU) only, skipping the colour layers (for occupancy updates).
    ///
    /// # Shapes
    /// `encoded_points`: `[n, position_dim]` → `[n]`.
    pub fn density(&self, encoded_points: Tensor<2>) -> Tensor<1> {
        let h = self.trunk_forward(encoded_points);
        let n = h.dims()[0];
        let out = self.heads[0].forward(h);
        if self.spec.use_viewdirs { out.reshape([n]) } else { out.narrow(1, 3, 1).reshape([n]) }
    }

    /// Multiply-adds per point this network performs: the spec's count
    /// ([`NetworkSpec::macs_per_point`]) less the feature layer's, which is folded into the view
    /// layer ([`Self::view_layer_on_trunk`]).
    pub fn macs_per_point(&self) -> usize {
        let folded = if self.spec.use_viewdirs { self.spec.width * self.spec.width } else { 0 };
        self.spec.macs_per_point() - folded
    }

    /// The ReLU layers on the encoded position (skip inputs as split products).
    fn trunk_forward(&self, x: Tensor<2>) -> Tensor<2> {
        let mut inputs = vec![x.clone()];
        for (i, layer) in self.trunk.iter().enumerate() {
            let h = relu(dense(layer, &inputs));
            inputs = if self.spec.skips.contains(&i) { vec![x.clone(), h] } else { vec![h] };
        }
        inputs.pop().expect("one trunk output")
    }

    /// The view layer's pre-activation, `[feature(h), d]·W_v + b_v`, without the feature.
    ///
    /// The feature layer has no activation, so it folds into the view layer's weights:
    /// `feature·W_v,f = h·(W_f·W_v,f) + b_f·W_v,f`. The folded 256×128 product replaces the
    /// 256×256 feature layer and the feature activations are never stored. Gradients reach `W_f`, `b_f` and `W_v` through the fold, so
    /// the parameters and the function are the paper's.
    fn view_layer_on_trunk(&self, h: Tensor<2>, encoded_dirs: Tensor<2>, group: usize) -> Tensor<2> {
        let (feature, view) = (&self.heads[1], &self.heads[2]);
        let weight = view.weight.val();
        let [n, _] = h.dims();
        let [groups, dir_width] = encoded_dirs.dims();
        let [_, out_dim] = weight.dims();
        let feature_rows = weight.clone().narrow(0, 0, self.spec.width);
        let own = h.matmul(feature.weight.val().matmul(feature_rows.clone()));
        // One direction per `group` consecutive rows: its product is broadcast, not repeated.
        // The folded feature bias joins it there, on one row per ray rather than per sample.
        let mut common = encoded_dirs.matmul(weight.narrow(0, self.spec.width, dir_width));
        if let Some(bias) = &feature.bias {
            common = common + bias.val().unsqueeze::<2>().matmul(feature_rows);
        }
        let sum = if group == 1 {
            own + common
        } else {
            (own.reshape([groups, group, out_dim]) + common.reshape([groups, 1, out_dim])).reshape([n, out_dim])
        };
        add_bias(view, sum)
    }

    /// The weights as plain data (for the ONNX compiler and checks).
    pub fn to_plain(&self) -> PlainNetwork {
        let names = self.spec.layer_shapes();
        let layers = self
            .trunk
            .iter()
            .chain(&self.heads)
            .zip(names)
            .map(|(l, (name, in_dim, out_dim))| DenseLayer {
                name,
                in_dim,
                out_dim,
                weight: l.weight.val().into_data().try_to_vec::<f32>().expect("f32 weights"),
                bias: l.bias.as_ref().map(|b| b.val().into_data().try_to_vec::<f32>().expect("f32 bias")).unwrap_or_else(|| vec![0.0; out_dim]),
            })
            .collect();
        PlainNetwork { spec: self.spec.clone(), layers }
    }

    /// A network holding the given plain weights (validated first).
    pub fn from_plain(plain: &PlainNetwork, device: &Device) -> crate::error::Result<Self> {
        plain.validate().map_err(crate::error::Error::Network)?;
        let mut layers: Vec<Linear> = plain
            .layers
            .iter()
            .map(|l| Linear {
                weight: Param::from_tensor(Tensor::from_data(TensorData::new(l.weight.clone(), [l.in_dim, l.out_dim]), device)),
                bias: Some(Param::from_tensor(Tensor::from_data(TensorData::new(l.bias.clone(), [l.out_dim]), device))),
            })
            .collect();
        let heads = layers.split_off(plain.spec.depth);
        Ok(NerfMlp { trunk: layers, heads, spec: plain.spec.clone() })
    }
}

/// `layer` applied to the concatenation of `inputs` along the feature axis, without building it.
fn dense(layer: &Linear, inputs: &[Tensor<2>]) -> Tensor<2> {
    let weight = layer.weight.val();
    let mut row = 0;
    let mut out: Option<Tensor<2>> = None;
    for input in inputs {
        let width = input.dims()[1];
        let part = input.clone().matmul(weight.clone().narrow(0, row, width));
        row += width;
        out = Some(match out {
            Some(sum) => sum + part,
            None => part,
        });
    }
    add_bias(layer, out.expect("at least one input"))
}

fn add_bias(layer: &Linear, x: Tensor<2>) -> Tensor<2> {
    match &layer.bias {
        Some(bias) => x + bias.val().unsqueeze::<2>(),
        None => x,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::field::mlp::EncodingSpec;

    fn small_spec(use_viewdirs: bool) -> NetworkSpec {
        NetworkSpec {
            depth: 4,
            width: 32,
            skips: vec![1],
            position_encoding: EncodingSpec { n_frequencies: 6, include_input: true },
            direction_encoding: EncodingSpec { n_frequencies: 2, include_input: true },
            use_viewdirs,
        }
    }

    #[test]
    fn burn_forward_matches_the_plain_reference() {
        let device = crate::backend::cpu();
        device.seed(3);
        for use_viewdirs in [true, false] {
            let net = NerfMlp::new(&small_spec(use_viewdirs), &device);
            let plain = net.to_plain();
            plain.validate().unwrap();
            let mut rng = nerf_core::Rng::new(5);
            let pts: Vec<[f32; 3]> = (0..50).map(|_| [0; 3].map(|_: i32| rng.uniform() * 4.0 - 2.0)).collect();
            let dirs: Vec<[f32; 3]> = pts.iter().map(|p| {
                let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                p.map(|v| v / n)
            }).collect();
            let to_tensor = |v: &[[f32; 3]]| Tensor::<2>::from_data(TensorData::new(v.concat(), [v.len(), 3]), &device);
            let (rgb, sigma) = net.forward(to_tensor(&pts), to_tensor(&dirs));
            let rgb = rgb.into_data().try_to_vec::<f32>().unwrap();
            let sigma = sigma.into_data().try_to_vec::<f32>().unwrap();
            for k in 0..pts.len() {
                let want = plain.forward(pts[k], dirs[k]);
                assert!((want.raw_sigma - sigma[k]).abs() < 1e-4, "σ {k}: {} vs {}", want.raw_sigma, sigma[k]);
                for c in 0..3 {
                    assert!((want.rgb[c] - rgb[3 * k + c]).abs() < 1e-5);
                }
            }
            // And back: a network built from the plain weights gives the same plain weights.
            let again = NerfMlp::from_plain(&plain, &device).unwrap();
            assert_eq!(again.to_plain(), plain);
        }
    }

    #[test]
    fn shared_direction_rows_give_the_same_outputs_and_gradients() {
        let device = crate::backend::cpu_autodiff();
        device.seed(11);
        let spec = small_spec(true);
        let net = NerfMlp::new(&spec, &device);
        let (rays, per_ray) = (5, 4);
        let mut rng = nerf_core::Rng::new(2);
        let points: Vec<[f32; 3]> = (0..rays * per_ray).map(|_| [0; 3].map(|_: i32| rng.uniform() * 2.0 - 1.0)).collect();
        let dirs: Vec<[f32; 3]> = (0..rays).map(|r| [0.6, 0.0, 0.8].map(|v| v * if r % 2 == 0 { 1.0 } else { -1.0 })).collect();
        let repeated: Vec<[f32; 3]> = dirs.iter().flat_map(|d| std::iter::repeat_n(*d, per_ray)).collect();
        let tensor = |values: Vec<f32>, rows: usize, cols: usize| Tensor::<2>::from_data(TensorData::new(values, [rows, cols]), &device);
        let x = tensor(spec.position_encoding.encode_all(&points), points.len(), spec.position_encoding.output_dim());
        let d_dim = spec.direction_encoding.output_dim();
        let run = |d: Tensor<2>, group: usize| {
            let (rgb, sigma) = net.forward_encoded(x.clone(), d, group);
            // A loss that depends on every output, differently per row.
            let loss = (rgb.clone() * rgb.clone()).sum() + sigma.clone().sin().sum();
            let grads = loss.backward();
            let view_grad = net.heads[2].weight.grad(&grads).unwrap().into_data().try_to_vec::<f32>().unwrap();
            let first_grad = net.trunk[0].weight.grad(&grads).unwrap().into_data().try_to_vec::<f32>().unwrap();
            (rgb.into_data().try_to_vec::<f32>().unwrap(), view_grad, first_grad)
        };
        let shared = run(tensor(spec.direction_encoding.encode_all(&dirs), rays, d_dim), per_ray);
        let full = run(tensor(spec.direction_encoding.encode_all(&repeated), rays * per_ray, d_dim), 1);
        for (a, b) in [(&shared.0, &full.0), (&shared.1, &full.1), (&shared.2, &full.2)] {
            assert_eq!(a.len(), b.len());
            for (p, q) in a.iter().zip(b.iter()) {
                assert!((p - q).abs() < 1e-5, "{p} vs {q}");
            }
        }
        // The view layer's gradient really depends on the direction part.
        assert!(shared.1.iter().any(|g| g.abs() > 1e-6));
    }
}
