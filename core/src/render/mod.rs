//! The inference renderer, shared by `nerf eval`/`render` (burn), the trainer's validation
//! renders and `nerf-render` (onnxruntime): the field is a parameter, so they differ only in
//! who evaluates the networks.
//!
//! - [`dense`]: the reference hierarchical path, rays → stratified samples → coarse field →
//!   weights → inverse-CDF samples → fine field → pixels.
//! - [`grid`]: marching through an occupancy grid's occupied cells (empty-space skipping).
//! - [`packed`]: the front-to-back evaluator both use for early ray termination, over one
//!   packed sample layout.
//!
//! Every path composites through [`crate::render::compositing::RayAccumulator`]. [`render_image`] picks
//! the path (a grid → marching, else dense) and walks the image a chunk of rays at a time.

pub mod compositing;
pub mod dense;
pub mod grid;
pub mod metrics;
pub mod packed;

use crate::camera::{Pose, Rays};
use crate::camera::PinholeCamera;
use crate::field::Field;
use compositing::RayOutput;
use crate::sample::occupancy::OccupancyGrid;
use crate::sample::stratified::SamplingConfig;
use serde::{Deserialize, Serialize};

/// How to render.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RenderOptions {
    /// Samples and bounds.
    pub sampling: SamplingConfig,
    /// Composite over white (`rgb + (1 − acc)`).
    pub white_background: bool,
    /// Rays per field call (bounds memory: points per call = chunk · samples per ray).
    pub chunk: usize,
    /// Early ray termination: evaluate front to back, [`MARCH_SEGMENT`] samples per ray at a
    /// time, and stop evaluating a ray once its transmittance is below this (its later samples
    /// count as σ = 0; their weights would be below it anyway). `None`: evaluate every sample.
    #[serde(default)]
    pub min_transmittance: Option<f32>,
    /// Intervals over [near, far] when marching through an occupancy grid ([`grid`]).
    #[serde(default = "default_march_steps")]
    pub march_steps: usize,
    /// Marching: overlap the CPU's marching and compositing with the field's evaluation, half
    /// the rays at a time ([`grid::render_rays_in`]); for fields evaluated on a device.
    #[serde(default)]
    pub overlap: bool,
}

fn default_march_steps() -> usize {
    DEFAULT_MARCH_STEPS
}

impl RenderOptions {
    /// The options every renderer uses: with `skip_empty_space` (a grid, when the model has
    /// one), rays also stop once opaque ([`DEFAULT_MIN_TRANSMITTANCE`]) and marching takes
    /// [`DEFAULT_MARCH_STEPS`] intervals; without it every sample is evaluated.
    pub fn new(sampling: SamplingConfig, white_background: bool, chunk: usize, skip_empty_space: bool) -> Self {
        RenderOptions {
            sampling,
            white_background,
            chunk,
            min_transmittance: skip_empty_space.then_some(DEFAULT_MIN_TRANSMITTANCE),
            march_steps: DEFAULT_MARCH_STEPS,
            overlap: false,
        }
    }
}

/// Default marching resolution: 256 intervals over [near, far] (δ = 1/64 for lego's 2..6,
/// a third of a 64³ cell over ±1.5; finer than the 192 samples of the dense path).
pub const DEFAULT_MARCH_STEPS: usize = 256;

/// Samples per ray evaluated per field call when marching front to back.
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

/// Render a batch of rays deterministically: marching through `occupancy` when a grid is
/// given ([`grid::render_rays`]), else the dense hierarchical path ([`dense::render_rays`]).
pub fn render_rays<F: Field>(
    field: &mut F,
    occupancy: Option<&OccupancyGrid>,
    rays: &Rays,
    options: &RenderOptions,
) -> Result<Vec<RayOutput>, F::Error> {
    render_rays_in(field, occupancy.map(grid::Skipper::new).as_ref(), rays, options)
}

/// [`render_rays`] with the grid's coarse level made once by the caller.
fn render_rays_in<F: Field>(field: &mut F, skipper: Option<&grid::Skipper>, rays: &Rays, options: &RenderOptions) -> Result<Vec<RayOutput>, F::Error> {
    match skipper {
        Some(skipper) => grid::render_rays_in(field, skipper, rays, options),
        None => dense::render_rays(field, rays, options, None).map(|c| c.rays),
    }
}

/// Render a whole image deterministically (as [`render_rays`]), `options.chunk` rays per batch,
/// generating rays a chunk of rows at a time so memory stays bounded by the chunk, not the
/// image; `progress(done, total)` counts pixels.
pub fn render_image<F: Field>(
    field: &mut F,
    occupancy: Option<&OccupancyGrid>,
    camera: &PinholeCamera,
    pose: &Pose,
    options: &RenderOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<RenderedImage, F::Error> {
    let skipper = occupancy.map(grid::Skipper::new);
    render_image_with(camera, pose, options, progress, &mut |rays| render_rays_in(field, skipper.as_ref(), rays, options))
}

/// [`render_image`]'s batches (at most `options.chunk` rays, warped as the sampling says) each
/// rendered by `render_batch`, e.g. another implementation of the same loop.
pub fn render_image_with<E>(
    camera: &PinholeCamera,
    pose: &Pose,
    options: &RenderOptions,
    progress: &mut dyn FnMut(usize, usize),
    render_batch: &mut dyn FnMut(&Rays) -> Result<Vec<RayOutput>, E>,
) -> Result<RenderedImage, E> {
    let chunk = options.chunk.max(1);
    let width = camera.width as usize;
    let rows_per_chunk = (chunk / width.max(1)).max(1) as u32;
    let total = camera.num_pixels();
    let mut out = RenderedRays::default();
    let mut row = 0;
    while row < camera.height {
        let end = (row + rows_per_chunk).min(camera.height);
        let rays = options.sampling.warp_rays(Rays::for_rows(camera, pose, row..end));
        let mut start = 0;
        while start < rays.len() {
            let stop = (start + chunk).min(rays.len());
            out.append(&render_batch(&rays.slice(start..stop))?);
            progress(out.rgb.len(), total);
            start = stop;
        }
        row = end;
    }
    Ok(RenderedImage { width: camera.width, height: camera.height, rays: out })
}
