//! mip-NeRF 360's distortion loss over packed samples, with its gradient: a regulariser that
//! pulls each ray's weight together into as short a stretch as it can, so that density floating
//! in front of a surface (seen by few training rays, hiding it from other views) costs
//! something even where it fits the photos.
//!
//! For one ray with weights wᵢ (as [`composite_packed`](super::packed::composite_packed) makes
//! them) at normalised distances sᵢ, each standing for an interval of the same width h (one
//! marching step): L = Σᵢ Σⱼ wᵢwⱼ|sᵢ − sⱼ| + ⅓ Σᵢ wᵢ²h (Barron et al. 2022, eq. 15, where each
//! interval has a width of its own; nerfacto's and nerfacc's).
//! Samples are front to back, so the double sum is 2 Σᵢ wᵢ (sᵢ·Wᵢ − Pᵢ) with Wᵢ, Pᵢ the sums of
//! wⱼ and wⱼsⱼ over j < i: O(n) a ray. Then ∂L/∂wₖ = 2 Σⱼ wⱼ|sₖ − sⱼ| + ⅔ wₖh, and through
//! wᵢ = Tᵢαᵢ, ∂L/∂σₖ = δₖ·(Tₖ₊₁·∂L/∂wₖ − Σ₍ᵢ>ₖ₎ wᵢ·∂L/∂wᵢ), the same shape as the colour's.
//!
//! Distances are in marching steps ([`step_coordinates`]): uniform steps along the ray in the
//! cube (and in NDC), steps that grow with distance in a contracted world, as mip-NeRF 360
//! measures its s in a space where its samples are evenly spread.

use nerf_core::render::compositing::{alpha_from_density, RayAccumulator};
use nerf_core::render::grid::Segment;
use nerf_core::render::packed::PackedSamples;
use rayon::prelude::*;

/// Each sample's position in marching steps over `segments`, divided by their total number of
/// steps: 0 at the first step's start, 1 at the last one's end (the width of every step is
/// 1 / total). A t before the first segment or past the last is measured with the nearest
/// segment's interval.
pub fn step_coordinates(segments: &[Segment], t: &[f32]) -> Vec<f32> {
    let total: usize = segments.iter().map(|s| s.steps).sum();
    assert!(total > 0, "marching takes at least one step");
    t.iter()
        .map(|&t| {
            let mut before = 0;
            let last = segments.len() - 1;
            for (k, s) in segments.iter().enumerate() {
                if k == last || t < s.start + s.steps as f32 * s.interval {
                    return (before as f32 + (t - s.start) / s.interval) / total as f32;
                }
                before += s.steps;
            }
            unreachable!("the last segment returns")
        })
        .collect()
}

/// Per ray, the distortion loss of the weights that `sigma` gives `samples` (σ ≤ 0 counts as
/// empty, as compositing has it), every sample standing for an interval of `width` (one
/// marching step: 1 / the steps in [`step_coordinates`]).
///
/// # Shapes
/// `sigma`, `s`: `[n_samples]` → `[n_rays]`.
pub fn distortion(samples: &PackedSamples, sigma: &[f32], s: &[f32], width: f32) -> Vec<f32> {
    check_shapes(samples, sigma, s);
    (0..samples.n_rays())
        .into_par_iter()
        .map_init(RayWeights::default, |ray, r| {
            ray.fill(samples, sigma, r);
            let (mut weight_before, mut moment_before) = (0.0f32, 0.0f32);
            samples
                .ray(r)
                .zip(&ray.weights)
                .map(|(i, &w)| {
                    let loss = 2.0 * w * (s[i] * weight_before - moment_before) + w * w * width / 3.0;
                    weight_before += w;
                    moment_before += w * s[i];
                    loss
                })
                .sum()
        })
        .collect()
}

