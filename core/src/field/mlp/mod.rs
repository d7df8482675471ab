//! The NeRF MLP as plain data: its shape ([`NetworkSpec`]) and weights ([`PlainNetwork`]).
//!
//! This is what leaves the trainer for the ONNX compiler and the checks, so neither needs burn.
//! [`PlainNetwork::forward`] is a slow, obviously-correct reference evaluation used as the
//! oracle in parity tests.

use super::layer::DenseLayer;
use serde::{Deserialize, Serialize};

/// Positional encoding `[x, sin(2⁰x), cos(2⁰x), …, sin(2^(L−1)x), cos(2^(L−1)x)]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EncodingSpec {
    /// Number of frequencies L (2⁰ … 2^(L−1)).
    pub n_frequencies: usize,
    /// Whether the raw input is concatenated first.
    pub include_input: bool,
}

impl EncodingSpec {
    /// Output width for a 3-vector input: 3·(include_input) + 3·2·L (L=10 → 63, L=4 → 27).
    pub fn output_dim(&self) -> usize {
        3 * usize::from(self.include_input) + 6 * self.n_frequencies
    }

    /// The frequencies 2ᵏ, k < L.
    pub fn frequencies(&self) -> Vec<f32> {
        (0..self.n_frequencies).map(|k| (1u64 << k) as f32).collect()
    }

    /// Encode one 3-vector, appending [`output_dim`](Self::output_dim) values to `out`.
    pub fn encode(&self, x: [f32; 3], out: &mut Vec<f32>) {
        if self.include_input {
            out.extend_from_slice(&x);
        }
        for k in 0..self.n_frequencies {
            let f = (1u64 << k) as f32;
            out.extend(x.iter().map(|v| (v * f).sin()));
            out.extend(x.iter().map(|v| (v * f).cos()));
        }
    }

    /// Encode many 3-vectors (in parallel) into one row-major `[xs.len(), output_dim]` buffer.
    pub fn encode_all(&self, xs: &[[f32; 3]]) -> Vec<f32> {
        use rayon::prelude::*;
        let dim = self.output_dim();
        let mut out = vec![0.0; xs.len() * dim];
        out.par_chunks_mut(dim * 1024).zip(xs.par_chunks(1024)).for_each(|(rows, points)| {
            let mut row = Vec::with_capacity(dim);
            for (dst, &x) in rows.chunks_exact_mut(dim).zip(points) {
                row.clear();
                self.encode(x, &mut row);
                dst.copy_from_slice(&row);
            }
        });
        out
    }
}

/// The shape of a NeRF MLP (nerf-pytorch's `NeRF(D, W, skips, input_ch, input_ch_views, use_viewdirs)`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetworkSpec {
    /// Number of ReLU layers on the encoded position (D).
    pub depth: usize,
    /// Width of those layers (W).
    pub width: usize,
    /// After layer `i` (0-based) of these, the encoded input is concatenated back (`[input, h]`).
    pub skips: Vec<usize>,
    /// Encoding of positions.
    pub position_encoding: EncodingSpec,
    /// Encoding of view directions.
    pub direction_encoding: EncodingSpec,
    /// Whether colour depends on the view direction (σ head + feature + one W/2 layer).
    pub use_viewdirs: bool,
}

impl NetworkSpec {
    /// The paper network: 8 × 256, skip after the 5th layer, L = 10 / 4, view-dependent colour.
    pub fn paper() -> Self {
        NetworkSpec {
            depth: 8,
            width: 256,
            skips: vec![4],
            position_encoding: EncodingSpec { n_frequencies: 10, include_input: true },
            direction_encoding: EncodingSpec { n_frequencies: 4, include_input: true },
            use_viewdirs: true,
        }
    }

    /// Input width of trunk layer `i`.
    pub fn trunk_input_dim(&self, i: usize) -> usize {
        let x = self.position_encoding.output_dim();
        match i {
            0 => x,
            _ if self.skips.contains(&(i - 1)) => self.width + x,
            _ => self.width,
        }
    }

    /// Every dense layer as (name, input width, output width), in evaluation order.
    pub fn layer_shapes(&self) -> Vec<(String, usize, usize)> {
        let w = self.width;
        let mut layers: Vec<(String, usize, usize)> =
            (0..self.depth).map(|i| (format!("trunk.{i}"), self.trunk_input_dim(i), w)).collect();
        if self.use_viewdirs {
            layers.push(("sigma".into(), w, 1));
            layers.push(("feature".into(), w, w));
            layers.push(("view".into(), w + self.direction_encoding.output_dim(), w / 2));
            layers.push(("rgb".into(), w / 2, 3));
        } else {
            layers.push(("output".into(), w, 4));
        }
        layers
    }

    /// Multiply-adds per evaluated point (for FLOP counts: 2 FLOPs each).
    pub fn macs_per_point(&self) -> usize {
        self.layer_shapes().iter().map(|(_, i, o)| i * o).sum()
    }

