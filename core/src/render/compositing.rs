//! Volume rendering: from densities and colours at samples to a pixel.
//!
//! Small functions named for what they produce, chained by [`composite`]. These are the
//! reference `raw2outputs` maths; the burn trainer has a differentiable twin that is tested
//! against these.

use crate::camera::length;
use crate::sample::stratified::DenseSamples;
use rayon::prelude::*;

/// The δ added after the last sample: the reference treats the last interval as infinite.
pub const LAST_DELTA: f32 = 1e10;
/// Added to 1 − α in the transmittance product, as in the reference.
pub const TRANSMITTANCE_EPS: f32 = 1e-10;

/// Interval lengths along one ray: `t[k+1] − t[k]`, then [`LAST_DELTA`], all scaled by ‖d‖ so
/// that they are world distances for an unnormalised direction.
///
/// Example: `t = [2, 3, 5]`, ‖d‖ = 2 → `[2, 4, 2e10]`.
pub fn deltas(t: &[f32], direction_norm: f32, out: &mut Vec<f32>) {
    out.clear();
    out.extend(t.windows(2).map(|w| (w[1] - w[0]) * direction_norm));
    if !t.is_empty() {
        out.push(LAST_DELTA * direction_norm);
    }
}

/// Opacity of an interval: α = 1 − exp(−relu(σ)·δ). Example: σ = ln 2, δ = 1 → α = 0.5.
pub fn alpha_from_density(sigma: f32, delta: f32) -> f32 {
    1.0 - (-sigma.max(0.0) * delta).exp()
}

/// Front-to-back compositing of one ray, one sample at a time: the single home of the
/// transmittance product. Each sample of opacity αₖ gets the weight wₖ = αₖ·Tₖ, with the
/// exclusive product Tₖ = Πⱼ₍ⱼ<ₖ₎ (1 − αⱼ + 1e-10) as in the reference, and adds wₖ·colour,
/// wₖ·t and wₖ to the ray's colour, depth and opacity. The dense renderer, the marching
/// renderers and [`composite`] all composite through it.
///
/// Example: α = [0.1, 0.3, 0.5, 0.2] → weights [0.1, 0.27, 0.315, 0.063], acc 0.748.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayAccumulator {
    out: RayOutput,
    transmittance: f32,
}

impl Default for RayAccumulator {
    fn default() -> Self {
        RayAccumulator { out: RayOutput::default(), transmittance: 1.0 }
    }
}

impl RayAccumulator {
    /// Add the next sample (opacity `alpha`, colour `rgb`, distance `t`); returns its weight.
    pub fn add(&mut self, alpha: f32, rgb: [f32; 3], t: f32) -> f32 {
        let w = alpha * self.transmittance;
        for (out, c) in self.out.rgb.iter_mut().zip(rgb) {
            *out += w * c;
        }
        self.out.depth += w * t;
        self.out.acc += w;
        self.transmittance *= 1.0 - alpha + TRANSMITTANCE_EPS;
        w
    }

    /// The light left for the samples still to come (1 before the first).
    pub fn transmittance(&self) -> f32 {
        self.transmittance
    }

    /// The ray's colour, depth and opacity, over white when asked ([`over_white`]).
    pub fn finish(self, white_background: bool) -> RayOutput {
        let mut out = self.out;
        if white_background {
            out.rgb = over_white(out.rgb, out.acc);
        }
        out
    }
}

/// Weights from opacities (the weights [`RayAccumulator`] gives).
///
/// Example: α = [0.1, 0.3, 0.5, 0.2] → T = [1, 0.9, 0.63, 0.315] → w = [0.1, 0.27, 0.315, 0.063].
pub fn weights_from_alpha(alphas: &[f32], out: &mut Vec<f32>) {
    let mut ray = RayAccumulator::default();
    out.clear();
    out.extend(alphas.iter().map(|&a| ray.add(a, [0.0; 3], 0.0)));
}

/// The white-background rule: a pixel's colour plus the light that passed through, `rgb + (1 − acc)`.
/// Example: rgb 0.3 with acc 0.6 → 0.7.
pub fn over_white(rgb: [f32; 3], acc: f32) -> [f32; 3] {
    rgb.map(|c| c + (1.0 - acc))
}

/// One ray's rendering.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RayOutput {
    /// Composited colour (background applied if asked).
    pub rgb: [f32; 3],
    /// Expected distance Σ wₖ tₖ.
    pub depth: f32,
    /// Accumulated opacity Σ wₖ.
    pub acc: f32,
}

/// Composite one ray: `t`, `sigma` `[n]`, `rgb` `[n]` of 3, writing the weights into `weights`.
pub fn composite_ray(
    t: &[f32],
    sigma: &[f32],
    rgb: &[[f32; 3]],
    direction_norm: f32,
    white_background: bool,
    scratch: &mut Vec<f32>,
    weights: &mut Vec<f32>,
) -> RayOutput {
    deltas(t, direction_norm, scratch);
    let mut ray = RayAccumulator::default();
    weights.clear();
    for (((&delta, &s), c), &tk) in scratch.iter().zip(sigma).zip(rgb).zip(t) {
        weights.push(ray.add(alpha_from_density(s, delta), *c, tk));
    }
    ray.finish(white_background)
}

/// A composited batch.
///
/// # Shapes
/// `rays`: `[n_rays]`; `weights`: `[n_rays, n_samples]` (the input to `sample_pdf`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Composited {
    /// Per-ray colour, depth and opacity.
    pub rays: Vec<RayOutput>,
    /// Per-sample weights.
    pub weights: Vec<f32>,
}

