//! Volume rendering with its gradient, over packed samples: the training twin of
//! [`nerf_core::render::packed::march_front_to_back`] for fields whose samples vary in number per ray (the
//! hash-grid field marches through the occupancy grid). Written by hand rather than as burn ops
//! because ray lengths differ; the burn side only sees ∂loss/∂σ and ∂loss/∂rgb per sample.
//!
//! For one ray with samples i: αᵢ = 1 − exp(−σᵢδᵢ), Tᵢ = Πⱼ₍ⱼ<ᵢ₎(1 − αⱼ), wᵢ = Tᵢαᵢ and
//! C = Σ wᵢcᵢ + T_N·b (b the background, T_N the light that passes every sample). Then
//! ∂C/∂cᵢ = wᵢ and ∂C/∂σᵢ = δᵢ·(Tᵢ₊₁cᵢ − Sᵢ), with Sᵢ = Σ₍ₖ>ᵢ₎ wₖcₖ + T_N·b the colour that
//! comes from behind sample i.

use nerf_core::render::packed::PackedSamples;
use nerf_core::render::compositing::{RayAccumulator, alpha_from_density};
use rayon::prelude::*;

/// Per-ray colour and opacity of packed samples, each ray composited over its own background
/// (a constant colour, or a random one per ray when training on random backgrounds).
///
/// # Shapes
/// `sigma`: `[n_samples]`, `rgb`: `[n_samples]` of 3, `backgrounds`: `[n_rays]` of 3 →
/// `[n_rays]` colours and opacities.
pub fn composite_packed(samples: &PackedSamples, sigma: &[f32], rgb: &[[f32; 3]], backgrounds: &[[f32; 3]]) -> (Vec<[f32; 3]>, Vec<f32>) {
    assert_eq!(sigma.len(), samples.t.len(), "one density per sample");
    assert_eq!(rgb.len(), samples.t.len(), "one colour per sample");
    assert_eq!(backgrounds.len(), samples.n_rays(), "one background per ray");
    (0..samples.n_rays())
        .into_par_iter()
        .map(|r| {
            let mut ray = RayAccumulator::default();
            for i in samples.ray(r) {
                ray.add(alpha_from_density(sigma[i], samples.delta[i]), rgb[i], samples.t[i]);
            }
            let out = ray.finish(false);
            let light = ray.transmittance();
            ([0, 1, 2].map(|c| out.rgb[c] + light * backgrounds[r][c]), out.acc)
        })
        .unzip()
}

/// The gradient of a loss through [`composite_packed`]: given ∂loss/∂C per ray, ∂loss/∂σ and
/// ∂loss/∂rgb per sample (σ ≤ 0 gets 0, as `alpha_from_density` clamps it).
///
/// # Shapes
/// `grad_color`: `[n_rays]` of 3 → (`[n_samples]`, `[n_samples]` of 3).
pub fn composite_packed_backward(
    samples: &PackedSamples,
    sigma: &[f32],
    rgb: &[[f32; 3]],
    backgrounds: &[[f32; 3]],
    grad_color: &[[f32; 3]],
) -> (Vec<f32>, Vec<[f32; 3]>) {
    assert_eq!(grad_color.len(), samples.n_rays(), "one colour gradient per ray");
    assert_eq!(backgrounds.len(), samples.n_rays(), "one background per ray");
    let mut grad_sigma = vec![0.0f32; sigma.len()];
    let mut grad_rgb = vec![[0.0f32; 3]; rgb.len()];
    // Split the outputs ray by ray so that rays run in parallel.
    let mut sigma_parts = Vec::with_capacity(samples.n_rays());
    let mut rgb_parts = Vec::with_capacity(samples.n_rays());
    let (mut gs, mut gr) = (grad_sigma.as_mut_slice(), grad_rgb.as_mut_slice());
    for r in 0..samples.n_rays() {
        let n = samples.ray(r).len();
        let (a, rest) = gs.split_at_mut(n);
        let (b, rest_rgb) = gr.split_at_mut(n);
        sigma_parts.push(a);
        rgb_parts.push(b);
        gs = rest;
        gr = rest_rgb;
    }
    sigma_parts.into_par_iter().zip(rgb_parts).enumerate().for_each(|(r, (gs, gr))| {
        let range = samples.ray(r);
        let g = grad_color[r];
        let dot = |c: [f32; 3]| g[0] * c[0] + g[1] * c[1] + g[2] * c[2];
        // First pass: the foreground Σ wc (as g·, a scalar) and the light that passes.
        let mut transmittance = 1.0f32;
        let mut foreground = 0.0f32;
        for i in range.clone() {
            let alpha = alpha_from_density(sigma[i], samples.delta[i]);
            foreground += transmittance * alpha * dot(rgb[i]);
            transmittance *= 1.0 - alpha;
        }
        let behind_all = transmittance * dot(backgrounds[r]);
        // Second pass: Sᵢ = foreground − prefix up to i + T_N·b.
        let mut t_i = 1.0f32;
        let mut prefix = 0.0f32;
        for (k, i) in range.enumerate() {
            let alpha = alpha_from_density(sigma[i], samples.delta[i]);
            let w = t_i * alpha;
            prefix += w * dot(rgb[i]);
            let t_next = t_i * (1.0 - alpha);
            gr[k] = g.map(|v| v * w);
            gs[k] = if sigma[i] > 0.0 { samples.delta[i] * (t_next * dot(rgb[i]) - (foreground - prefix + behind_all)) } else { 0.0 };
            t_i = t_next;
        }
    });
    (grad_sigma, grad_rgb)
}

