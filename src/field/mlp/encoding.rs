//! Positional encoding as burn tensor ops (same layout as [`nerf_core::field::mlp::EncodingSpec`]).

use burn::tensor::Tensor;
use nerf_core::field::mlp::EncodingSpec;

/// `[x, sin(2⁰x), cos(2⁰x), …]` along the last axis.
///
/// # Shapes
/// `x`: `[n, 3]` → `[n, spec.output_dim()]`.
pub fn encode(spec: &EncodingSpec, x: Tensor<2>) -> Tensor<2> {
    let mut parts = Vec::with_capacity(1 + 2 * spec.n_frequencies);
    if spec.include_input {
        parts.push(x.clone());
    }
    for f in spec.frequencies() {
        let scaled = x.clone().mul_scalar(f);
        parts.push(scaled.clone().sin());
        parts.push(scaled.cos());
    }
    Tensor::cat(parts, 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::TensorData;

    #[test]
    fn matches_the_core_encoding() {
        let device = crate::backend::cpu();
        let spec = EncodingSpec { n_frequencies: 10, include_input: true };
        let points = [[0.3f32, -1.2, 2.5], [0.0, 0.7, -0.1]];
        let x = Tensor::<2>::from_data(TensorData::new(points.concat(), [2, 3]), &device);
        let got = encode(&spec, x).into_data().try_to_vec::<f32>().unwrap();
        assert_eq!(got.len(), 2 * 63);
        let mut want = Vec::new();
        for p in points {
            spec.encode(p, &mut want);
        }
        for (a, b) in got.iter().zip(&want) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
    }
}
