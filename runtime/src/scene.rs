//! A scene bundle opened for rendering: `scene.json`, the graphs in onnxruntime and the
//! occupancy grid, rendered through the shared core (`nerf_core::render::render_image`), or on
//! a GPU with a grid through the GPU loop ([`crate::gpu`]).

use crate::environment::Device;
use crate::error::{Result, RuntimeError};
use crate::field::OrtField;
use crate::gpu::GpuMarch;
use crate::network::{Encoding, OrtNetwork, POINTS_PER_RUN, Threading};
use nerf_core::PinholeCamera;
use nerf_core::camera::Pose;
use nerf_core::field::Stage;
use nerf_core::io::limits::{self, Origin};
use nerf_core::sample::occupancy::{OccupancyGrid, marching_grid};
use nerf_core::render::{MARCH_SEGMENT, RenderOptions, RenderedImage, render_image, render_image_with};
use nerf_bundle::{SCENE_FILE, SceneDescription, bundle_file, read_occupancy, read_scene};
use std::path::{Path, PathBuf};

/// Default rays marched together: their samples go to the field in one call, which
/// [`crate::OrtNetwork`] splits into pieces of [`crate::network::POINTS_PER_RUN`] points per
/// onnxruntime run (bounding onnxruntime's memory); the chunk bounds the renderer's own buffers
/// (4096 rays × 192 samples: ≈ 30 MB of points, directions and outputs). Fewer, larger
/// chunks leave fewer nearly empty calls at the end of each chunk's march (measured on a
/// hash-grid lego frame: 5.54 s at 1024 rays, 5.05 s at 4096).
pub const DEFAULT_CHUNK: usize = 4096;

/// The chunk a bundle renders with on `device` unless told otherwise: [`DEFAULT_CHUNK`] rays
/// on the CPU, [`GPU_CHUNK`] on a GPU, fewer when `samples_per_ray` per call (the dense path's
/// all, marching's [`MARCH_SEGMENT`]) would take a call past [`limits::MAX_POINTS_PER_CALL`].
pub fn default_chunk(samples_per_ray: usize, device: Device) -> usize {
    let rays = if device == Device::Cpu { DEFAULT_CHUNK } else { GPU_CHUNK };
    rays.min(limits::MAX_POINTS_PER_CALL / samples_per_ray.max(1)).max(1)
}

/// How to open a bundle.
#[derive(Debug, Clone, PartialEq)]
pub struct OpenOptions {
    /// Sessions run side by side, one thread each (`None`: one per core); see
    /// [`crate::network::Threading`].
    pub threads: Option<usize>,
    /// The most points per onnxruntime call of one session.
    pub points_per_run: usize,
    /// Rays per onnxruntime call (bounds memory). `None`: [`default_chunk`] for the device.
    pub chunk: Option<usize>,
    /// Use the bundle's occupancy grid (when it has one) to skip empty space, and stop
    /// marching rays whose transmittance is below 1e-4 (early termination).
    pub skip_empty_space: bool,
    /// Run a hash-grid graph whole in onnxruntime instead of its encoding in Rust and its head
    /// in onnxruntime ([`crate::network::Encoding`]).
    pub whole_graph: bool,
    /// Where the graphs run. On a GPU, one session runs the whole graph (the Rust encoding
    /// is a CPU optimisation) on pieces of [`GPU_POINTS_PER_RUN`] points at least.
    pub device: Device,
    /// On a GPU, with a grid: march and composite there too ([`crate::gpu`]). Off by default
    /// until it has been measured on a GPU: tested against the CPU loop with its kernels
    /// compiled for the CPU, not yet run through CUDA.
    pub gpu_loop: bool,
}

/// Rays per field call on a GPU unless told otherwise: a whole 400×400 frame marches in one
/// batch (its first round 2.56 M points), as large batches keep a GPU busy.
pub const GPU_CHUNK: usize = 1 << 18;

/// The smallest piece a GPU session evaluates per call: small pieces keep a CPU's cache warm,
/// a GPU wants large batches (measured on an H200: 26–36 M points/s at 65,536 to 4,194,304 points a call).
pub const GPU_POINTS_PER_RUN: usize = 1 << 20;

impl Default for OpenOptions {
    fn default() -> Self {
        OpenOptions { threads: None, points_per_run: POINTS_PER_RUN, chunk: None, skip_empty_space: true, whole_graph: false, device: Device::Cpu, gpu_loop: false }
    }
}

/// A bundle ready to render.
pub struct OrtScene {
    /// The bundle directory.
    pub dir: PathBuf,
    /// Its `scene.json`.
    pub description: SceneDescription,
    /// Its networks.
    pub field: OrtField,
    /// Its occupancy grid, if any and if skipping is on.
    pub occupancy: Option<OccupancyGrid>,
    /// Sampling, background and chunk.
    pub options: RenderOptions,
    /// On a GPU with a grid: the loop around the field there too (`None`: the CPU's).
    pub gpu: Option<GpuMarch>,
}

