//! The loop around the field on a GPU (`--device cuda` with an occupancy grid): the kernels of
//! `python/nerf_bundle/march.cu` (the Python package's GPU loop runs the same file) march,
//! pack and composite with the rays' state in GPU memory, and onnxruntime evaluates the field
//! on the packed samples where they lie (IO binding). The samples, the field calls' points
//! and the compositing's float32 operations are those of the CPU loop
//! ([`nerf_core::render::grid`]): each round marches every live ray to its next
//! [`MARCH_SEGMENT`] occupied samples, one field call evaluates them all, and a ray goes on
//! while T ≥ the threshold and its segment was full.

pub mod cuda;

use crate::error::{Result, RuntimeError};
use crate::network::OrtNetwork;
use cuda::{Arg, Cuda, DeviceBuffer, Module};
use nerf_core::camera::{Rays, length};
use nerf_core::render::compositing::{RayOutput, over_white};
use nerf_core::render::{MARCH_SEGMENT, RenderOptions};
use nerf_core::sample::occupancy::OccupancyGrid;

/// The kernels, shared with the Python package.
const KERNELS: &str = include_str!("../../../python/nerf_bundle/march.cu");

/// The compiled kernels and the padded grid on one GPU.
pub struct GpuMarch {
    cuda: Cuda,
    module: Module,
    /// The grid with one empty cell on every side, one byte per cell.
    padded: DeviceBuffer,
    resolution: usize,
    bound: f32,
}

impl GpuMarch {
    /// Compile the kernels for GPU `ordinal` and upload `grid`.
    pub fn new(ordinal: u32, grid: &OccupancyGrid) -> std::result::Result<Self, String> {
        let cuda = Cuda::new(ordinal)?;
        let module = cuda.module(&format!("#define SEGMENT {MARCH_SEGMENT}\n{KERNELS}"), &["--fmad=false"])?;
        let r = grid.resolution();
        let side = r + 2;
        let mut padded = vec![0u8; side * side * side];
        for i in 0..r {
            for j in 0..r {
                for k in 0..r {
                    padded[((i + 1) * side + j + 1) * side + k + 1] = grid.is_cell_occupied((i * r + j) * r + k) as u8;
                }
            }
        }
        let padded = cuda.upload(&padded)?;
        Ok(GpuMarch { cuda, module, padded, resolution: r, bound: grid.bound() })
    }

    /// Render `rays` through `net` (a session on this GPU): the CPU loop's outputs.
    pub fn render_rays(&self, net: &mut OrtNetwork, rays: &Rays, options: &RenderOptions) -> Result<Vec<RayOutput>> {
        self.march(net, rays, options).map_err(|e| match e {
            Failure::Cuda(message) => RuntimeError::Other(format!("the GPU loop: {message}")),
            Failure::Ort(e) => e,
        })
    }

