//! Differentiable volume rendering for training: the burn twin of
//! [`nerf_core::render::compositing`], tested against it.
//!
//! The transmittance is computed as exp(exclusive cumsum(log(1 − α + 1e-10))), which is the
//! reference's exclusive cumulative product written so its gradient needs no division.

use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::render::compositing::{TRANSMITTANCE_EPS, deltas};
use nerf_core::sample::stratified::DenseSamples;

/// Rendered rays with gradients.
///
/// # Shapes
/// `rgb`: `[n_rays, 3]`; `weights`: `[n_rays, n_samples]`; `acc`: `[n_rays]`.
#[derive(Debug, Clone)]
pub struct VolumeOutput {
    /// Composited colour (background applied if asked).
    pub rgb: Tensor<2>,
    /// Per-sample weights.
    pub weights: Tensor<2>,
    /// Accumulated opacity.
    pub acc: Tensor<1>,
}

/// The interval lengths of `samples` (scaled by ‖d‖, last = 1e10·‖d‖) as a `[n_rays, n_samples]` tensor.
pub fn deltas_tensor(samples: &DenseSamples, directions: &[[f32; 3]], device: &Device) -> Tensor<2> {
    let mut all = Vec::with_capacity(samples.t.len());
    let mut ray = Vec::with_capacity(samples.n_samples);
    for (r, d) in directions.iter().enumerate() {
        let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        deltas(samples.ray(r), norm, &mut ray);
        all.extend_from_slice(&ray);
    }
    Tensor::from_data(TensorData::new(all, [samples.n_rays, samples.n_samples]), device)
}

/// Composite densities and colours along rays.
///
/// # Shapes
/// `raw_sigma`, `deltas`: `[n_rays, n_samples]`; `rgb`: `[n_rays, n_samples, 3]`.
pub fn composite(raw_sigma: Tensor<2>, rgb: Tensor<3>, deltas: Tensor<2>, white_background: bool) -> VolumeOutput {
    let [n_rays, n_samples] = raw_sigma.dims();
    let optical_depth = relu(raw_sigma) * deltas;
    let alpha = optical_depth.clone().neg().exp().neg().add_scalar(1.0);
    // (1 − α) first, then + 1e-10: in f32, 1 + 1e-10 == 1, so the order matters when α = 1.
    let log_step = alpha.clone().neg().add_scalar(1.0).add_scalar(TRANSMITTANCE_EPS).log();
    let transmittance = (log_step.clone().cumsum(1) - log_step).exp();
    let weights = alpha * transmittance;
    let rgb_map = (weights.clone().reshape([n_rays, n_samples, 1]) * rgb).sum_dim(1).reshape([n_rays, 3]);
    let acc = weights.clone().sum_dim(1);
    let rgb_map = if white_background { rgb_map + acc.clone().neg().add_scalar(1.0) } else { rgb_map };
    VolumeOutput { rgb: rgb_map, weights, acc: acc.reshape([n_rays]) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::Rng;
    use nerf_core::render::compositing;

    #[test]
    fn matches_the_core_compositing_and_the_four_sample_example() {
        let device = crate::backend::cpu();
        let mut rng = Rng::new(11);
        let (n_rays, n) = (7, 12);
        let cfg = nerf_core::SamplingConfig { n_coarse: n, ..Default::default() };
        let samples = nerf_core::sample::stratified::stratified(&cfg, n_rays, Some(&mut rng));
        let dirs: Vec<[f32; 3]> = (0..n_rays).map(|_| [rng.uniform() - 0.5, rng.uniform() - 0.5, -1.0]).collect();
        let sigma: Vec<f32> = (0..n_rays * n).map(|_| rng.uniform() * 6.0 - 1.0).collect();
        let rgb: Vec<[f32; 3]> = (0..n_rays * n).map(|_| [rng.uniform(), rng.uniform(), rng.uniform()]).collect();
        for white in [false, true] {
            let want = compositing::composite(&samples, &sigma, &rgb, &dirs, white);
            let out = composite(
                Tensor::from_data(TensorData::new(sigma.clone(), [n_rays, n]), &device),
                Tensor::from_data(TensorData::new(rgb.concat(), [n_rays, n, 3]), &device),
                deltas_tensor(&samples, &dirs, &device),
                white,
            );
            let got_rgb = out.rgb.into_data().try_to_vec::<f32>().unwrap();
            let got_w = out.weights.into_data().try_to_vec::<f32>().unwrap();
            let got_acc = out.acc.into_data().try_to_vec::<f32>().unwrap();
            for (a, b) in got_w.iter().zip(&want.weights) {
                assert!((a - b).abs() < 1e-5, "weight {a} vs {b}");
            }
            for (r, ray) in want.rays.iter().enumerate() {
                assert!((got_acc[r] - ray.acc).abs() < 1e-5);
                for c in 0..3 {
                    assert!((got_rgb[3 * r + c] - ray.rgb[c]).abs() < 1e-5);
                }
            }
        }
        // α = [0.1, 0.3, 0.5, 0.2] via σ = −ln(1 − α), δ = 1 → weights [0.1, 0.27, 0.315, 0.063].
        let sigma: Vec<f32> = [0.1f32, 0.3, 0.5, 0.2].iter().map(|a| -(1.0 - a).ln()).collect();
        let out = composite(
            Tensor::from_data(TensorData::new(sigma, [1, 4]), &device),
            Tensor::zeros([1, 4, 3], &device),
            Tensor::ones([1, 4], &device),
            false,
        );
        let w = out.weights.into_data().try_to_vec::<f32>().unwrap();
        for (a, b) in w.iter().zip([0.1, 0.27, 0.315, 0.063]) {
            assert!((a - b).abs() < 1e-6, "{w:?}");
        }
    }
}
