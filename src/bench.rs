//! `nerf bench`: training-step, network and frame timings measured in one run, so ratios
//! between them are fair on a shared, noisy machine.

use crate::export::model_bundle;
use crate::field::{NerfMlp, NerfModel};
use crate::inference::{BurnField, vec3_tensor};
use crate::train::{Preset, StepTiming, Trainer};
use nerf_core::camera::{Intrinsics, Pose};
use nerf_core::dataset::{Split, SyntheticSceneConfig, generate_scene, load_split};
use nerf_core::metrics::psnr;
use nerf_core::network::{NetworkSpec, PlainNetwork};
use nerf_core::occupancy::render_image_with;
use nerf_core::Rng;
use nerf_export::write_bundle;
use nerf_runtime::{OpenOptions, OrtNetwork, OrtScene};
use std::path::Path;
use std::time::Instant;

/// Mean timings of one preset's training step.
#[derive(Debug, Clone, serde::Serialize)]
pub struct StepBench {
    /// Preset measured.
    pub preset: String,
    /// Rays per step.
    pub batch_rays: usize,
    /// Steps timed (after the warm-up ones).
    pub steps: usize,
    /// Mean seconds per step.
    pub step_s: f64,
    /// Mean seconds in the forward passes (including batch and sampling).
    pub forward_s: f64,
    /// Mean seconds in backpropagation.
    pub backward_s: f64,
    /// Mean seconds in the Adam update.
    pub update_s: f64,
}

/// Time `steps` training steps of `preset` (after `warmup` untimed ones) on the scene in `data`,
/// or on a generated scene when `data` is `None`. Precrop is off so every step is full-size.
pub fn bench_train_step(preset: Preset, data: Option<&Path>, downscale: u32, warmup: usize, steps: usize) -> Result<StepBench, String> {
    let generated;
    let dir = match data {
        Some(d) => d,
        None => {
            generated = tempfile::tempdir().map_err(|e| e.to_string())?;
            generate_scene(generated.path(), &SyntheticSceneConfig::default()).map_err(|e| e.to_string())?;
            generated.path()
        }
    };
    let train = load_split(dir, Split::Train, downscale, true).map_err(|e| e.to_string())?;
    let mut config = preset.config();
    config.precrop_iters = 0;
    let batch_rays = config.batch_rays;
    let mut trainer = Trainer::new(config, train, crate::backend::cpu_autodiff())?;
    for _ in 0..warmup {
        trainer.step();
    }
    let mut total = StepTiming::default();
    for _ in 0..steps {
        let t = trainer.step().timing;
        total.forward_s += t.forward_s;
        total.backward_s += t.backward_s;
        total.update_s += t.update_s;
    }
    let n = steps.max(1) as f64;
    Ok(StepBench {
        preset: preset.name().to_string(),
        batch_rays,
        steps,
        step_s: (total.forward_s + total.backward_s + total.update_s) / n,
        forward_s: total.forward_s / n,
        backward_s: total.backward_s / n,
        update_s: total.update_s / n,
    })
}

/// The nerf-pytorch-style paper step of `scripts/pytorch_step.py`, as it reports it.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct PytorchStep {
    /// PyTorch version.
    pub torch: String,
    /// Intra-op threads.
    pub threads: usize,
    /// Mean seconds per step.
    pub step_s: f64,
    /// Mean seconds in the forward pass.
    pub forward_s: f64,
    /// Mean seconds in backpropagation.
    pub backward_s: f64,
    /// Mean seconds in the Adam update.
    pub update_s: f64,
    /// Peak RSS of the Python process.
    pub peak_rss_mb: f64,
}

/// Run `scripts/pytorch_step.py` with `python` (which must have PyTorch) for `steps` timed
/// steps on two threads.
pub fn bench_pytorch_step(python: &Path, steps: usize) -> Result<PytorchStep, String> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/pytorch_step.py");
    let out = tempfile::NamedTempFile::new().map_err(|e| e.to_string())?;
    let status = std::process::Command::new(python)
        .arg(&script)
        .args(["--steps", &steps.to_string(), "--threads", "2", "--json"])
        .arg(out.path())
        .stdout(std::process::Stdio::null())
        .status()
        .map_err(|e| format!("{}: {e}", python.display()))?;
    if !status.success() {
        return Err(format!("{} {} failed ({status}); does that Python have PyTorch?", python.display(), script.display()));
    }
    let text = std::fs::read_to_string(out.path()).map_err(|e| e.to_string())?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", script.display()))
}

/// Forward throughput of one network on a batch of points.
#[derive(Debug, Clone, serde::Serialize)]
pub struct MlpBench {
    /// `burn` or `onnxruntime`.
    pub backend: String,
    /// Points per forward pass.
    pub points: usize,
    /// Best seconds per forward pass (encoding included).
    pub seconds: f64,
    /// Dense-layer GFLOP/s (2 · multiply-adds per point · points / seconds, counting the
    /// multiply-adds this backend performs: burn folds the feature layer away; the encoding's
    /// work is timed but not counted).
    pub gflops: f64,
}