    /// Checks sizes that would make a network that cannot be built, before anything is
    /// allocated for it: a description read from a file may say anything.
    pub fn validate(&self) -> Result<(), String> {
        use crate::io::limits::{MAX_FREQUENCIES, MAX_NETWORK_DEPTH, MAX_NETWORK_WEIGHTS, MAX_NETWORK_WIDTH};
        if self.depth == 0 || self.width < 2 {
            return Err(format!("network depth {} and width {} must be ≥ 1 and ≥ 2", self.depth, self.width));
        }
        if self.depth > MAX_NETWORK_DEPTH || self.width > MAX_NETWORK_WIDTH {
            return Err(format!(
                "network depth {} and width {}: the limits are {MAX_NETWORK_DEPTH} layers of {MAX_NETWORK_WIDTH}",
                self.depth, self.width
            ));
        }
        for (name, e) in [("position_encoding", &self.position_encoding), ("direction_encoding", &self.direction_encoding)] {
            if e.n_frequencies > MAX_FREQUENCIES {
                return Err(format!("network {name}: {} frequencies is more than the limit of {MAX_FREQUENCIES}", e.n_frequencies));
            }
        }
        // Bounded depth, width and encodings keep this sum from overflowing.
        let weights = self.macs_per_point();
        if weights > MAX_NETWORK_WEIGHTS {
            return Err(format!("the network has {weights} weights, more than the limit of {MAX_NETWORK_WEIGHTS}"));
        }
        if let Some(s) = self.skips.iter().find(|&&s| s + 1 >= self.depth) {
            return Err(format!("skip after layer {s} needs a later layer (depth {})", self.depth));
        }
        Ok(())
    }
}

/// A network's shape and weights as plain data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlainNetwork {
    /// The shape.
    pub spec: NetworkSpec,
    /// The layers, in [`NetworkSpec::layer_shapes`] order.
    pub layers: Vec<DenseLayer>,
}

/// The NeRF MLPs of a trained field as plain data.
#[derive(Debug, Clone, PartialEq)]
pub struct PlainMlp {
    /// The coarse network (stratified samples).
    pub coarse: PlainNetwork,
    /// The fine network (coarse ∪ importance samples), if any.
    pub fine: Option<PlainNetwork>,
}

impl Default for NetworkSpec {
    /// The paper network.
    fn default() -> Self {
        NetworkSpec::paper()
    }
}

impl crate::field::KindShape for NetworkSpec {
    fn check(&self) -> Result<(), String> {
        self.validate()
    }

    fn field_box(&self) -> Option<crate::field::ngp::hash_grid::GridBound> {
        None
    }
}

/// What a NeRF network says about one point: sigmoid colour and raw density (ReLU is applied by
/// the compositing, so the raw value is kept here).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldSample {
    /// Colour in [0, 1].
    pub rgb: [f32; 3],
    /// Density before ReLU.
    pub raw_sigma: f32,
}

impl PlainNetwork {
    /// Seeded PyTorch-style initial weights (uniform ±1/√fan_in), for tests and benchmarks.
    pub fn seeded(spec: &NetworkSpec, seed: u64) -> Self {
        let mut rng = crate::rng::Rng::new(seed);
        let layers = spec
            .layer_shapes()
            .into_iter()
            .map(|(name, in_dim, out_dim)| {
                let bound = (in_dim as f32).powf(-0.5);
                let mut uniform = |n: usize| (0..n).map(|_| (rng.uniform() * 2.0 - 1.0) * bound).collect::<Vec<f32>>();
                DenseLayer { weight: uniform(in_dim * out_dim), bias: uniform(out_dim), name, in_dim, out_dim }
            })
            .collect();
        PlainNetwork { spec: spec.clone(), layers }
    }

    /// Checks that the layers match the spec's shapes.
    pub fn validate(&self) -> Result<(), String> {
        self.spec.validate()?;
        let shapes = self.spec.layer_shapes();
        if shapes.len() != self.layers.len() {
            return Err(format!("expected {} layers, found {}", shapes.len(), self.layers.len()));
        }
        for ((name, i, o), l) in shapes.iter().zip(&self.layers) {
            if &l.name != name || l.in_dim != *i || l.out_dim != *o || l.weight.len() != i * o || l.bias.len() != *o {
                return Err(format!(
                    "layer {} ({}×{}, {} weights, {} biases) does not match {name} ({i}×{o})",
                    l.name, l.in_dim, l.out_dim, l.weight.len(), l.bias.len()
                ));
            }
        }
        Ok(())
    }