/// The gradient through [`distortion`]: given ∂loss/∂L per ray, ∂loss/∂σ per sample (0 where
/// σ ≤ 0).
///
/// # Shapes
/// `grad_loss`: `[n_rays]` → `[n_samples]`.
pub fn distortion_backward(samples: &PackedSamples, sigma: &[f32], s: &[f32], width: f32, grad_loss: &[f32]) -> Vec<f32> {
    check_shapes(samples, sigma, s);
    assert_eq!(grad_loss.len(), samples.n_rays(), "one loss gradient per ray");
    let per_ray: Vec<Vec<f32>> = (0..samples.n_rays())
        .into_par_iter()
        .map_init(RayWeights::default, |ray, r| {
            ray.fill(samples, sigma, r);
            let range = samples.ray(r);
            let weights = &ray.weights;
            // ∂L/∂wₖ = 2(sₖWₖ − Pₖ + (P_total − Pₖ − wₖsₖ) − sₖ(W_total − Wₖ − wₖ)) + ⅔wₖh.
            let (total_weight, total_moment) = range.clone().zip(weights).fold((0.0f32, 0.0f32), |(a, b), (i, &w)| (a + w, b + w * s[i]));
            let (mut weight_before, mut moment_before) = (0.0f32, 0.0f32);
            let grad_weight: Vec<f32> = range
                .clone()
                .zip(weights)
                .map(|(i, &w)| {
                    let weight_after = total_weight - weight_before - w;
                    let moment_after = total_moment - moment_before - w * s[i];
                    let g = 2.0 * (s[i] * weight_before - moment_before + moment_after - s[i] * weight_after) + 2.0 / 3.0 * w * width;
                    weight_before += w;
                    moment_before += w * s[i];
                    g * grad_loss[r]
                })
                .collect();
            // Σ₍ᵢ>ₖ₎ wᵢ·∂L/∂wᵢ, back to front.
            let mut behind = 0.0f32;
            let mut grad_sigma = vec![0.0f32; range.len()];
            for (k, i) in range.enumerate().rev() {
                if sigma[i] > 0.0 {
                    grad_sigma[k] = samples.delta[i] * (ray.after[k] * grad_weight[k] - behind);
                }
                behind += weights[k] * grad_weight[k];
            }
            grad_sigma
        })
        .collect();
    per_ray.concat()
}

/// One ray's compositing weights and the light left after each sample, as compositing's
/// [`RayAccumulator`] gives them, in buffers reused ray to ray.
#[derive(Default)]
struct RayWeights {
    weights: Vec<f32>,
    after: Vec<f32>,
}

impl RayWeights {
    fn fill(&mut self, samples: &PackedSamples, sigma: &[f32], r: usize) {
        let mut ray = RayAccumulator::default();
        self.weights.clear();
        self.after.clear();
        for i in samples.ray(r) {
            self.weights.push(ray.add(alpha_from_density(sigma[i], samples.delta[i]), [0.0; 3], 0.0));
            self.after.push(ray.transmittance());
        }
    }
}