/// `n` seeded random points in [−1.5, 1.5]³ and unit directions.
pub fn random_points(n: usize, seed: u64) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let mut rng = Rng::new(seed);
    let points = (0..n).map(|_| [0; 3].map(|_: i32| rng.uniform() * 3.0 - 1.5)).collect();
    let dirs = (0..n)
        .map(|_| {
            let v = [0; 3].map(|_: i32| rng.uniform() * 2.0 - 1.0);
            let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-3);
            v.map(|x| x / norm)
        })
        .collect();
    (points, dirs)
}

fn best_of(repeats: usize, mut f: impl FnMut() -> Result<(), String>) -> Result<f64, String> {
    f()?; // warm-up: allocations, onnxruntime's first-run setup
    let mut best = f64::INFINITY;
    for _ in 0..repeats.max(1) {
        let start = Instant::now();
        f()?;
        best = best.min(start.elapsed().as_secs_f64());
    }
    Ok(best)
}

/// The paper network (seeded weights) in burn and through onnxruntime on the same `points`
/// random inputs: best of `repeats` forward passes each.
pub fn bench_mlp(points: usize, repeats: usize) -> Result<Vec<MlpBench>, String> {
    let plain = PlainNetwork::seeded(&NetworkSpec::paper(), 1);
    let flops = |macs: usize| 2.0 * macs as f64 * points as f64;
    let (p, d) = random_points(points, 2);
    let device = crate::backend::cpu();
    let net = NerfMlp::from_plain(&plain, &device)?;
    let burn_s = best_of(repeats, || {
        let (rgb, sigma) = net.forward(vec3_tensor(&p, &device), vec3_tensor(&d, &device));
        let _ = (rgb.into_data(), sigma.into_data());
        Ok(())
    })?;
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let path = dir.path().join("paper.onnx");
    let model = nerf_export::compile(&plain, "coarse", nerf_export::DEFAULT_OPSET, &[]).map_err(|e| e.to_string())?;
    nerf_core::error::write_atomic(&path, &prost::Message::encode_to_vec(&model)).map_err(|e| e.to_string())?;
    let mut ort = OrtNetwork::load(&path, None).map_err(|e| e.to_string())?;
    let ort_s = best_of(repeats, || ort.run(&p, &d).map(|_| ()).map_err(|e| e.to_string()))?;
    Ok([("burn", burn_s, net.macs_per_point()), ("onnxruntime", ort_s, plain.spec.macs_per_point())]
        .into_iter()
        .map(|(backend, seconds, macs)| MlpBench { backend: backend.into(), points, seconds, gflops: flops(macs) / seconds / 1e9 })
        .collect())
}

/// One rendered frame's time.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FrameBench {
    /// `burn` or `onnxruntime`.
    pub backend: String,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Samples per ray (coarse + fine).
    pub samples: String,
    /// Seconds for the frame.
    pub seconds: f64,
    /// PSNR of this frame against the burn frame of the same size (∞ for burn itself).
    pub psnr_vs_burn_db: f32,
}

/// The lego validation pose r_0 and camera from `data` (or, without data, the reference orbit's
/// first pose and lego's field of view): frame times are the same for any pose on the dense path.
fn bench_view(data: Option<&Path>) -> Result<(Intrinsics, Pose), String> {
    match data {
        Some(dir) => {
            let val = load_split(dir, Split::Val, 1, false).map_err(|e| e.to_string())?;
            Ok((val.intrinsics, val.views[0].pose))
        }
        None => Ok((Intrinsics::from_camera_angle_x(800, 800, nerf_core::dataset::CAMERA_ANGLE_X), Pose::orbit(1)[0])),
    }
}

/// Render one frame per size with the paper network (seeded weights; 64 + 128 samples, dense)
/// through burn and through onnxruntime (the exported graphs, as `nerf-render` runs them).
pub fn bench_frames(data: Option<&Path>, sizes: &[u32], chunk: usize, progress: bool) -> Result<Vec<FrameBench>, String> {
    let (camera, pose) = bench_view(data)?;
    let mut config = Preset::Paper.config();
    config.chunk = chunk;
    let plain = PlainNetwork::seeded(&config.network, 3);
    let fine_plain = PlainNetwork::seeded(&config.network, 4);
    let device = crate::backend::cpu();
    let model = NerfModel { coarse: NerfMlp::from_plain(&plain, &device)?, fine: Some(NerfMlp::from_plain(&fine_plain, &device)?) };
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let bundle = dir.path().join("bundle");
    write_bundle(&bundle, &model_bundle(&model, &config, &camera, None), nerf_export::DEFAULT_OPSET).map_err(|e| e.to_string())?;
    let options = OpenOptions { threads: None, chunk, skip_empty_space: false };
    let mut scene = OrtScene::open(&bundle, &options).map_err(|e| e.to_string())?;
    let render_options = crate::train::render_options(&config);
    let samples = format!("{} + {}", config.sampling.n_coarse, config.sampling.n_fine);
    let mut out = Vec::new();
    for &size in sizes {
        let k = camera.resized(size, size);
        let field = BurnField { model: &model, device: device.clone() };
        let (Ok(burn), burn_s) =
            timed_frame(progress, &format!("burn {size}×{size}"), k.num_pixels(), |p| render_image_with(field, None, &k, &pose, &render_options, p));
        let (ort, ort_s) = timed_frame(progress, &format!("onnxruntime {size}×{size}"), k.num_pixels(), |p| scene.render(&k, &pose, p));
        let ort = ort.map_err(|e| e.to_string())?;
        for (backend, seconds, psnr_vs_burn_db) in [("burn", burn_s, f32::INFINITY), ("onnxruntime", ort_s, psnr(&ort.rays.rgb, &burn.rays.rgb))] {
            out.push(FrameBench { backend: backend.into(), width: size, height: size, samples: samples.clone(), seconds, psnr_vs_burn_db });
        }
    }
    Ok(out)
}

