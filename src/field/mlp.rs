//! The NeRF MLP (nerf-pytorch's `NeRF`), built from a plain [`NetworkSpec`].

use burn::module::{Module, Param};
use burn::nn::{Linear, LinearConfig};
use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::network::{DenseLayer, NetworkSpec, PlainNetwork};

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

/// The coarse and fine networks trained together (one optimizer, one checkpoint).
#[derive(Module, Debug)]
pub struct NerfModel {
    /// Evaluated on the stratified samples.
    pub coarse: NerfMlp,
    /// Evaluated on all samples; absent when no fine samples are drawn.
    pub fine: Option<NerfMlp>,
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
        let spec = &self.spec;
        let x = encode(&spec.position_encoding, points);
        let mut h = x.clone();
        for (i, layer) in self.trunk.iter().enumerate() {
            h = relu(layer.forward(h));
            if spec.skips.contains(&i) {
                h = Tensor::cat(vec![x.clone(), h], 1);
            }
        }
        let n = h.dims()[0];
        if spec.use_viewdirs {
            let sigma = self.heads[0].forward(h.clone()).reshape([n]);
            let feature = self.heads[1].forward(h);
            let d = encode(&spec.direction_encoding, viewdirs);
            let v = relu(self.heads[2].forward(Tensor::cat(vec![feature, d], 1)));
            (sigmoid(self.heads[3].forward(v)), sigma)
        } else {
            let out = self.heads[0].forward(h);
            let rgb = sigmoid(out.clone().narrow(1, 0, 3));
            (rgb, out.narrow(1, 3, 1).reshape([n]))
        }
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
    pub fn from_plain(plain: &PlainNetwork, device: &Device) -> Result<Self, String> {
        plain.validate()?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::network::EncodingSpec;

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
}