/// The samples that light from the camera still reaches: along each ray, those with at least
/// `min_transmittance` in front of them (nerfacc's `early_stop_eps`, instant-ngp's compaction of
/// a training batch). The others weigh less than that, together, so a step drops them before
/// the colour MLP and the backward pass, and its sample budget goes to samples that matter.
///
/// σ is measured in rounds: `density` gets the next `round` samples (indices into `samples`)
/// of every ray that light still reaches, ray by ray, and returns their σ; rays whose light is
/// spent, or whose samples are all measured, leave. A ray then costs at most `round − 1`
/// samples past its last visible one, not all of its samples behind the surface; which samples
/// are kept does not depend on `round`.
/// Returns the kept samples (packed, ray by ray) and each one's position in the concatenation
/// of the rounds' batches (with one round of every sample, its index in `samples`).
pub fn visible_samples_in_rounds(samples: &PackedSamples, min_transmittance: f32, round: usize, mut density: impl FnMut(&[usize]) -> Vec<f32>) -> (PackedSamples, Vec<usize>) {
    let n_rays = samples.n_rays();
    let round = round.max(1);
    // Per ray: its next sample to measure (its end once it leaves) and the light left.
    let mut next: Vec<usize> = samples.offsets[..n_rays].to_vec();
    let mut light = vec![1.0f32; n_rays];
    let mut live: Vec<usize> = (0..n_rays).filter(|&r| !samples.ray(r).is_empty() && !(1.0 < min_transmittance)).collect();
    // Where each kept sample sits in the rounds' batches.
    let mut position = vec![0usize; samples.t.len()];
    let mut measured = 0;
    let mut batch = Vec::new();
    while !live.is_empty() {
        batch.clear();
        for &r in &live {
            batch.extend(next[r]..next[r].saturating_add(round).min(samples.offsets[r + 1]));
        }
        let sigma = density(&batch);
        assert_eq!(sigma.len(), batch.len(), "one density per sample of the round");
        let mut k = 0;
        live.retain(|&r| {
            let (start, end) = (next[r], next[r].saturating_add(round).min(samples.offsets[r + 1]));
            let mut spent = false;
            for i in start..end {
                position[i] = measured + k + (i - start);
                light[r] *= 1.0 - alpha_from_density(sigma[k + i - start], samples.delta[i]);
                next[r] = i + 1;
                if light[r] < min_transmittance {
                    spent = true;
                    break;
                }
            }
            k += end - start;
            !spent && next[r] < samples.offsets[r + 1]
        });
        measured += batch.len();
    }
    let mut kept = PackedSamples { offsets: vec![0], ..PackedSamples::default() };
    let mut kept_position = Vec::new();
    for r in 0..n_rays {
        for i in samples.offsets[r]..next[r] {
            kept.t.push(samples.t[i]);
            kept.delta.push(samples.delta[i]);
            kept_position.push(position[i]);
        }
        kept.offsets.push(kept.t.len());
    }
    (kept, kept_position)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::rng::Rng;

    /// Every sample measured at once: each kept sample's position is its index.
    fn visible_samples(samples: &PackedSamples, sigma: &[f32], min_transmittance: f32) -> (PackedSamples, Vec<usize>) {
        assert_eq!(sigma.len(), samples.t.len(), "one density per sample");
        visible_samples_in_rounds(samples, min_transmittance, usize::MAX, |batch| batch.iter().map(|&i| sigma[i]).collect())
    }

    fn random_rays(rng: &mut Rng) -> (PackedSamples, Vec<f32>, Vec<[f32; 3]>) {
        let mut samples = PackedSamples { offsets: vec![0], ..PackedSamples::default() };
        for r in 0..5 {
            let n = [0, 1, 4, 9, 17][r];
            for k in 0..n {
                samples.t.push(2.0 + 0.1 * k as f32);
                samples.delta.push(0.05 + 0.1 * rng.uniform());
            }
            samples.offsets.push(samples.t.len());
        }
        let n = samples.t.len();
        let sigma = (0..n).map(|_| 20.0 * rng.uniform() - 2.0).collect();
        let rgb = (0..n).map(|_| [rng.uniform(), rng.uniform(), rng.uniform()]).collect();
        (samples, sigma, rgb)
    }

    /// loss = Σ_rays Σ_c g_c · C_c with fixed random g: its gradient is the backward's output.
    fn loss(samples: &PackedSamples, sigma: &[f32], rgb: &[[f32; 3]], bg: &[[f32; 3]], g: &[[f32; 3]]) -> f64 {
        let (colors, _) = composite_packed(samples, sigma, rgb, bg);
        colors.iter().zip(g).map(|(c, g)| (0..3).map(|k| c[k] as f64 * g[k] as f64).sum::<f64>()).sum()
    }

    #[test]
    fn backward_matches_finite_differences() {
        let mut rng = Rng::new(7);
        let (samples, sigma, rgb) = random_rays(&mut rng);
        // A different background on every ray (random-background training).
        let bg: Vec<[f32; 3]> = (0..samples.n_rays()).map(|_| [rng.uniform(), rng.uniform(), rng.uniform()]).collect();
        let bg = bg.as_slice();
        let g: Vec<[f32; 3]> = (0..samples.n_rays()).map(|_| [rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5]).collect();
        let (gs, gr) = composite_packed_backward(&samples, &sigma, &rgb, bg, &g);
        let h = 1e-2f32;
        let mut checked = 0;
        for i in 0..sigma.len() {
            // Central differences away from the ReLU kink at σ = 0.
            if sigma[i].abs() > 2.0 * h {
                let (mut up, mut down) = (sigma.clone(), sigma.clone());
                up[i] += h;
                down[i] -= h;
                let fd = (loss(&samples, &up, &rgb, bg, &g) - loss(&samples, &down, &rgb, bg, &g)) / (2.0 * h as f64);
                assert!((fd - gs[i] as f64).abs() < 2e-3 * (1.0 + fd.abs()), "σ[{i}]: fd {fd} vs {}", gs[i]);
                checked += 1;
            } else if sigma[i] < 0.0 {
                assert_eq!(gs[i], 0.0);
            }
            for c in 0..3 {
                let (mut up, mut down) = (rgb.clone(), rgb.clone());
                up[i][c] += h;
                down[i][c] -= h;
                let fd = (loss(&samples, &sigma, &up, bg, &g) - loss(&samples, &sigma, &down, bg, &g)) / (2.0 * h as f64);
                assert!((fd - gr[i][c] as f64).abs() < 1e-3, "rgb[{i}][{c}]: fd {fd} vs {}", gr[i][c]);
            }
        }
        assert!(checked > 20, "{checked} densities checked");
    }

    #[test]
    fn visible_samples_stop_where_the_light_is_spent() {
        // Ray 0: α = 1 − e^(−σδ) with σδ = ln 10 (α 0.9): T before its samples 1, 0.1, 0.01,
        // 1e-3, 1e-4, 1e-5. Ray 1: empty. Ray 2: σ ≤ 0 lets all light through.
        let samples = PackedSamples { t: (0..9).map(|k| k as f32).collect(), delta: vec![1.0; 9], offsets: vec![0, 6, 6, 9] };
        let sigma = [10f32.ln(), 10f32.ln(), 10f32.ln(), 10f32.ln(), 10f32.ln(), 10f32.ln(), -1.0, 0.0, -3.0];
        let (kept, index) = visible_samples(&samples, &sigma, 2e-3);
        // T = 1, 0.1, 0.01 ≥ 2e-3 and 1e-3 < 2e-3: three samples of ray 0, all of ray 2.
        assert_eq!(index, vec![0, 1, 2, 6, 7, 8]);
        assert_eq!(kept.offsets, vec![0, 3, 3, 6]);
        assert_eq!(kept.t, vec![0.0, 1.0, 2.0, 6.0, 7.0, 8.0]);
        // Nothing stops at 0; nothing is kept at 1.5 (the light starts at 1).
        assert_eq!(visible_samples(&samples, &sigma, 0.0).1, (0..9).collect::<Vec<_>>());
        assert_eq!(visible_samples(&samples, &sigma, 1.5).1, Vec::<usize>::new());
        // The colour of the kept samples differs from the full ray's by less than the
        // threshold (the dropped samples' weights sum to below it).
        let rgb = vec![[0.3, 0.6, 0.9]; 9];
        let full = composite_packed(&samples, &sigma, &rgb, &[[1.0; 3]; 3]).0;
        let kept_rgb: Vec<[f32; 3]> = index.iter().map(|&i| rgb[i]).collect();
        let kept_sigma: Vec<f32> = index.iter().map(|&i| sigma[i]).collect();
        let part = composite_packed(&kept, &kept_sigma, &kept_rgb, &[[1.0; 3]; 3]).0;
        for (a, b) in full.iter().zip(&part) {
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() < 2e-3, "{a:?} vs {b:?}");
            }
        }
    }

    #[test]
    fn rounds_keep_what_one_pass_keeps_and_measure_at_most_a_round_past_it() {
        let mut rng = Rng::new(11);
        let (samples, sigma, _) = random_rays(&mut rng);
        for min_transmittance in [0.0, 1e-4, 0.05, 0.5, 1.0, 1.5] {
            let (want, index) = visible_samples(&samples, &sigma, min_transmittance);
            for round in [1, 2, 3, 5, 64] {
                let mut batches: Vec<usize> = Vec::new();
                let mut rounds = 0;
                let (kept, position) = visible_samples_in_rounds(&samples, min_transmittance, round, |batch| {
                    rounds += 1;
                    // Ray by ray, in order, at most `round` of each ray.
                    assert!(batch.windows(2).all(|w| w[0] < w[1]), "{batch:?}");
                    batches.extend_from_slice(batch);
                    batch.iter().map(|&i| sigma[i]).collect()
                });
                assert_eq!(kept, want, "min {min_transmittance}, round {round}");
                // Each kept sample's position names it in the rounds' batches.
                assert_eq!(position.iter().map(|&p| batches[p]).collect::<Vec<_>>(), index);
                // No sample twice; per ray at most `round − 1` measured past its last kept one.
                let mut sorted = batches.clone();
                sorted.dedup();
                assert_eq!(sorted.len(), batches.len());
                for r in 0..samples.n_rays() {
                    let measured = batches.iter().filter(|&&i| samples.ray(r).contains(&i)).count();
                    assert!(measured >= kept.ray(r).len() && measured < kept.ray(r).len() + round, "ray {r}: {measured} measured, {} kept", kept.ray(r).len());
                }
                if round == 1 {
                    assert_eq!(batches.len(), index.len(), "one at a time measures only what is kept");
                }
                if round == 1 && min_transmittance == 0.0 {
                    assert_eq!(rounds, 17, "nothing stops: the longest ray takes a round per sample");
                }
            }
        }
    }

    #[test]
    fn two_samples_by_hand() {
        // α = 0.5, 0.5 (σδ = ln 2): w = 0.5, 0.25, T_N = 0.25.
        let samples = PackedSamples { t: vec![1.0, 2.0], delta: vec![1.0, 1.0], offsets: vec![0, 2] };
        let sigma = [2f32.ln(); 2];
        let rgb = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let (c, acc) = composite_packed(&samples, &sigma, &rgb, &[[1.0, 1.0, 1.0]]);
        let want = [0.5 + 0.25, 0.25 + 0.25, 0.25];
        for k in 0..3 {
            assert!((c[0][k] - want[k]).abs() < 1e-6, "{c:?}");
        }
        assert!((acc[0] - 0.75).abs() < 1e-6);
        // ∂C_red/∂σ₀ = δ·(T₁·1 − S₀), S₀ = w₁·0 + T_N·1 = 0.25, T₁ = 0.5 → 0.25.
        let (gs, gr) = composite_packed_backward(&samples, &sigma, &rgb, &[[1.0, 1.0, 1.0]], &[[1.0, 0.0, 0.0]]);
        assert!((gs[0] - 0.25).abs() < 1e-6, "{gs:?}");
        // ∂C_red/∂σ₁ = δ·(T₂·0 − T_N·1) = −0.25.
        assert!((gs[1] + 0.25).abs() < 1e-6, "{gs:?}");
        assert_eq!(gr[1], [0.25, 0.0, 0.0]);
    }
}
