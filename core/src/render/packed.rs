//! Packed samples (nerfacc's layout) and the front-to-back evaluator with early ray
//! termination that both the dense and the marching renderers use.

use super::MARCH_SEGMENT;
use crate::field::{Field, Stage};
use crate::camera::{Rays, length, point_at};
use super::compositing::{RayAccumulator, RayOutput, alpha_from_density, deltas};
use crate::sample::stratified::DenseSamples;

/// Samples of a batch of rays, any number per ray, stored flat and ray by ray, front to back.
///
/// # Shapes
/// `t`, `delta`: `[n_samples]`; `offsets`: `[n_rays + 1]`, ray `r`'s samples are
/// `offsets[r]..offsets[r + 1]`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PackedSamples {
    /// Distance along the (unnormalised) ray.
    pub t: Vec<f32>,
    /// The interval each sample stands for, in world units (its α = 1 − exp(−σ·δ)).
    pub delta: Vec<f32>,
    /// Where each ray's samples start, plus the total at the end.
    pub offsets: Vec<usize>,
}

impl PackedSamples {
    /// Every sample of dense `samples`, with the reference δ: the gap to the next sample, the
    /// last one "infinite" ([`deltas`]), times ‖d‖.
    pub fn from_dense(samples: &DenseSamples, directions: &[[f32; 3]]) -> Self {
        let mut packed = PackedSamples { t: samples.t.clone(), delta: Vec::with_capacity(samples.t.len()), offsets: vec![0] };
        let mut ray_deltas = Vec::new();
        for (r, &d) in directions.iter().enumerate().take(samples.n_rays) {
            deltas(samples.ray(r), length(d), &mut ray_deltas);
            packed.delta.extend_from_slice(&ray_deltas);
            packed.offsets.push(packed.delta.len());
        }
        packed
    }

    /// Number of rays.
    pub fn n_rays(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// The sample indices of ray `r`.
    pub fn ray(&self, r: usize) -> std::ops::Range<usize> {
        self.offsets[r]..self.offsets[r + 1]
    }
}

/// What [`march_front_to_back`] returns.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Marched {
    /// Per-ray colour, depth and opacity.
    pub rays: Vec<RayOutput>,
    /// Per-sample weights (0 for samples never evaluated), in the samples' order.
    pub weights: Vec<f32>,
}

/// Evaluate `samples` with `stage`'s network front to back, [`MARCH_SEGMENT`] per ray per field
/// call (all active rays' segments packed into one call), compositing as it goes, and drop a ray
/// once its transmittance is below `min_transmittance`. Samples never evaluated count as σ = 0.
pub fn march_front_to_back<F: Field>(
    field: &mut F,
    stage: Stage,
    rays: &Rays,
    viewdirs: &[[f32; 3]],
    samples: &PackedSamples,
    min_transmittance: f32,
    white_background: bool,
) -> Result<Marched, F::Error> {
    let mut accumulators = vec![RayAccumulator::default(); rays.len()];
    let mut weights = vec![0.0f32; samples.t.len()];
    let mut next: Vec<usize> = samples.offsets[..rays.len()].to_vec();
    let mut active: Vec<usize> = (0..rays.len()).filter(|&r| !samples.ray(r).is_empty()).collect();
    let (mut points, mut dirs, mut index) = (Vec::new(), Vec::new(), Vec::new());
    while !active.is_empty() {
        points.clear();
        dirs.clear();
        index.clear();
        for &r in &active {
            let end = (next[r] + MARCH_SEGMENT).min(samples.offsets[r + 1]);
            for i in next[r]..end {
                points.push(point_at(rays.origins[r], rays.directions[r], samples.t[i]));
                dirs.push(viewdirs[r]);
                index.push(i);
            }
            next[r] = end;
        }
        let part = field.evaluate(stage, &points, &dirs)?;
        let mut j = 0;
        for &r in &active {
            while j < index.len() && index[j] < samples.offsets[r + 1] {
                let i = index[j];
                let alpha = alpha_from_density(part.sigma[j], samples.delta[i]);
                weights[i] = accumulators[r].add(alpha, part.rgb[j], samples.t[i]);
                j += 1;
            }
        }
        active.retain(|&r| accumulators[r].transmittance() >= min_transmittance && next[r] < samples.offsets[r + 1]);
    }
    let rays = accumulators.into_iter().map(|a| a.finish(white_background)).collect();
    Ok(Marched { rays, weights })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::FieldOutput;

    /// σ = 1 everywhere, colour = (t-ish) position x; counts evaluated points.
    struct Uniform(usize);

    impl Field for Uniform {
        type Error = std::convert::Infallible;
        fn evaluate(&mut self, _: Stage, points: &[[f32; 3]], _: &[[f32; 3]]) -> Result<FieldOutput, Self::Error> {
            self.0 += points.len();
            Ok(FieldOutput { rgb: points.iter().map(|p| [p[0], 0.0, 1.0]).collect(), sigma: vec![2f32.ln(); points.len()] })
        }
    }

    #[test]
    fn packed_march_composites_each_ray_and_stops_opaque_ones() {
        // Ray 0 along +x from the origin: 3 samples at t = 1, 2, 3 with δ = 1 (α = 0.5 each).
        // Ray 1: no samples. Ray 2 along +x: 40 samples of δ = 10 (α ≈ 1 − 2⁻¹⁰ each).
        let rays = Rays { origins: vec![[0.0; 3]; 3], directions: vec![[1.0, 0.0, 0.0]; 3], viewdirs: None };
        let mut samples = PackedSamples { t: vec![1.0, 2.0, 3.0], delta: vec![1.0; 3], offsets: vec![0, 3, 3] };
        samples.t.extend((0..40).map(|k| k as f32));
        samples.delta.extend([10.0; 40]);
        samples.offsets.push(43);
        let mut field = Uniform(0);
        let out = march_front_to_back(&mut field, Stage::Fine, &rays, &rays.directions, &samples, 1e-4, false).unwrap();
        // Ray 0: w = 0.5, 0.25, 0.125; rgb.x = 0.5·1 + 0.25·2 + 0.125·3 = 1.375.
        assert_eq!(&out.weights[..3], &[0.5, 0.25, 0.125]);
        assert!((out.rays[0].rgb[0] - 1.375).abs() < 1e-6 && (out.rays[0].acc - 0.875).abs() < 1e-6);
        assert_eq!(out.rays[1], RayOutput::default());
        // Ray 2 is opaque (T ≈ 1e-3 after one sample, 1e-6 after two): one segment only.
        assert_eq!(field.0, 3 + MARCH_SEGMENT);
        assert!(out.weights[3 + MARCH_SEGMENT..].iter().all(|w| *w == 0.0));
        assert!((out.rays[2].acc - 1.0).abs() < 1e-5);
    }

    #[test]
    fn from_dense_uses_the_reference_deltas() {
        let dense = DenseSamples { n_rays: 2, n_samples: 3, t: vec![2.0, 3.0, 5.0, 2.0, 2.5, 3.0] };
        let p = PackedSamples::from_dense(&dense, &[[0.0, 0.0, -2.0], [0.0, 1.0, 0.0]]);
        assert_eq!(p.offsets, vec![0, 3, 6]);
        assert_eq!(p.delta, vec![2.0, 4.0, 2e10, 0.5, 0.5, 1e10]);
        assert_eq!(p.ray(1), 3..6);
    }
}
