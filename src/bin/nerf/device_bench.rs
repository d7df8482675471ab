//! `nerf bench --only render`'s hash-grid part: one view of a hash-grid bundle through
//! nerf-render's renderer on each device asked for, with each lowering of its field, the frame
//! split into the field's share (onnxruntime's runs, and the Rust encoding on the CPU's split
//! path) and the loop's (rays, marching, compositing: everything else). Each frame is checked
//! against the CPU's split frame of the same lowering.

use anyhow::{Result, bail};
use nerf::bench::timed_frame;
use nerf_core::camera::Pose;
use nerf_core::render::RenderedImage;
use nerf_export::{CompileOptions, write_bundle};
use nerf_runtime::environment::Device;
use nerf_runtime::{OpenOptions, OrtScene};
use std::path::Path;

/// One frame: a device, a lowering and a path through it.
#[derive(Debug, serde::Serialize)]
pub struct DeviceFrame {
    /// `cpu` or `cuda:N`.
    pub device: String,
    /// `bitwise` (the default export) or `portable` (`nerf export --portable`).
    pub lowering: String,
    /// `split` (the Rust encoding, the graph's head in onnxruntime: the CPU default), `whole
    /// graph`, or `GPU loop` (the whole graph, marching and compositing on the GPU too).
    pub path: String,
    /// Seconds for the frame, the best of the timed renders.
    pub seconds: f64,
    /// Of which in onnxruntime's runs.
    pub onnxruntime_s: f64,
    /// Of which in the Rust hash encoding (split path).
    pub encoding_s: f64,
    /// The rest: rays, marching, packing, compositing.
    pub loop_s: f64,
    /// The slowest timed render (a GPU's first one pays its start-up: it is not timed).
    pub worst_s: f64,
    /// Field evaluations per pixel.
    pub points_per_pixel: f64,
    /// Largest |Δ| of rgb, depth and acc against the CPU split frame of the same lowering.
    pub max_abs_vs_cpu: f32,
}

/// Render `bundle`'s first test view on each of `devices`, bitwise and portable: the CPU's split
/// path, and the whole graph on each device; `repeats` (at least 1) timed renders each after
/// one untimed one.
pub fn bench_device_frames(bundle: &Path, devices: &[Device], repeats: usize, progress: bool) -> Result<Vec<DeviceFrame>> {
    let (compiled, tables) = nerf::export::ngp_bundle(bundle)?;
    let Some(view) = compiled.scene.poses.test.first() else { bail!("{}: scene.json has no poses.test to render", bundle.display()) };
    let pose = Pose::from_rows(view.transform_matrix);
    let temporary = tempfile::tempdir()?;
    let mut frames = Vec::new();
    for (lowering, portable) in [("bitwise", false), ("portable", true)] {
        let options = CompileOptions { portable, tables, ..Default::default() };
        let dir = temporary.path().join(lowering);
        write_bundle(&dir, &compiled, &options)?;
        let mut reference: Option<RenderedImage> = None;
        // The CPU split frame always (the reference), the whole graph on each device asked for,
        // and on a GPU the GPU loop too.
        let mut paths = vec![(Device::Cpu, "split", false, false)];
        for &d in devices {
            paths.push((d, "whole graph", true, false));
            if d != Device::Cpu {
                paths.push((d, "GPU loop", true, true));
            }
        }
        for (device, path, whole_graph, gpu_loop) in paths {
            let mut ort = OrtScene::open(&dir, &OpenOptions { whole_graph, device, gpu_loop, ..OpenOptions::default() })?;
            // Where the GPU loop cannot start (its warning says why), the CPU loop's frame.
            let path = if gpu_loop && ort.gpu.is_none() { "GPU loop (unavailable: CPU loop)" } else { path };
            let k = ort.camera(None);
            let label = format!("{device} {lowering} {path}");
            let mut image = None;
            let (mut best, mut worst, mut best_split) = (f64::INFINITY, 0.0f64, (0.0, 0.0));
            for run in 0..=repeats.max(1) {
                let net = &ort.field.graphs[0].1;
                let (ort_before, encoding_before, evaluated_before) = (net.seconds, net.encoding_seconds, net.evaluated);
                let (rendered, seconds) = timed_frame(progress, &label, k.num_pixels(), |p| ort.render(&k, &pose, p));
                let net = &ort.field.graphs[0].1;
                let split = (net.seconds - ort_before, net.encoding_seconds - encoding_before);
                let evaluated = net.evaluated - evaluated_before;
                image = Some((rendered?, evaluated));
                if run == 0 {
                    continue;
                }
                worst = worst.max(seconds);
                if seconds < best {
                    (best, best_split) = (seconds, split);
                }
            }
            let (image, evaluated) = image.expect("rendered at least once");
            let max_abs_vs_cpu = reference.as_ref().map_or(0.0, |r| max_abs(r, &image));
            frames.push(DeviceFrame {
                device: device.to_string(),
                lowering: lowering.into(),
                path: path.into(),
                seconds: best,
                onnxruntime_s: best_split.0,
                encoding_s: best_split.1,
                loop_s: best - best_split.0 - best_split.1,
                worst_s: worst,
                points_per_pixel: evaluated as f64 / k.num_pixels() as f64,
                max_abs_vs_cpu,
            });
            reference.get_or_insert(image);
        }
    }
    Ok(frames)
}

/// Largest |Δ| over rgb, depth and acc of two renders of one view.
fn max_abs(a: &RenderedImage, b: &RenderedImage) -> f32 {
    let (a, b) = (&a.rays, &b.rays);
    let rgb = a.rgb.iter().flatten().zip(b.rgb.iter().flatten());
    rgb.chain(a.depth.iter().zip(&b.depth)).chain(a.acc.iter().zip(&b.acc)).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}
