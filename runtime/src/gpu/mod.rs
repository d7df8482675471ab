//! The loop around the field on a GPU (`--device cuda` with an occupancy grid): the kernels of
//! `python/nerf_bundle/march.cu` (the Python package's GPU loop runs the same file) march,
//! pack and composite with the rays' state in GPU memory, and onnxruntime evaluates the field
//! on the packed samples where they lie (IO binding). The samples, the field calls' points
//! and the compositing's float32 operations are those of the CPU loop
//! ([`nerf_core::render::grid`]): each round marches every live ray to its next
//! [`MARCH_SEGMENT`] occupied samples, one field call evaluates them all, and a ray goes on
//! while T ≥ the threshold and its segment was full.

pub mod cuda;
#[cfg(test)]
mod host;

use crate::error::{Result, RuntimeError};
use crate::network::OrtNetwork;
use cuda::{Cuda, DevicePtr, Module};
use nerf_core::camera::{Rays, length};
use nerf_core::render::compositing::{RayOutput, over_white};
use nerf_core::render::{MARCH_SEGMENT, RenderOptions};
use nerf_core::sample::occupancy::OccupancyGrid;

/// The kernels, shared with the Python package.
const KERNELS: &str = include_str!("../../../python/nerf_bundle/march.cu");

/// A kernel argument, passed by value.
#[derive(Clone, Copy)]
pub enum Arg {
    /// A device address.
    Ptr(DevicePtr),
    /// `int`.
    I32(i32),
    /// `float`.
    F32(f32),
}

/// A launch's parameter list: the address of each argument's value (`cuLaunchKernel`'s
/// `kernelParams`), valid while `values` is.
fn parameters(values: &mut [Arg]) -> Vec<*mut std::ffi::c_void> {
    values
        .iter_mut()
        .map(|a| match a {
            Arg::Ptr(p) => (p as *mut DevicePtr).cast(),
            Arg::I32(v) => (v as *mut i32).cast(),
            Arg::F32(v) => (v as *mut f32).cast(),
        })
        .collect()
}

/// Memory where the kernels run.
pub trait Buffer {
    /// Its address.
    fn ptr(&self) -> DevicePtr;
    /// Copy `data` to its start.
    fn write<T: Copy>(&self, data: &[T]) -> std::result::Result<(), String>;
    /// Copy its start into `out`.
    fn read<T: Copy>(&self, out: &mut [T]) -> std::result::Result<(), String>;
}

/// What the loop needs of a GPU: memory, the kernels of `march.cu`, a barrier. The CUDA one
/// ([`CudaKernels`]); the tests' runs the same kernels compiled for the CPU.
pub trait Backend {
    /// Its memory.
    type Buffer: Buffer;
    /// `bytes` of memory.
    fn alloc(&self, bytes: usize) -> std::result::Result<Self::Buffer, String>;
    /// Run kernel `name` on `threads` threads with `args` (queued).
    fn launch(&self, name: &str, threads: usize, args: &[Arg]) -> std::result::Result<(), String>;
    /// Wait for the work queued so far.
    fn synchronize(&self) -> std::result::Result<(), String>;
    /// Make the backend usable on this thread.
    fn bind(&self) -> std::result::Result<(), String>;
}

/// A copy of `data` in `backend`'s memory.
fn upload<B: Backend, T: Copy>(backend: &B, data: &[T]) -> std::result::Result<B::Buffer, String> {
    let buffer = backend.alloc(std::mem::size_of_val(data))?;
    buffer.write(data)?;
    Ok(buffer)
}

/// The kernels compiled by NVRTC for one GPU.
pub struct CudaKernels {
    cuda: Cuda,
    module: Module,
}

impl Backend for CudaKernels {
    type Buffer = cuda::DeviceBuffer;
    fn alloc(&self, bytes: usize) -> std::result::Result<Self::Buffer, String> {
        self.cuda.alloc(bytes)
    }
    fn launch(&self, name: &str, threads: usize, args: &[Arg]) -> std::result::Result<(), String> {
        self.module.launch(name, threads, args)
    }
    fn synchronize(&self) -> std::result::Result<(), String> {
        self.cuda.synchronize()
    }
    fn bind(&self) -> std::result::Result<(), String> {
        self.cuda.bind()
    }
}

/// The kernels and the padded grid on one GPU.
pub struct GpuMarch<B: Backend = CudaKernels> {
    backend: B,
    /// The grid with one empty cell on every side, one byte per cell.
    padded: B::Buffer,
    resolution: usize,
    bound: f32,
}

impl GpuMarch {
    /// Compile the kernels for GPU `ordinal` and upload `grid`.
    pub fn new(ordinal: u32, grid: &OccupancyGrid) -> std::result::Result<Self, String> {
        let cuda = Cuda::new(ordinal)?;
        let module = cuda.module(&kernel_source(), &["--fmad=false"])?;
        GpuMarch::with_backend(CudaKernels { cuda, module }, grid)
    }
}

