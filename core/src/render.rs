//! The inference renderer: rays → coarse samples → field → weights → fine samples → field →
//! pixels. The field (burn or onnxruntime) is a parameter, so `nerf render` and `nerf-render`
//! run the same sampling and compositing code and differ only in who evaluates the networks.

use crate::camera::{Intrinsics, Pose, Rays};
use crate::compositing::{Composited, composite};
use crate::rng::Rng;
use crate::sampling::{DenseSamples, SamplingConfig, importance, stratified};
use serde::{Deserialize, Serialize};

/// Which network a batch of points is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// The coarse network, on the stratified samples.
    Coarse,
    /// The fine network, on coarse ∪ importance samples.
    Fine,
}

/// A network's answer for a batch of points.
///
/// # Shapes
/// `rgb`: `[n]` of 3 (in [0, 1]); `raw_sigma`: `[n]` (before ReLU; ReLU'd values work too).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FieldOutput {
    /// Colour per point.
    pub rgb: Vec<[f32; 3]>,
    /// Density per point.
    pub raw_sigma: Vec<f32>,
}

/// Something that evaluates the coarse and fine networks on points with unit view directions.
pub trait Field {
    /// The evaluator's error.
    type Error;
    /// Evaluate `stage`'s network on `points` `[n]` with `viewdirs` `[n]` (unit vectors).
    fn evaluate(&mut self, stage: Stage, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> Result<FieldOutput, Self::Error>;
}

/// A borrowed field is a field, so wrappers such as the skipping one can hold `&mut F`.
impl<F: Field + ?Sized> Field for &mut F {
    type Error = F::Error;
    fn evaluate(&mut self, stage: Stage, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> Result<FieldOutput, Self::Error> {
        (**self).evaluate(stage, points, viewdirs)
    }
}

/// How to render.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RenderOptions {
    /// Samples and bounds.
    pub sampling: SamplingConfig,
    /// Composite over white (`rgb + (1 − acc)`).
    pub white_background: bool,
    /// Rays per field call (bounds memory: points per call = chunk · samples per ray).
    pub chunk: usize,
}

/// Per-ray results of the last stage (fine if there is one).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RenderedRays {
    /// Colour.
    pub rgb: Vec<[f32; 3]>,
    /// Expected depth.
    pub depth: Vec<f32>,
    /// Accumulated opacity.
    pub acc: Vec<f32>,
}

impl RenderedRays {
    fn append(&mut self, c: &Composited) {
        for r in &c.rays {
            self.rgb.push(r.rgb);
            self.depth.push(r.depth);
            self.acc.push(r.acc);
        }
    }
}

fn evaluate_samples<F: Field>(
    field: &mut F,
    stage: Stage,
    rays: &Rays,
    viewdirs: &[[f32; 3]],
    samples: &DenseSamples,
    white_background: bool,
) -> Result<Composited, F::Error> {
    let points = samples.points(&rays.origins, &rays.directions);
    let dirs: Vec<[f32; 3]> =
        viewdirs.iter().flat_map(|d| std::iter::repeat_n(*d, samples.n_samples)).collect();
    let out = field.evaluate(stage, &points, &dirs)?;
    Ok(composite(samples, &out.raw_sigma, &out.rgb, &rays.directions, white_background))
}

/// Render a batch of rays (one field call per stage; split big batches with [`render_rays`]).
/// `rng` jitters the samples (training-style); `None` gives the deterministic test-time path.
pub fn render_batch<F: Field>(
    field: &mut F,
    rays: &Rays,
    options: &RenderOptions,
    mut rng: Option<&mut Rng>,
) -> Result<Composited, F::Error> {
    let s = &options.sampling;
    let viewdirs = rays.view_directions();
    let coarse = stratified(s, rays.len(), rng.as_deref_mut());
    let coarse_out = evaluate_samples(field, Stage::Coarse, rays, &viewdirs, &coarse, options.white_background)?;
    if s.n_fine == 0 {
        return Ok(coarse_out);
    }
    let extra = importance(&coarse, &coarse_out.weights, s.n_fine, rng);
    let all = coarse.merge_sorted(&extra);
    evaluate_samples(field, Stage::Fine, rays, &viewdirs, &all, options.white_background)
}

/// Render any number of rays in chunks of `options.chunk`, calling `progress(done, total)`.
pub fn render_rays<F: Field>(
    field: &mut F,
    rays: &Rays,
    options: &RenderOptions,
    mut rng: Option<&mut Rng>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<RenderedRays, F::Error> {
    let mut out = RenderedRays::default();
    let chunk = options.chunk.max(1);
    let mut start = 0;
    while start < rays.len() {
        let end = (start + chunk).min(rays.len());
        let c = render_batch(field, &rays.slice(start..end), options, rng.as_deref_mut())?;
        out.append(&c);
        progress(end, rays.len());
        start = end;
    }
    Ok(out)
}

/// A rendered image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Per-pixel results.
    pub rays: RenderedRays,
}

/// Render a whole image deterministically (test-time sampling), generating rays a chunk of rows
/// at a time so memory stays bounded by the chunk, not the image.
pub fn render_image<F: Field>(
    field: &mut F,
    intrinsics: &Intrinsics,
    pose: &Pose,
    options: &RenderOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<RenderedImage, F::Error> {
    let width = intrinsics.width as usize;
    let rows_per_chunk = (options.chunk / width.max(1)).max(1) as u32;
    let total = intrinsics.num_pixels();
    let mut out = RenderedRays::default();
    let mut row = 0;
    while row < intrinsics.height {
        let end = (row + rows_per_chunk).min(intrinsics.height);
        let rays = Rays::for_rows(intrinsics, pose, row..end);
        let done = out.rgb.len();
        let part = render_rays(field, &rays, options, None, &mut |d, _| progress(done + d, total))?;
        out.rgb.extend(part.rgb);
        out.depth.extend(part.depth);
        out.acc.extend(part.acc);
        row = end;
    }
    Ok(RenderedImage { width: intrinsics.width, height: intrinsics.height, rays: out })
}

#[cfg(test)]
mod tests {
    use super::*;

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
                raw_sigma: points.iter().map(|p| if p[2].abs() < 0.5 { 50.0 } else { 0.0 }).collect(),
            })
        }
    }

    #[test]
    fn hierarchical_render_hits_the_slab_front_and_misses_elsewhere() {
        let k = Intrinsics { width: 8, height: 4, focal: 8.0 };
        // Camera at z = 4 looking down −z (identity rotation).
        let pose = Pose([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0]]);
        let options = RenderOptions {
            sampling: SamplingConfig { n_coarse: 16, n_fine: 32, ..Default::default() },
            white_background: true,
            chunk: 10,
        };
        let mut field = Slab { calls: vec![] };
        let img = render_image(&mut field, &k, &pose, &options, &mut |_, _| {}).unwrap();
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
        // Looking away from the slab: nothing accumulates, the pixel is the white background.
        let away = Pose([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 4.0]]);
        let img = render_image(&mut field, &k, &away, &options, &mut |_, _| {}).unwrap();
        assert!(img.rays.acc.iter().all(|a| *a < 1e-6));
        assert!(img.rays.rgb.iter().all(|c| c.iter().all(|v| (v - 1.0).abs() < 1e-6)));
    }
}