/// Composite a batch of rays in parallel.
///
/// # Shapes
/// `samples.t`, `sigma`: `[n_rays, n_samples]`; `rgb`: `[n_rays · n_samples]` of 3;
/// `directions`: `[n_rays]` (unnormalised, for ‖d‖).
pub fn composite(
    samples: &DenseSamples,
    sigma: &[f32],
    rgb: &[[f32; 3]],
    directions: &[[f32; 3]],
    white_background: bool,
) -> Composited {
    let n = samples.n_samples;
    assert_eq!(sigma.len(), samples.t.len());
    assert_eq!(rgb.len(), samples.t.len());
    let mut weights = vec![0.0f32; samples.t.len()];
    let rays: Vec<RayOutput> = weights
        .par_chunks_mut(n.max(1))
        .enumerate()
        .map_init(
            || (Vec::with_capacity(n), Vec::with_capacity(n)),
            |(scratch, w), (r, out_w)| {
                let norm = length(directions[r]);
                let range = r * n..(r + 1) * n;
                let out = composite_ray(
                    samples.ray(r),
                    &sigma[range.clone()],
                    &rgb[range],
                    norm,
                    white_background,
                    scratch,
                    w,
                );
                out_w.copy_from_slice(w);
                out
            },
        )
        .collect();
    Composited { rays, weights }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn four_sample_weights() {
        let mut w = Vec::new();
        weights_from_alpha(&[0.1, 0.3, 0.5, 0.2], &mut w);
        for (a, b) in w.iter().zip([0.1, 0.27, 0.315, 0.063]) {
            assert!((a - b).abs() < 1e-6, "{w:?}");
        }
    }

    #[test]
    fn accumulator_composites_front_to_back() {
        let mut ray = RayAccumulator::default();
        let w: Vec<f32> = [(0.1, 2.0), (0.3, 3.0), (0.5, 4.0), (0.2, 5.0)].iter().map(|&(a, t)| ray.add(a, [1.0, 0.0, 0.5], t)).collect();
        for (a, b) in w.iter().zip([0.1, 0.27, 0.315, 0.063]) {
            assert!((a - b).abs() < 1e-6, "{w:?}");
        }
        assert!((ray.transmittance() - 0.252).abs() < 1e-6, "0.9 · 0.7 · 0.5 · 0.8");
        let out = ray.finish(false);
        assert!((out.acc - 0.748).abs() < 1e-6 && (out.rgb[0] - 0.748).abs() < 1e-6 && (out.rgb[2] - 0.374).abs() < 1e-6);
        // depth = 0.2 + 0.81 + 1.26 + 0.315
        assert!((out.depth - 2.585).abs() < 1e-5, "{out:?}");
        let white = ray.finish(true);
        assert!((white.rgb[1] - 0.252).abs() < 1e-6, "{white:?}");
    }

    #[test]
    fn deltas_alpha_and_background() {
        let mut d = Vec::new();
        deltas(&[2.0, 3.0, 5.0], 2.0, &mut d);
        assert_eq!(d, vec![2.0, 4.0, 2e10]);
        assert!((alpha_from_density(2f32.ln(), 1.0) - 0.5).abs() < 1e-6);
        assert_eq!(alpha_from_density(-3.0, 1.0), 0.0, "negative density is clamped");
        let white = over_white([0.3, 0.0, 1.0], 0.6);
        for (a, b) in white.iter().zip([0.7, 0.4, 1.4]) {
            assert!((a - b).abs() < 1e-6, "{white:?}");
        }
    }

    #[test]
    fn composite_matches_hand_computation() {
        // Two rays of 4 samples with α = [0.1, 0.3, 0.5, 0.2] from σ = −ln(1−α)/δ, δ = 1 (t step
        // 1, ‖d‖ = 1), the last sample's α chosen through its huge δ: σ₃·1e10 → α₃ = 1.
        let t = vec![2.0, 3.0, 4.0, 5.0];
        let alphas = [0.1f32, 0.3, 0.5];
        let mut sigma: Vec<f32> = alphas.iter().map(|a| -(1.0 - a).ln()).collect();
        sigma.push(0.0);
        let samples = DenseSamples { n_rays: 1, n_samples: 4, t };
        let rgb = vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]];
        let out = composite(&samples, &sigma, &rgb, &[[0.0, 0.0, -1.0]], false);
        let r = out.rays[0];
        // w = [0.1, 0.27, 0.315, 0]; acc 0.685; depth 0.2 + 0.81 + 1.26 = 2.27.
        assert!((r.acc - 0.685).abs() < 1e-5, "{r:?}");
        assert!((r.depth - 2.27).abs() < 1e-5, "{r:?}");
        assert!((r.rgb[0] - 0.1).abs() < 1e-5 && (r.rgb[1] - 0.27).abs() < 1e-5);
        let white = composite(&samples, &sigma, &rgb, &[[0.0, 0.0, -1.0]], true);
        assert!((white.rays[0].rgb[2] - (0.315 + 0.315)).abs() < 1e-5);
        // ‖d‖ = 2 doubles every δ: α₀ = 1 − 0.9² = 0.19.
        let long = composite(&samples, &sigma, &rgb, &[[0.0, 0.0, -2.0]], false);
        assert!((long.weights[0] - 0.19).abs() < 1e-5);
    }
}