    /// Reference evaluation of one point with its unit view direction.
    pub fn forward(&self, point: [f32; 3], viewdir: [f32; 3]) -> FieldSample {
        let spec = &self.spec;
        let mut x = Vec::new();
        spec.position_encoding.encode(point, &mut x);
        let mut h = x.clone();
        for i in 0..spec.depth {
            h = self.layers[i].apply(&h, true);
            if spec.skips.contains(&i) {
                let mut cat = x.clone();
                cat.extend_from_slice(&h);
                h = cat;
            }
        }
        let sigmoid = |v: f32| 1.0 / (1.0 + (-v).exp());
        let heads = &self.layers[spec.depth..];
        if spec.use_viewdirs {
            let raw_sigma = heads[0].apply(&h, false)[0];
            let mut f = heads[1].apply(&h, false);
            spec.direction_encoding.encode(viewdir, &mut f);
            let v = heads[2].apply(&f, true);
            let c = heads[3].apply(&v, false);
            FieldSample { rgb: [sigmoid(c[0]), sigmoid(c[1]), sigmoid(c[2])], raw_sigma }
        } else {
            let o = heads[0].apply(&h, false);
            FieldSample { rgb: [sigmoid(o[0]), sigmoid(o[1]), sigmoid(o[2])], raw_sigma: o[3] }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encoding_dims_and_values() {
        let pos = EncodingSpec { n_frequencies: 10, include_input: true };
        let dir = EncodingSpec { n_frequencies: 4, include_input: true };
        assert_eq!(pos.output_dim(), 63);
        assert_eq!(dir.output_dim(), 27);
        let mut out = Vec::new();
        let two = EncodingSpec { n_frequencies: 2, include_input: true };
        two.encode([0.5, -1.0, 0.0], &mut out);
        assert_eq!(out.len(), 15);
        assert_eq!(&out[..3], &[0.5, -1.0, 0.0]);
        // k = 0: sin(x), cos(x); k = 1: sin(2x), cos(2x).
        let expect = [
            0.5f32.sin(), (-1.0f32).sin(), 0.0,
            0.5f32.cos(), (-1.0f32).cos(), 1.0,
            1.0f32.sin(), (-2.0f32).sin(), 0.0,
            1.0f32.cos(), (-2.0f32).cos(), 1.0,
        ];
        for (a, b) in out[3..].iter().zip(expect) {
            assert!((a - b).abs() < 1e-6, "{out:?}");
        }
    }

    #[test]
    fn batch_encoding_equals_one_at_a_time() {
        let spec = EncodingSpec { n_frequencies: 3, include_input: false };
        // More than one parallel chunk, and a ragged last one.
        let xs: Vec<[f32; 3]> = (0..2500).map(|i| [i as f32 * 0.01, -(i as f32) * 0.002, 1.5]).collect();
        let all = spec.encode_all(&xs);
        assert_eq!(all.len(), xs.len() * 18);
        let mut one = Vec::new();
        spec.encode(xs[2047], &mut one);
        assert_eq!(&all[2047 * 18..2048 * 18], &one[..]);
    }

    #[test]
    fn paper_layer_shapes() {
        let spec = NetworkSpec::paper();
        let shapes = spec.layer_shapes();
        assert_eq!(shapes[0], ("trunk.0".into(), 63, 256));
        assert_eq!(shapes[5], ("trunk.5".into(), 256 + 63, 256), "skip after the 5th layer");
        assert_eq!(shapes[10], ("view".into(), 256 + 27, 128));
        // ≈ 2.4 MB of f32 weights: 593,408 multiply-adds per point.
        assert_eq!(spec.macs_per_point(), 593_408);
        assert!(NetworkSpec { skips: vec![7], ..spec.clone() }.validate().is_err());
        // Sizes read from files stop at the limits (before any weight is allocated).
        let err = NetworkSpec { width: 1 << 20, ..spec.clone() }.validate().unwrap_err();
        assert!(err.contains("width 1048576") && err.contains("4096"), "{err}");
        let err = NetworkSpec { position_encoding: EncodingSpec { n_frequencies: 65, include_input: true }, ..spec }.validate().unwrap_err();
        assert!(err.contains("position_encoding: 65 frequencies"), "{err}");
    }

    #[test]
    fn absurd_sizes_are_rejected_before_allocating() {
        // Found by fuzzing config.toml: depth 2⁵³ passed and `layer_shapes` aborted the process.
        let spec = NetworkSpec::paper();
        let err = NetworkSpec { depth: 1 << 53, ..spec.clone() }.validate().unwrap_err();
        assert!(err.contains("depth 9007199254740992"), "{err}");
        assert!(NetworkSpec { width: usize::MAX, ..spec.clone() }.validate().is_err());
        let many = EncodingSpec { n_frequencies: 1 << 40, include_input: true };
        let err = NetworkSpec { direction_encoding: many, ..spec.clone() }.validate().unwrap_err();
        assert!(err.contains("direction_encoding"), "{err}");
        // Within every per-field limit but 64 × 4096² ≈ 1.1e9 weights in all.
        let err = NetworkSpec { depth: crate::io::limits::MAX_NETWORK_DEPTH, width: crate::io::limits::MAX_NETWORK_WIDTH, ..spec.clone() }
            .validate()
            .unwrap_err();
        assert!(err.contains("weights"), "{err}");
        // The largest sizes in use stay accepted.
        NetworkSpec { depth: 16, width: 1024, ..spec }.validate().unwrap();
    }
}