impl OrtScene {
    /// Open `dir`: read and check `scene.json`, load the graphs and the grid.
    pub fn open(dir: &Path, options: &OpenOptions) -> Result<Self> {
        if !dir.is_dir() {
            return Err(RuntimeError::bundle(dir, "no such bundle directory (write one with `nerf export --run <run> --out <dir>`)"));
        }
        let description = read_scene(dir)?;
        let occupancy = if options.skip_empty_space { read_occupancy(dir, &description)? } else { None };
        // A bounded field's box is its grid's (scene.json checks it has one).
        let bounded = description.is_bounded().then(|| description.occupancy.as_ref().map(|o| o.bound)).flatten();
        let occupancy = marching_grid(occupancy, bounded, description.contraction);
        // Marching evaluates at most MARCH_SEGMENT samples per ray per call, the dense path all.
        let s = &description.sampling;
        let samples_per_ray = if occupancy.is_some() { MARCH_SEGMENT } else { s.n_coarse + s.n_fine };
        let chunk = match options.chunk {
            Some(chunk) => {
                limits::check_chunk(chunk, samples_per_ray, Origin::Option("--chunk"))?;
                chunk
            }
            None => default_chunk(samples_per_ray, options.device),
        };
        if let Some(n) = options.threads {
            limits::check_count(n, limits::MAX_THREADS, "threads", Origin::Option("--threads"))?;
        }
        limits::check_count(options.points_per_run, limits::MAX_POINTS_PER_CALL, "points per run", Origin::Option("--points-per-run"))?;
        let on_cpu = options.device == Device::Cpu;
        let threading = if on_cpu {
            Threading { points_per_run: options.points_per_run, ..Threading::new(options.threads) }
        } else {
            Threading { workers: 1, points_per_run: options.points_per_run.max(GPU_POINTS_PER_RUN), device: options.device }
        };
        let encoding = if options.whole_graph || !on_cpu { Encoding::Graph } else { Encoding::Rust };
        let graphs = description
            .graph_files()
            .iter()
            .map(|g| Ok((g.role, OrtNetwork::load_with(&bundle_file(dir, g.file, g.key)?, threading, encoding)?)))
            .collect::<Result<Vec<_>>>()?;
        let mut render_options =
            RenderOptions::new(description.sampling.clone(), description.white_background, chunk, options.skip_empty_space);
        render_options.march_steps = description.march_steps;
        // A GPU evaluates while the CPU marches the other half of the rays (the CPU loop).
        render_options.overlap = !on_cpu;
        let gpu = match (options.device, &occupancy) {
            (Device::Cuda(ordinal), Some(grid)) if options.gpu_loop => match GpuMarch::new(ordinal, grid) {
                Ok(gpu) => Some(gpu),
                Err(e) => {
                    eprintln!("warning: --device {}: the loop around the field stays on the CPU ({e})", options.device);
                    None
                }
            },
            _ => None,
        };
        Ok(OrtScene { dir: dir.to_path_buf(), description, field: OrtField { graphs }, occupancy, options: render_options, gpu })
    }

    /// The training camera, optionally at another resolution (focal lengths and principal
    /// point scaled with each side).
    pub fn camera(&self, size: Option<(u32, u32)>) -> PinholeCamera {
        let k = self.description.camera.camera;
        match size {
            Some((w, h)) => k.resized(w, h),
            None => k,
        }
    }

    /// The bundle's orbit poses (`scene.json` `poses.orbit`).
    pub fn orbit_poses(&self) -> Result<Vec<Pose>> {
        let path = self.dir.join(SCENE_FILE);
        self.description
            .poses
            .orbit
            .iter()
            .enumerate()
            .map(|(k, m)| {
                let pose = Pose::from_rows(*m);
                if pose.is_finite() { Ok(pose) } else { Err(RuntimeError::bundle(&path, format!("poses.orbit[{k}] has a non-finite entry"))) }
            })
            .collect()
    }

    /// Render one view deterministically, reporting `progress(done, total)` pixels.
    pub fn render(&mut self, camera: &PinholeCamera, pose: &Pose, progress: &mut dyn FnMut(usize, usize)) -> Result<RenderedImage> {
        let Some(gpu) = &self.gpu else {
            return render_image(&mut self.field, self.occupancy.as_ref(), camera, pose, &self.options, progress);
        };
        let stage = if self.options.sampling.n_fine > 0 { Stage::Fine } else { Stage::Coarse };
        let net = self.field.graph(stage).ok_or_else(|| RuntimeError::Other(format!("no graph of the bundle serves {stage:?} samples")))?;
        let options = &self.options;
        render_image_with(camera, pose, options, progress, &mut |rays| gpu.render_rays(net, rays, options))
    }
}