/// `march.cu` after `#define SEGMENT`.
fn kernel_source() -> String {
    format!("#define SEGMENT {MARCH_SEGMENT}\n{KERNELS}")
}

impl<B: Backend> GpuMarch<B> {
    /// `backend` with `grid` in its memory.
    pub fn with_backend(backend: B, grid: &OccupancyGrid) -> std::result::Result<Self, String> {
        if grid.contraction().is_some() {
            return Err("the GPU loop does not march contracted grids yet".into());
        }
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
        let padded = upload(&backend, &padded)?;
        Ok(GpuMarch { backend, padded, resolution: r, bound: grid.bound() })
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
        let b = &self.backend;
        b.bind()?;
        let s = &options.sampling;
        let steps = options.march_steps.max(1);
        let interval = (s.far - s.near) / steps as f32;
        // T ≥ 0 always holds: no threshold, as the CPU loop's `T < 0` never stops a ray.
        let min_t = options.min_transmittance.unwrap_or(0.0);
        let delta: Vec<f32> = rays.directions.iter().map(|&d| interval * length(d)).collect();
        let o = upload(b, rays.origins.as_flattened())?;
        let d = upload(b, rays.directions.as_flattened())?;
        let v = upload(b, rays.view_directions().as_flattened())?;
        let delta = upload(b, &delta)?;
        let cursor = upload(b, &vec![0i32; n])?;
        let trans = upload(b, &vec![1f32; n])?;
        let (rgb, depth, acc) = (upload(b, &vec![0f32; 3 * n])?, upload(b, &vec![0f32; n])?, upload(b, &vec![0f32; n])?);
        let most = n * MARCH_SEGMENT;
        let ks = b.alloc(4 * most)?;
        let counts = b.alloc(4 * n)?;
        let offsets = b.alloc(8 * (n + 1))?;
        let (points, dirs, colour) = (b.alloc(12 * most)?, b.alloc(12 * most)?, b.alloc(12 * most)?);
        let (ts, sigma, keep) = (b.alloc(4 * most)?, b.alloc(4 * most)?, b.alloc(n)?);
        let mut active: Vec<i32> = (0..n as i32).collect();
        let active_d = upload(b, &active)?;
        let (mut counts_h, mut offsets_h, mut keep_h) = (vec![0i32; n], vec![0i64; n + 1], vec![0u8; n]);
        let grid = [Arg::Ptr(self.padded.ptr()), Arg::I32(self.resolution as i32 + 2), Arg::F32(self.bound), Arg::F32(2.0 * self.bound), Arg::F32(self.resolution as f32)];
        let ray_args = [Arg::Ptr(o.ptr()), Arg::Ptr(d.ptr())];
        while !active.is_empty() {
            let m = active.len();
            let head = [Arg::Ptr(active_d.ptr()), Arg::I32(m as i32)];
            let march = [&head[..], &ray_args, &[Arg::Ptr(cursor.ptr()), Arg::I32(steps as i32), Arg::F32(s.near), Arg::F32(interval)], &grid, &[Arg::Ptr(ks.ptr()), Arg::Ptr(counts.ptr())]].concat();
            b.launch("march", m, &march)?;
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
                &[Arg::Ptr(ks.ptr()), Arg::Ptr(counts.ptr()), Arg::Ptr(offsets.ptr())],
                &ray_args,
                &[Arg::Ptr(v.ptr()), Arg::F32(s.near), Arg::F32(interval), Arg::Ptr(points.ptr()), Arg::Ptr(dirs.ptr()), Arg::Ptr(ts.ptr())],
            ]
            .concat();
            b.launch("emit", m, &emit)?;
            b.synchronize()?;
            // SAFETY: buffers of this GPU with room for `total` ≤ `most` rows, idle until it returns.
            unsafe { net.run_on_device(total, [points.ptr(), dirs.ptr()], [colour.ptr(), sigma.ptr()]) }.map_err(Failure::Ort)?;
            let composite = [
                &head[..],
                &[Arg::Ptr(counts.ptr()), Arg::Ptr(offsets.ptr()), Arg::Ptr(sigma.ptr()), Arg::Ptr(colour.ptr()), Arg::Ptr(ts.ptr()), Arg::Ptr(delta.ptr())],
                &[Arg::Ptr(trans.ptr()), Arg::Ptr(rgb.ptr()), Arg::Ptr(depth.ptr()), Arg::Ptr(acc.ptr()), Arg::F32(min_t), Arg::Ptr(keep.ptr())],
            ]
            .concat();
            b.launch("composite", m, &composite)?;
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

#[cfg(test)]
mod tests {
    use super::host::HostKernels;
    use super::*;
    use crate::{OpenOptions, OrtScene};
    use nerf_core::camera::Pose;
    use nerf_core::render::grid;

    /// The loop with the kernels compiled for the CPU against the CPU loop
    /// (`nerf_core::render::grid`), on the same onnxruntime session: the same samples (points
    /// evaluated) and the same pixels.
    fn assert_same_as_the_cpu_loop(scene: &mut OrtScene, kernels: HostKernels, rays: &Rays, what: &str) {
        let grid = scene.occupancy.clone().expect("a grid");
        let expected = grid::render_rays(&mut scene.field, &grid, rays, &scene.options).unwrap();
        let net = &mut scene.field.graphs[0].1;
        let evaluated = net.evaluated;
        let gpu = GpuMarch::with_backend(kernels, &grid).unwrap();
        let got = gpu.render_rays(net, rays, &scene.options).unwrap();
        assert_eq!(net.evaluated - evaluated, evaluated, "{what}: the same samples");
        assert!(evaluated > rays.len(), "{what}: the rays see the model ({evaluated} points)");
        let worst = expected
            .iter()
            .zip(&got)
            .flat_map(|(a, b)| a.rgb.iter().zip(&b.rgb).map(|(x, y)| (x - y).abs()).chain([(a.depth - b.depth).abs(), (a.acc - b.acc).abs()]))
            .fold(0.0f32, f32::max);
        assert!(worst <= 1e-6, "{what}: max |Δ| {worst:e}");
    }

    fn lego() -> Option<(OrtScene, HostKernels)> {
        let kernels = match HostKernels::compile() {
            Ok(k) => k,
            Err(e) => {
                eprintln!("skipped: no C++ compiler for the kernels ({e})");
                return None;
            }
        };
        let bundle = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/lego-ngp");
        let scene = OrtScene::open(&bundle, &OpenOptions { whole_graph: true, threads: Some(1), ..OpenOptions::default() }).unwrap();
        Some((scene, kernels))
    }

    /// Run `test` on a thread and fail if it has not finished within two minutes (a lock taken
    /// twice on the way to onnxruntime would otherwise hang the suite).
    fn within_two_minutes(test: impl FnOnce() + Send + 'static) {
        let (done, finished) = std::sync::mpsc::channel();
        let handle = std::thread::spawn(move || {
            test();
            done.send(()).ok();
        });
        match finished.recv_timeout(std::time::Duration::from_secs(120)) {
            Ok(()) => handle.join().unwrap(),
            // The thread panicked: its panic, as the test's.
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => std::panic::resume_unwind(handle.join().unwrap_err()),
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => panic!("the GPU loop did not finish in two minutes (a deadlock?)"),
        }
    }

    #[test]
    fn the_kernels_render_the_cpu_loops_frame() {
        within_two_minutes(|| {
            let Some((mut scene, kernels)) = lego() else { return };
            let k = scene.camera(Some((48, 48)));
            let pose = Pose::from_rows(scene.description.poses.test[0].transform_matrix);
            let rays = scene.options.sampling.warp_rays(Rays::for_rows(&k, &pose, 0..48));
            assert_same_as_the_cpu_loop(&mut scene, kernels, &rays, "test view 0 at 48×48");
        });
    }

    #[test]
    fn the_kernels_march_degenerate_rays_as_the_cpu_loop() {
        within_two_minutes(degenerate_rays);
    }

    fn degenerate_rays() {
        let Some((mut scene, kernels)) = lego() else { return };
        let (b, r) = (scene.occupancy.as_ref().unwrap().bound(), scene.occupancy.as_ref().unwrap().resolution());
        let face = -b + 2.0 * b * (r / 3) as f32 / r as f32;
        let mut rng = nerf_core::Rng::new(5);
        let mut rays = Rays { origins: vec![], directions: vec![], viewdirs: None };
        for i in 0..400 {
            // From a sphere of radius 4 towards points near the model.
            let u = [rng.uniform() * 2.0 - 1.0, rng.uniform() * 2.0 - 1.0, rng.uniform() * 2.0 - 1.0];
            let o = u.map(|x| x * 4.0 / length(u));
            let target = [rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5];
            let d = [target[0] - o[0], target[1] - o[1], target[2] - o[2]];
            let (o, d) = match i % 8 {
                0 => (o, [0.0; 3]),                       // no direction
                1 => (o, [d[0], 0.0, 0.0]),               // along an axis
                2 => ([face, o[1], o[2]], [0.0, d[1], d[2]]), // on a cell face
                3 => ([100.0; 3], d),                     // far outside
                _ => (o, d.map(|x| x / length(d))),
            };
            rays.origins.push(o);
            rays.directions.push(d);
        }
        assert_same_as_the_cpu_loop(&mut scene, kernels, &rays, "degenerate rays");
    }
}