    fn march(&self, net: &mut OrtNetwork, rays: &Rays, options: &RenderOptions) -> std::result::Result<Vec<RayOutput>, Failure> {
        let n = rays.len();
        if n == 0 {
            return Ok(vec![]);
        }
        let cuda = &self.cuda;
        cuda.bind()?;
        let s = &options.sampling;
        let steps = options.march_steps.max(1);
        let interval = (s.far - s.near) / steps as f32;
        // T ≥ 0 always holds: no threshold, as the CPU loop's `T < 0` never stops a ray.
        let min_t = options.min_transmittance.unwrap_or(0.0);
        let delta: Vec<f32> = rays.directions.iter().map(|&d| interval * length(d)).collect();
        let o = cuda.upload(rays.origins.as_flattened())?;
        let d = cuda.upload(rays.directions.as_flattened())?;
        let v = cuda.upload(rays.view_directions().as_flattened())?;
        let delta = cuda.upload(&delta)?;
        let cursor = cuda.upload(&vec![0i32; n])?;
        let trans = cuda.upload(&vec![1f32; n])?;
        let (rgb, depth, acc) = (cuda.upload(&vec![0f32; 3 * n])?, cuda.upload(&vec![0f32; n])?, cuda.upload(&vec![0f32; n])?);
        let most = n * MARCH_SEGMENT;
        let ks = cuda.alloc(4 * most)?;
        let counts = cuda.alloc(4 * n)?;
        let offsets = cuda.alloc(8 * (n + 1))?;
        let (points, dirs, colour) = (cuda.alloc(12 * most)?, cuda.alloc(12 * most)?, cuda.alloc(12 * most)?);
        let (ts, sigma, keep) = (cuda.alloc(4 * most)?, cuda.alloc(4 * most)?, cuda.alloc(n)?);
        let mut active: Vec<i32> = (0..n as i32).collect();
        let active_d = cuda.upload(&active)?;
        let (mut counts_h, mut offsets_h, mut keep_h) = (vec![0i32; n], vec![0i64; n + 1], vec![0u8; n]);
        let grid = [Arg::Ptr(self.padded.ptr), Arg::I32(self.resolution as i32 + 2), Arg::F32(self.bound), Arg::F32(2.0 * self.bound), Arg::F32(self.resolution as f32)];
        let ray_args = [Arg::Ptr(o.ptr), Arg::Ptr(d.ptr)];
        while !active.is_empty() {
            let m = active.len();
            let head = [Arg::Ptr(active_d.ptr), Arg::I32(m as i32)];
            let march = [&head[..], &ray_args, &[Arg::Ptr(cursor.ptr), Arg::I32(steps as i32), Arg::F32(s.near), Arg::F32(interval)], &grid, &[Arg::Ptr(ks.ptr), Arg::Ptr(counts.ptr)]].concat();
            self.module.launch("march", m, &march)?;
            counts.read(&mut counts_h[..m])?;
            for i in 0..m {
                offsets_h[i + 1] = offsets_h[i] + counts_h[i] as i64;
            }
            let total = offsets_h[m] as usize;
            if total == 0 {
                break;
            }
            offsets.write(&offsets_h[..m + 1])?;
            let emit = [
                &head[..],
                &[Arg::Ptr(ks.ptr), Arg::Ptr(counts.ptr), Arg::Ptr(offsets.ptr)],
                &ray_args,
                &[Arg::Ptr(v.ptr), Arg::F32(s.near), Arg::F32(interval), Arg::Ptr(points.ptr), Arg::Ptr(dirs.ptr), Arg::Ptr(ts.ptr)],
            ]
            .concat();
            self.module.launch("emit", m, &emit)?;
            cuda.synchronize()?;
            // SAFETY: buffers of this GPU with room for `total` ≤ `most` rows, idle until it returns.
            unsafe { net.run_on_device(total, [points.ptr, dirs.ptr], [colour.ptr, sigma.ptr]) }.map_err(Failure::Ort)?;
            let composite = [
                &head[..],
                &[Arg::Ptr(counts.ptr), Arg::Ptr(offsets.ptr), Arg::Ptr(sigma.ptr), Arg::Ptr(colour.ptr), Arg::Ptr(ts.ptr), Arg::Ptr(delta.ptr)],
                &[Arg::Ptr(trans.ptr), Arg::Ptr(rgb.ptr), Arg::Ptr(depth.ptr), Arg::Ptr(acc.ptr), Arg::F32(min_t), Arg::Ptr(keep.ptr)],
            ]
            .concat();
            self.module.launch("composite", m, &composite)?;
            keep.read(&mut keep_h[..m])?;
            let mut kept = 0;
            for i in 0..m {
                if keep_h[i] != 0 {
                    active[kept] = active[i];
                    kept += 1;
                }
            }
            active.truncate(kept);
            if kept > 0 {
                active_d.write(&active)?;
            }
        }
        let (mut rgb_h, mut depth_h, mut acc_h) = (vec![[0f32; 3]; n], vec![0f32; n], vec![0f32; n]);
        rgb.read(rgb_h.as_flattened_mut())?;
        depth.read(&mut depth_h)?;
        acc.read(&mut acc_h)?;
        Ok((0..n)
            .map(|r| {
                let rgb = if options.white_background { over_white(rgb_h[r], acc_h[r]) } else { rgb_h[r] };
                RayOutput { rgb, depth: depth_h[r], acc: acc_h[r] }
            })
            .collect())
    }
}

/// Why a round failed: the GPU, or onnxruntime (already a [`RuntimeError`]).
enum Failure {
    Cuda(String),
    Ort(RuntimeError),
}

impl From<String> for Failure {
    fn from(message: String) -> Self {
        Failure::Cuda(message)
    }
}
