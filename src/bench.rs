//! The burn side of `nerf bench`: training steps, timing helpers, frame times in burn, and the
//! PyTorch comparison (the paper network's own measurements are its kind's: `field::mlp::bench`). The onnxruntime side lives in the `nerf` binary,
//! so this library does not depend on the runtime; the binary measures both in one run, so
//! ratios between them are fair on a shared, noisy machine.

use crate::error::{Error, Result};
use crate::field::TrainedField;
use crate::config::{Preset, TrainConfig};
use crate::field::StepTiming;
use nerf_core::Rng;
use nerf_core::camera::{Intrinsics, Pose, length};
use nerf_core::PinholeCamera;
use nerf_core::dataset::{Split, SyntheticSceneConfig, generate_scene, load_split};
use nerf_core::render::RenderedImage;
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
    /// Mean seconds of the step in the hash grid (forward, gradient scatter, sparse Adam).
    pub grid_s: f64,
    /// Mean samples per step (field evaluations, forward and backward).
    pub samples: f64,
    /// Training throughput: samples per second of forward + backward + update.
    pub samples_per_s: f64,
}

/// Time `steps` training steps of `preset` (after `warmup` untimed ones) on the scene in `data`,
/// or on a generated scene when `data` is `None`. Precrop is off so every step is full-size.
/// For the hash-grid field, warm up past the occupancy grid's first updates: its samples per
/// step only settle once the grid is tight.
pub fn bench_train_step(preset: Preset, data: Option<&Path>, downscale: u32, warmup: usize, steps: usize) -> Result<StepBench> {
    let generated;
    let dir = match data {
        Some(d) => d,
        None => {
            generated = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
            generate_scene(generated.path(), &SyntheticSceneConfig::default())?;
            generated.path()
        }
    };
    let train = load_split(dir, Split::Train, downscale, true)?;
    let mut config = preset.config();
    config.precrop_iters = 0;
    let batch_rays = config.batch_rays;
    let mut trainer = crate::field::trainer(config.clone(), train)?;
    let lr = |step: usize| config.learning_rate(step, step as f64 / config.iters as f64);
    for _ in 0..warmup {
        trainer.step(lr(trainer.steps_done()));
    }
    let mut total = StepTiming::default();
    let mut samples = 0;
    for _ in 0..steps {
        let stats = trainer.step(lr(trainer.steps_done()));
        let t = stats.timing;
        total.forward_s += t.forward_s;
        total.backward_s += t.backward_s;
        total.update_s += t.update_s;
        total.grid_s += t.grid_s;
        samples += stats.samples;
    }
    let n = steps.max(1) as f64;
    let seconds = total.forward_s + total.backward_s + total.update_s;
    Ok(StepBench {
        grid_s: total.grid_s / n,
        samples: samples as f64 / n,
        samples_per_s: samples as f64 / seconds.max(f64::MIN_POSITIVE),
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
pub fn bench_pytorch_step(python: &Path, steps: usize) -> Result<PytorchStep> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/pytorch_step.py");
    let out = tempfile::NamedTempFile::new().map_err(|e| Error::io(std::env::temp_dir(), e))?;
    let status = std::process::Command::new(python)
        .arg(&script)
        .args(["--steps", &steps.to_string(), "--threads", "2", "--json"])
        .arg(out.path())
        .stdout(std::process::Stdio::null())
        .status()
        .map_err(|e| Error::External { program: python.to_path_buf(), problem: e.to_string() })?;
    if !status.success() {
        let problem = format!("{} failed ({status}); does that Python have PyTorch?", script.display());
        return Err(Error::External { program: python.to_path_buf(), problem });
    }
    let text = std::fs::read_to_string(out.path()).map_err(|e| Error::io(out.path(), e))?;
    serde_json::from_str(&text).map_err(|e| Error::External { program: script, problem: format!("unreadable report: {e}") })
}

/// Forward throughput of one network on a batch of points.
#[derive(Debug, Clone, serde::Serialize)]
pub struct NetworkBench {
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
            let norm = length(v).max(1e-3);
            v.map(|x| x / norm)
        })
        .collect();
    (points, dirs)
}

/// The best of `repeats` timings of `f` (after one untimed warm-up call), in seconds.
pub fn best_of<E>(repeats: usize, mut f: impl FnMut() -> std::result::Result<(), E>) -> std::result::Result<f64, E> {
    f()?; // warm-up: allocations, onnxruntime's first-run setup
    let mut best = f64::INFINITY;
    for _ in 0..repeats.max(1) {
        let start = Instant::now();
        f()?;
        best = best.min(start.elapsed().as_secs_f64());
    }
    Ok(best)
}

impl NetworkBench {
    /// A measurement of `points` points in `seconds`, `macs` multiply-adds per point.
    pub fn new(backend: &str, points: usize, seconds: f64, macs: usize) -> Self {
        NetworkBench { backend: backend.into(), points, seconds, gflops: 2.0 * macs as f64 * points as f64 / seconds / 1e9 }
    }
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
pub fn bench_view(data: Option<&Path>) -> Result<(PinholeCamera, Pose)> {
    match data {
        Some(dir) => {
            let val = load_split(dir, Split::Val, 1, false)?;
            Ok((val.views[0].camera, val.views[0].pose))
        }
        None => Ok((Intrinsics::from_camera_angle_x(800, 800, nerf_core::dataset::CAMERA_ANGLE_X).into(), Pose::orbit(1)[0])),
    }
}

/// One frame of `field` rendered by burn (without a grid: dense, or a bounded field's whole
/// box), timed under a progress bar.
pub fn burn_frame(field: &dyn TrainedField, config: &TrainConfig, camera: &PinholeCamera, pose: &Pose, progress: bool) -> (RenderedImage, f64) {
    let label = format!("burn {}×{}", camera.width, camera.height);
    let options = config.render_options();
    let device = crate::backend::cpu();
    timed_frame(progress, &label, camera.num_pixels(), |p| field.render(&device, None, camera, pose, &options, p))
}

/// `render(progress)` under a progress bar labelled `what` over `pixels`, and its seconds.
pub fn timed_frame<R>(show: bool, what: &str, pixels: usize, render: impl FnOnce(&mut dyn FnMut(usize, usize)) -> R) -> (R, f64) {
    let bar = nerf_core::frames::write::frame_bar(show, what);
    bar.set_length(pixels as u64);
    let start = Instant::now();
    let out = render(&mut |done, _| bar.set_position(done as u64));
    let seconds = start.elapsed().as_secs_f64();
    bar.finish_and_clear();
    (out, seconds)
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