fn check_shapes(samples: &PackedSamples, sigma: &[f32], s: &[f32]) {
    assert_eq!(sigma.len(), samples.t.len(), "one density per sample");
    assert_eq!(s.len(), samples.t.len(), "one distance per sample");
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::render::grid::march_segments;
    use nerf_core::rng::Rng;
    use nerf_core::sample::Contraction;

    #[test]
    fn two_samples_by_hand() {
        // α = 0.5 each (σδ = ln 2): w = 0.5, 0.25 at s = 0.1, 0.5, widths 0.2:
        // 2·0.5·0.25·0.4 + ⅓(0.25·0.2 + 0.0625·0.2) = 0.1 + 0.0625/3.
        let samples = PackedSamples { t: vec![1.0, 2.0], delta: vec![1.0, 1.0], offsets: vec![0, 2, 2] };
        let sigma = [2f32.ln(); 2];
        let loss = distortion(&samples, &sigma, &[0.1, 0.5], 0.2);
        assert!((loss[0] - (0.1 + 0.0625 / 3.0)).abs() < 1e-6, "{loss:?}");
        // An empty ray costs nothing; one opaque sample costs ⅓h.
        assert_eq!(loss[1], 0.0);
        let one = PackedSamples { t: vec![1.0], delta: vec![100.0], offsets: vec![0, 1] };
        assert!((distortion(&one, &[1.0], &[0.3], 0.03)[0] - 0.01).abs() < 1e-6);
    }

    #[test]
    fn the_same_weight_spread_over_a_longer_stretch_costs_more() {
        // Two samples of α 0.5, close together and far apart: the far pair is a floater.
        let samples = PackedSamples { t: vec![1.0, 2.0], delta: vec![1.0, 1.0], offsets: vec![0, 2] };
        let sigma = [2f32.ln(); 2];
        let near = distortion(&samples, &sigma, &[0.5, 0.51], 0.01)[0];
        let far = distortion(&samples, &sigma, &[0.1, 0.51], 0.01)[0];
        assert!(far > 10.0 * near, "{near} {far}");
    }

    #[test]
    fn backward_matches_finite_differences() {
        let mut rng = Rng::new(5);
        let mut samples = PackedSamples { offsets: vec![0], ..PackedSamples::default() };
        for n in [0, 1, 3, 8, 21] {
            for k in 0..n {
                samples.t.push(1.0 + 0.1 * k as f32);
                samples.delta.push(0.05 + 0.2 * rng.uniform());
            }
            samples.offsets.push(samples.t.len());
        }
        let n = samples.t.len();
        let sigma: Vec<f32> = (0..n).map(|_| 4.0 * rng.uniform() - 0.5).collect();
        let s: Vec<f32> = samples.t.iter().map(|t| (t - 0.9) / 3.0 + 0.01 * rng.uniform()).collect();
        let width = 0.15;
        let g: Vec<f32> = (0..samples.n_rays()).map(|_| rng.uniform() - 0.3).collect();
        let loss = |sigma: &[f32]| distortion(&samples, sigma, &s, width).iter().zip(&g).map(|(l, g)| *l as f64 * *g as f64).sum::<f64>();
        let grad = distortion_backward(&samples, &sigma, &s, width, &g);
        let h = 1e-2f32;
        let mut checked = 0;
        for i in 0..n {
            if sigma[i].abs() > 2.0 * h {
                let (mut up, mut down) = (sigma.clone(), sigma.clone());
                up[i] += h;
                down[i] -= h;
                let fd = (loss(&up) - loss(&down)) / (2.0 * h as f64);
                assert!((fd - grad[i] as f64).abs() < 2e-4 * (1.0 + fd.abs()), "σ[{i}]: fd {fd} vs {}", grad[i]);
                checked += (fd.abs() > 1e-4) as usize;
            } else if sigma[i] < 0.0 {
                assert_eq!(grad[i], 0.0);
            }
        }
        assert!(checked > 20, "{checked} gradients checked away from zero");
    }

    #[test]
    fn step_coordinates_count_steps_in_every_segment() {
        // The cube: 4 steps over [2, 6]: t = 2 → 0, 4 → 0.5, 6 → 1.
        let cube = march_segments(2.0, 6.0, 4, None);
        assert_eq!(step_coordinates(&cube, &[2.0, 4.0, 6.0, 2.5]), vec![0.0, 0.5, 1.0, 0.125]);
        // Contracted, 16 steps: segments of 4 steps, intervals 0.5, 2, 8 from near 0.1; the
        // middle of the second segment's first step is 4.5 steps in.
        let contracted = march_segments(0.1, 20.0, 16, Some(Contraction::Linf));
        assert_eq!(contracted.len(), 3);
        let s = step_coordinates(&contracted, &[0.1, 2.1, 3.1, 10.1, 42.1]);
        let want = [0.0, 4.0 / 12.0, 4.5 / 12.0, 8.0 / 12.0, 12.0 / 12.0];
        for (got, want) in s.iter().zip(want) {
            assert!((got - want).abs() < 1e-6, "{s:?}");
        }
    }

    #[test]
    fn marched_samples_sit_whole_steps_apart_in_step_coordinates() {
        // What a step feeds the loss: jittered samples of the whole cube and of the whole
        // contracted world, measured over the segments marching used.
        use nerf_core::camera::Rays;
        use nerf_core::render::grid::occupied_samples;
        use nerf_core::sample::occupancy::OccupancyGrid;
        let rays = Rays { origins: vec![[0.1, -0.2, 0.3], [0.0, 0.4, -0.5]], directions: vec![[0.6, 0.3, -0.74], [-0.2, 0.9, 0.38]], viewdirs: None };
        for (grid, near, far) in [(OccupancyGrid::whole_cube(1.5), 0.05, 4.0), (OccupancyGrid::whole_world(Contraction::Linf), 0.05, 1000.0)] {
            let steps = 64;
            let samples = occupied_samples(&grid, &rays, near, far, steps, Some(&mut Rng::new(2)));
            let segments = march_segments(near, far, steps, grid.contraction());
            let total: usize = segments.iter().map(|s| s.steps).sum();
            let s = step_coordinates(&segments, &samples.t);
            for r in 0..rays.len() {
                let ray = &s[samples.ray(r)];
                assert!(ray.len() > 10, "{} samples", ray.len());
                let first = ray[0] * total as f32;
                for &x in ray {
                    assert!((0.0..=1.0).contains(&x), "{x}");
                    let k = x * total as f32 - first;
                    assert!((k - k.round()).abs() < 2e-3, "{:?}: {k} steps after the first", grid.contraction());
                }
            }
        }
    }
}