/// `render(progress)` under a progress bar labelled `what` over `pixels`, and its seconds.
fn timed_frame<R>(show: bool, what: &str, pixels: usize, render: impl FnOnce(&mut dyn FnMut(usize, usize)) -> R) -> (R, f64) {
    let bar = nerf_core::frames::frame_bar(show, what);
    bar.set_length(pixels as u64);
    let start = Instant::now();
    let out = render(&mut |done, _| bar.set_position(done as u64));
    let seconds = start.elapsed().as_secs_f64();
    bar.finish_and_clear();
    (out, seconds)
}

/// Rendering lego val views through onnxruntime (as `nerf-render` does) with the dense path and
/// with empty-space skipping + early termination, both with `n_coarse + n_fine` samples.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SkipBench {
    /// Views rendered (val r_0, r_1, …).
    pub views: usize,
    /// Image size.
    pub width: u32,
    /// Image size.
    pub height: u32,
    /// Samples per ray, as "coarse + fine".
    pub samples: String,
    /// Mean seconds per frame, dense.
    pub dense_s: f64,
    /// Mean seconds per frame, skipping empty space and terminating early.
    pub skip_s: f64,
    /// Mean PSNR against the images, dense.
    pub dense_psnr_db: f32,
    /// Mean PSNR against the images, skipping.
    pub skip_psnr_db: f32,
    /// Network evaluations per ray (coarse + fine), dense.
    pub dense_points_per_ray: f64,
    /// Network evaluations per ray (coarse + fine), skipping.
    pub skip_points_per_ray: f64,
}

/// Render the first `views` val views of `data` at `1/downscale` through the bundle at `bundle`,
/// dense and skipping, with `n_coarse + n_fine` samples per ray.
pub fn bench_skipping(bundle: &Path, data: &Path, downscale: u32, views: usize, samples: (usize, usize), march: (usize, Option<f32>), progress: bool) -> Result<SkipBench, String> {
    let mut val = load_split(data, Split::Val, downscale, true).map_err(|e| e.to_string())?;
    val.views.truncate(views.max(1));
    let measure = |skip: bool| -> Result<(f64, f32, f64), String> {
        let options = OpenOptions { threads: None, chunk: nerf_runtime::scene::DEFAULT_CHUNK, skip_empty_space: skip };
        let mut scene = OrtScene::open(bundle, &options).map_err(|e| e.to_string())?;
        if skip && scene.occupancy.is_none() {
            return Err(format!("{}: the bundle has no occupancy grid to skip with", bundle.display()));
        }
        (scene.options.sampling.n_coarse, scene.options.sampling.n_fine) = samples;
        scene.options.march_steps = march.0;
        if let Some(threshold) = march.1 {
            scene.occupancy = scene.occupancy.take().map(|g| g.with_threshold(threshold));
        }
        let (mut seconds, mut db) = (0.0, 0.0);
        for view in &val.views {
            let label = format!("{} {}", if skip { "skip" } else { "dense" }, view.name);
            let (image, s) = timed_frame(progress, &label, val.intrinsics.num_pixels(), |p| scene.render(&val.intrinsics, &view.pose, p));
            let image = image.map_err(|e| e.to_string())?;
            seconds += s;
            db += psnr(&image.rays.rgb, view.image.as_ref().expect("loaded with images"));
        }
        let n = val.views.len();
        let f = &scene.field;
        let points = f.coarse.evaluated + f.fine.as_ref().map_or(0, |n| n.evaluated);
        Ok((seconds / n as f64, db / n as f32, points as f64 / (n * val.intrinsics.num_pixels()) as f64))
    };
    let (dense_s, dense_psnr_db, dense_points_per_ray) = measure(false)?;
    let (skip_s, skip_psnr_db, skip_points_per_ray) = measure(true)?;
    let k = val.intrinsics;
    let samples = format!("{} + {}", samples.0, samples.1);
    Ok(SkipBench { views: val.views.len(), width: k.width, height: k.height, samples, dense_s, skip_s, dense_psnr_db, skip_psnr_db, dense_points_per_ray, skip_points_per_ray })
}

/// Peak resident memory of this process so far, in MB (`getrusage`).
pub fn peak_rss_mb() -> f64 {
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: getrusage fills the struct we pass; RUSAGE_SELF is always valid.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return f64::NAN;
    }
    usage.ru_maxrss as f64 / 1024.0 // Linux reports kilobytes
}
