//! The reference hierarchical renderer: stratified samples → coarse network → weights →
//! inverse-CDF samples → fine network on coarse ∪ fine samples → pixels.

use super::packed::{PackedSamples, march_front_to_back};
use super::RenderOptions;
use crate::field::{Field, Stage};
use crate::camera::Rays;
use super::compositing::{Composited, composite};
use crate::rng::Rng;
use crate::sample::stratified::{DenseSamples, importance, stratified};

/// Render a batch of rays: one field call per stage, or, with `options.min_transmittance`, one
/// per [`MARCH_SEGMENT`](super::MARCH_SEGMENT) front-to-back step. `rng` jitters the samples
/// (training-style); `None` gives the deterministic test-time path.
pub fn render_rays<F: Field>(
    field: &mut F,
    rays: &Rays,
    options: &RenderOptions,
    mut rng: Option<&mut Rng>,
) -> Result<Composited, F::Error> {
    let s = &options.sampling;
    let viewdirs = rays.view_directions();
    let coarse = stratified(s, rays.len(), rng.as_deref_mut());
    let coarse_out = render_stage(field, Stage::Coarse, rays, &viewdirs, &coarse, options)?;
    if s.n_fine == 0 {
        return Ok(coarse_out);
    }
    let extra = importance(&coarse, &coarse_out.weights, s.n_fine, rng);
    let all = coarse.merge_sorted(&extra);
    render_stage(field, Stage::Fine, rays, &viewdirs, &all, options)
}

/// Evaluate and composite one stage's samples.
fn render_stage<F: Field>(
    field: &mut F,
    stage: Stage,
    rays: &Rays,
    viewdirs: &[[f32; 3]],
    samples: &DenseSamples,
    options: &RenderOptions,
) -> Result<Composited, F::Error> {
    match options.min_transmittance {
        None => {
            let points = samples.points(&rays.origins, &rays.directions);
            let dirs: Vec<[f32; 3]> = viewdirs.iter().flat_map(|d| std::iter::repeat_n(*d, samples.n_samples)).collect();
            let out = field.evaluate(stage, &points, &dirs)?;
            Ok(composite(samples, &out.sigma, &out.rgb, &rays.directions, options.white_background))
        }
        Some(min_t) => {
            let packed = PackedSamples::from_dense(samples, &rays.directions);
            let m = march_front_to_back(field, stage, rays, viewdirs, &packed, min_t, options.white_background)?;
            Ok(Composited { rays: m.rays, weights: m.weights })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{DEFAULT_MARCH_STEPS, render_image};
    use crate::field::FieldOutput;
    use super::*;
    use crate::camera::{Intrinsics, Pose};
    use crate::sample::stratified::SamplingConfig;

    /// A slab of constant density between z = −0.5 and 0.5, red in front (z > 0), else blue.
    struct Slab {
        calls: Vec<(Stage, usize)>,
    }

    impl Field for Slab {
        type Error = std::convert::Infallible;
        fn evaluate(&mut self, stage: Stage, points: &[[f32; 3]], _: &[[f32; 3]]) -> Result<FieldOutput, Self::Error> {
            self.calls.push((stage, points.len()));
            Ok(FieldOutput {
                rgb: points.iter().map(|p| if p[2] > 0.0 { [1.0, 0.0, 0.0] } else { [0.0, 0.0, 1.0] }).collect(),
                sigma: points.iter().map(|p| if p[2].abs() < 0.5 { 500.0 } else { 0.0 }).collect(),
            })
        }
    }

    #[test]
    fn hierarchical_render_hits_the_slab_front_and_misses_elsewhere() {
        let k = crate::PinholeCamera::from(Intrinsics { width: 8, height: 4, focal: 8.0 });
        // Camera at z = 4 looking down −z (identity rotation).
        let pose = Pose([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0]]);
        let options = RenderOptions {
            sampling: SamplingConfig { n_coarse: 16, n_fine: 32, ..Default::default() },
            white_background: true,
            chunk: 10,
            min_transmittance: None,
            march_steps: DEFAULT_MARCH_STEPS,
            overlap: false,
        };
        let mut field = Slab { calls: vec![] };
        let img = render_image(&mut field, None, &k, &pose, &options, &mut |_, _| {}).unwrap();
        assert_eq!(img.rays.rgb.len(), 32);
        for (rgb, (depth, acc)) in img.rays.rgb.iter().zip(img.rays.depth.iter().zip(&img.rays.acc)) {
            assert!(*acc > 0.999, "opaque slab: acc {acc}");
            assert!(rgb[0] > 0.99 && rgb[2] < 0.01, "front face is red: {rgb:?}");
            // The slab's front is at z = 0.5 → t ≈ 3.5 along these nearly axial rays.
            assert!(*depth > 3.4 && *depth < 3.7, "depth {depth}");
        }
        // Chunks of ≤ 10 rays: coarse calls see ≤ 160 points, fine ≤ 480.
        assert!(field.calls.iter().all(|(s, n)| match s {
            Stage::Coarse => *n <= 160,
            Stage::Fine => *n <= 480,
        }));
        // Early termination: the same pixels (the slab is opaque: its later samples weigh
        // < 1e-4), from fewer evaluated points.
        let dense = RenderOptions { sampling: SamplingConfig { n_coarse: 64, n_fine: 128, ..Default::default() }, ..options.clone() };
        let marching = RenderOptions { min_transmittance: Some(1e-4), ..dense.clone() };
        let mut evaluated = |options: &RenderOptions| {
            field.calls.clear();
            let img = render_image(&mut field, None, &k, &pose, options, &mut |_, _| {}).unwrap();
            (img, field.calls.iter().map(|c| c.1).sum::<usize>())
        };
        let (full, dense_points) = evaluated(&dense);
        let (early, early_points) = evaluated(&marching);
        assert!(early_points * 2 < dense_points, "{early_points} points marched vs {dense_points} dense");
        for (a, b) in early.rays.rgb.iter().flatten().zip(full.rays.rgb.iter().flatten()) {
            assert!((a - b).abs() < 1e-3, "{a} vs {b}");
        }
        for (a, b) in early.rays.depth.iter().zip(&full.rays.depth) {
            assert!((a - b).abs() < 1e-2, "depth {a} vs {b}");
        }
        // Looking away from the slab: nothing accumulates, the pixel is the white background.
        let away = Pose([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 4.0]]);
        let img = render_image(&mut field, None, &k, &away, &options, &mut |_, _| {}).unwrap();
        assert!(img.rays.acc.iter().all(|a| *a < 1e-6));
        assert!(img.rays.rgb.iter().all(|c| c.iter().all(|v| (v - 1.0).abs() < 1e-6)));
    }
}
