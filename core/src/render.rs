//! The inference renderer: rays → coarse samples → field → weights → fine samples → field →
//! pixels. The field (burn or onnxruntime) is a parameter, so `nerf render` and `nerf-render`
//! run the same sampling and compositing code and differ only in who evaluates the networks.

use crate::camera::{Intrinsics, Pose, Rays};
use crate::compositing::{Composited, RayOutput, TRANSMITTANCE_EPS, alpha_from_density, composite, deltas};
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
    /// Early ray termination: march front to back, [`MARCH_SEGMENT`] samples per ray at a time,
    /// and stop evaluating a ray once its transmittance is below this (its later samples count
    /// as σ = 0; their weights would be below it anyway). `None`: evaluate every sample.
    #[serde(default)]
    pub min_transmittance: Option<f32>,
    /// Intervals over [near, far] when marching through an occupancy grid
    /// (`nerf_core::occupancy::march_rays`).
    #[serde(default = "default_march_steps")]
    pub march_steps: usize,
}

fn default_march_steps() -> usize {
    DEFAULT_MARCH_STEPS
}

/// Default marching resolution: 256 intervals over [near, far] (δ = 1/64 for lego's 2..6,
/// a third of a 64³ cell over ±1.5; finer than the 192 samples of the dense path).
pub const DEFAULT_MARCH_STEPS: usize = 256;

/// Samples per ray evaluated per step when marching with early termination.
pub const MARCH_SEGMENT: usize = 16;
/// The default early-termination threshold (instant-ngp and nerfacc use 1e-4 too).
pub const DEFAULT_MIN_TRANSMITTANCE: f32 = 1e-4;

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
    fn append(&mut self, rays: &[RayOutput]) {
        for r in rays {
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
    options: &RenderOptions,
) -> Result<Composited, F::Error> {
    let out = match options.min_transmittance {
        None => {
            let points = samples.points(&rays.origins, &rays.directions);
            let dirs: Vec<[f32; 3]> = viewdirs.iter().flat_map(|d| std::iter::repeat_n(*d, samples.n_samples)).collect();
            field.evaluate(stage, &points, &dirs)?
        }
        Some(min_t) => march(field, stage, rays, viewdirs, samples, min_t)?,
    };
    Ok(composite(samples, &out.raw_sigma, &out.rgb, &rays.directions, options.white_background))
}

/// Evaluate `samples` front to back, [`MARCH_SEGMENT`] per ray at a time, dropping rays whose
/// transmittance falls below `min_transmittance`; unevaluated samples get σ = 0.
fn march<F: Field>(
    field: &mut F,
    stage: Stage,
    rays: &Rays,
    viewdirs: &[[f32; 3]],
    samples: &DenseSamples,
    min_transmittance: f32,
) -> Result<FieldOutput, F::Error> {
    let n = samples.n_samples;
    let mut out = FieldOutput { rgb: vec![[0.0; 3]; samples.t.len()], raw_sigma: vec![0.0; samples.t.len()] };
    let mut transmittance = vec![1.0f32; rays.len()];
    let mut active: Vec<usize> = (0..rays.len()).collect();
    let (mut points, mut dirs, mut index, mut ray_deltas) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for start in (0..n).step_by(MARCH_SEGMENT) {
        let end = (start + MARCH_SEGMENT).min(n);
        points.clear();
        dirs.clear();
        index.clear();
        for &r in &active {
            let (o, d) = (rays.origins[r], rays.directions[r]);
            for (k, &t) in samples.ray(r)[start..end].iter().enumerate() {
                points.push([o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]);
                dirs.push(viewdirs[r]);
                index.push(r * n + start + k);
            }
        }
        let part = field.evaluate(stage, &points, &dirs)?;
        for (j, &i) in index.iter().enumerate() {
            out.rgb[i] = part.rgb[j];
            out.raw_sigma[i] = part.raw_sigma[j];
        }
        for &r in &active {
            let d = rays.directions[r];
            deltas(samples.ray(r), (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt(), &mut ray_deltas);
            for k in start..end {
                transmittance[r] *= 1.0 - alpha_from_density(out.raw_sigma[r * n + k], ray_deltas[k]) + TRANSMITTANCE_EPS;
            }
        }
        active.retain(|&r| transmittance[r] >= min_transmittance);
        if active.is_empty() {
            break;
        }
    }
    Ok(out)
}

/// Render a batch of rays (one field call per stage, or one per marching segment; images are
/// split into batches of `options.chunk` rays by [`render_image`]).
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
    let coarse_out = evaluate_samples(field, Stage::Coarse, rays, &viewdirs, &coarse, options)?;
    if s.n_fine == 0 {
        return Ok(coarse_out);
    }
    let extra = importance(&coarse, &coarse_out.weights, s.n_fine, rng);
    let all = coarse.merge_sorted(&extra);
    evaluate_samples(field, Stage::Fine, rays, &viewdirs, &all, options)
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
    render_image_by(intrinsics, pose, options.chunk, progress, |rays| render_batch(field, rays, options, None).map(|c| c.rays))
}

/// Render a whole image with `batch` (≤ `chunk` rays → one output per ray), generating rays a
/// chunk of rows at a time so memory stays bounded by the chunk, not the image.
pub fn render_image_by<E>(
    intrinsics: &Intrinsics,
    pose: &Pose,
    chunk: usize,
    progress: &mut dyn FnMut(usize, usize),
    mut batch: impl FnMut(&Rays) -> Result<Vec<RayOutput>, E>,
) -> Result<RenderedImage, E> {
    let chunk = chunk.max(1);
    let width = intrinsics.width as usize;
    let rows_per_chunk = (chunk / width.max(1)).max(1) as u32;
    let total = intrinsics.num_pixels();
    let mut out = RenderedRays::default();
    let mut row = 0;
    while row < intrinsics.height {
        let end = (row + rows_per_chunk).min(intrinsics.height);
        let rays = Rays::for_rows(intrinsics, pose, row..end);
        let mut start = 0;
        while start < rays.len() {
            let stop = (start + chunk).min(rays.len());
            out.append(&batch(&rays.slice(start..stop))?);
            progress(out.rgb.len(), total);
            start = stop;
        }
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
                raw_sigma: points.iter().map(|p| if p[2].abs() < 0.5 { 500.0 } else { 0.0 }).collect(),
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
            min_transmittance: None,
            march_steps: DEFAULT_MARCH_STEPS,
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
        // Early termination: the same pixels (the slab is opaque: its later samples weigh
        // < 1e-4), from fewer evaluated points.
        let dense = RenderOptions { sampling: SamplingConfig { n_coarse: 64, n_fine: 128, ..Default::default() }, ..options.clone() };
        let marching = RenderOptions { min_transmittance: Some(1e-4), ..dense.clone() };
        let mut evaluated = |options: &RenderOptions| {
            field.calls.clear();
            let img = render_image(&mut field, &k, &pose, options, &mut |_, _| {}).unwrap();
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
        let img = render_image(&mut field, &k, &away, &options, &mut |_, _| {}).unwrap();
        assert!(img.rays.acc.iter().all(|a| *a < 1e-6));
        assert!(img.rays.rgb.iter().all(|c| c.iter().all(|v| (v - 1.0).abs() < 1e-6)));
    }
}
