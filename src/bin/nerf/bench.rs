//! `nerf bench`: the burn measurements of `nerf::bench` and their onnxruntime counterparts,
//! in one run. The onnxruntime side lives here, in the binary, so that the training library
//! does not depend on the runtime.

use super::BenchPart;
use anyhow::{Result, bail};
use nerf::bench::{FrameBench, NetworkBench, best_of, bench_view, burn_frame, random_points, timed_frame};
use nerf::field::mlp::bench::{bench_mlp_burn, paper_model, paper_network};
use nerf::export::field_bundle;
use nerf::config::Preset;
use nerf_core::dataset::{Split, load_split};
use nerf::field::ngp::throughput::{SampleOrder, measure_throughput};
use nerf_core::field::ngp::hash_grid::HashGridConfig;
use nerf_core::render::metrics::psnr;
use nerf_export::write_bundle;
use nerf_runtime::environment::Device;
use nerf_runtime::{OpenOptions, OrtNetwork, OrtScene};
use std::path::{Path, PathBuf};

/// Untimed steps before the hash-grid field's timed ones: past the occupancy grid's warm-up
/// (64 steps) and a few updates, so the samples per ray are those of training.
const NGP_WARMUP: usize = 150;

/// The hash-grid bundle of `--only render` unless `--ngp-bundle` says otherwise.
pub const DEFAULT_NGP_BUNDLE: &str = "models/lego-ngp";

/// Where `nerf bench` looks for lego unless `--data` says otherwise.
pub const DEFAULT_DATA: &str = "../shared/data/nerf_synthetic/lego";

/// What `nerf bench` measures and on what.
#[derive(clap::Args, Debug)]
pub struct BenchOptions {
    /// What to measure (default: all).
    #[arg(long, value_enum)]
    pub only: Vec<super::BenchPart>,
    /// Presets for the training step (default: cpu-fast, paper and ngp).
    #[arg(long, value_enum)]
    pub preset: Vec<Preset>,
    /// Blender scene: training rays and the frame's camera (lego val r_0); when it is not
    /// there, the training step runs on a generated scene and the lego measurements are skipped.
    #[arg(long, default_value = DEFAULT_DATA)]
    pub data: PathBuf,
    /// Image downscale factor for the training rays.
    #[arg(long, default_value_t = 4)]
    pub downscale: u32,
    /// Timed training steps per preset (after 2 warm-up steps).
    #[arg(long, default_value_t = 5)]
    pub steps: usize,
    /// Points per network forward pass.
    #[arg(long, default_value_t = 65_536)]
    pub points: usize,
    /// Square frame sizes to render.
    #[arg(long, value_delimiter = ',', default_values_t = vec![100u32, 200])]
    pub sizes: Vec<u32>,
    /// Rays per network call when rendering.
    #[arg(long, default_value_t = nerf_runtime::scene::DEFAULT_CHUNK)]
    pub chunk: usize,
    /// Trained bundle with an occupancy grid for the skipping measurement (lego).
    #[arg(long, default_value = "models/lego")]
    pub bundle: PathBuf,
    /// Hash-grid bundle for the ngp-render measurement (lego; default: train the ngp preset
    /// on lego for --ngp-steps steps and export it) and for `--only render`'s hash-grid
    /// frames (default: models/lego-ngp).
    #[arg(long)]
    pub ngp_bundle: Option<PathBuf>,
    /// Devices for the hash-grid frames of `--only render` (cpu, cuda, cuda:N; comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = vec![Device::Cpu])]
    pub device: Vec<Device>,
    /// Timed renders per hash-grid frame of `--only render` (after one untimed).
    #[arg(long, default_value_t = 2)]
    pub repeats: usize,
    /// Training steps of the hash-grid field when no --ngp-bundle is given.
    #[arg(long, default_value_t = 400)]
    pub ngp_steps: usize,
    /// Val views for the skipping measurement.
    #[arg(long, default_value_t = 5)]
    pub views: usize,
    /// Marching intervals over [near, far] for the skipping measurement.
    #[arg(long, default_value_t = nerf_core::render::DEFAULT_MARCH_STEPS)]
    pub march_steps: usize,
    /// Occupancy threshold for the skipping measurement (default: the grid's own).
    #[arg(long)]
    pub skip_threshold: Option<f32>,
    /// Also time the nerf-pytorch-style paper step (scripts/pytorch_step.py) with this Python,
    /// which must have PyTorch, right after ours (not installed by the project).
    #[arg(long)]
    pub pytorch: Option<PathBuf>,
    /// Also write the results as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// `nerf bench`: everything measured in one run, printed as tables (and JSON with `json`).
pub fn run(options: &BenchOptions, progress: bool) -> Result<()> {
    let BenchOptions { only, preset, data, downscale, steps, points, sizes, chunk, bundle, ngp_bundle, device, repeats, ngp_steps, views, march_steps, skip_threshold, pytorch, json } = options;
    let (downscale, steps, points, chunk, ngp_steps, views, march_steps, skip_threshold) = (*downscale, *steps, *points, *chunk, *ngp_steps, *views, *march_steps, *skip_threshold);
    let wanted = |p: BenchPart| only.is_empty() || only.contains(&p);
    let data = data.join("transforms_val.json").is_file().then_some(data.clone());
    match &data {
        Some(d) => println!("scene: {}", d.display()),
        None => println!("scene: generated ({} has no transforms_val.json: pass --data <Blender scene> for the lego measurements)", options.data.display()),
    }
    let mut report = serde_json::Map::new();
    if wanted(BenchPart::Train) {
        let presets = if preset.is_empty() { vec![Preset::CpuFast, Preset::Paper, Preset::Ngp] } else { preset.clone() };
        let mut results = Vec::new();
        println!("\ntraining step (1/{downscale} resolution rays, mean of {steps} after 2 warm-up, ngp after {NGP_WARMUP})");
        println!("{:<10} {:>6} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>11}", "preset", "rays", "step s", "forward", "backward", "update", "grid", "samples", "samples/s");
        for p in presets {
            let warmup = if p == Preset::Ngp { NGP_WARMUP } else { 2 };
            let b = nerf::bench::bench_train_step(p, data.as_deref(), downscale, warmup, steps)?;
            println!(
                "{:<10} {:>6} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9.0} {:>11.0}",
                b.preset, b.batch_rays, b.step_s, b.forward_s, b.backward_s, b.update_s, b.grid_s, b.samples, b.samples_per_s
            );
            if p == Preset::Ngp {
                report.insert("train_ngp_samples_per_s".into(), b.samples_per_s.into());
            }
            if b.preset == Preset::Paper.name() {
                report.insert("train_step_paper_s".into(), b.step_s.into());
            }
            results.push(b);
        }
        // Training runs first, so the process peak so far is the training peak.
        let rss = nerf::bench::peak_rss_mb();
        println!("peak RSS so far: {rss:.0} MB");
        report.insert("train_peak_rss_mb".into(), rss.into());
        if let Some(python) = &pytorch {
            let torch = nerf::bench::bench_pytorch_step(python, steps)?;
            let ours = results.iter().find(|b| b.preset == Preset::Paper.name());
            println!(
                "{:<10} {:>6} {:>9.3} {:>9.3} {:>9.3} {:>9.3}   peak RSS {:.0} MB{}",
                "pytorch", 1024, torch.step_s, torch.forward_s, torch.backward_s, torch.update_s, torch.peak_rss_mb,
                ours.map(|b| format!("; ours / pytorch = {:.2}", b.step_s / torch.step_s)).unwrap_or_default()
            );
            report.insert("train_step_pytorch_s".into(), torch.step_s.into());
            report.insert("train_peak_rss_pytorch_mb".into(), torch.peak_rss_mb.into());
            if let Some(b) = ours {
                report.insert("train_step_ratio_vs_pytorch".into(), (b.step_s / torch.step_s).into());
            }
            report.insert("pytorch".into(), serde_json::to_value(torch)?);
        }
        report.insert("train_steps".into(), serde_json::to_value(results)?);
    }
    if wanted(BenchPart::Mlp) {
        println!("\npaper MLP forward on {points} points (best of 3, encoding included)");
        let results = bench_mlp(points, 3)?;
        for b in &results {
            println!("{:<12} {:>8.3} s {:>8.1} GFLOP/s", b.backend, b.seconds, b.gflops);
            report.insert(if b.backend == "burn" { "mlp_gflops_burn" } else { "mlp_gflops_ort" }.into(), b.gflops.into());
        }
        report.insert("mlp".into(), serde_json::to_value(results)?);
    }
    if wanted(BenchPart::Render) {
        println!("\nframe time, paper network, dense 64 + 128 samples, {chunk} rays per call");
        let results = bench_frames(data.as_deref(), sizes, chunk, progress)?;
        println!("{:<12} {:>9} {:>9} {:>14}", "backend", "size", "seconds", "PSNR vs burn");
        for b in &results {
            println!("{:<12} {:>9} {:>9.2} {:>11.1} dB", b.backend, format!("{}×{}", b.width, b.height), b.seconds, b.psnr_vs_burn_db);
        }
        report.insert("frames".into(), serde_json::to_value(results)?);
        let ngp = ngp_bundle.clone().unwrap_or_else(|| PathBuf::from(DEFAULT_NGP_BUNDLE));
        println!("\nhash-grid frames: {} test view 0 through nerf-render, best of {repeats} after one untimed; loop = frame − onnxruntime − encoding", ngp.display());
        let frames = super::device_bench::bench_device_frames(&ngp, device, *repeats, progress)?;
        println!("{:<8} {:<9} {:<12} {:>9} {:>13} {:>10} {:>8} {:>9} {:>12} {:>14}", "device", "lowering", "path", "frame s", "onnxruntime s", "encoding s", "loop s", "worst s", "points/px", "max |Δ| vs cpu");
        for f in &frames {
            println!(
                "{:<8} {:<9} {:<12} {:>9.3} {:>13.3} {:>10.3} {:>8.3} {:>9.3} {:>12.1} {:>14.1e}",
                f.device, f.lowering, f.path, f.seconds, f.onnxruntime_s, f.encoding_s, f.loop_s, f.worst_s, f.points_per_pixel, f.max_abs_vs_cpu
            );
        }
        report.insert("device_frames".into(), serde_json::to_value(frames)?);
    }
    if wanted(BenchPart::Skip) {
        match &data {
            Some(d) => {
                println!("\nskipping vs dense through onnxruntime: {}, lego val at 1/{downscale}, 64 + 128 samples dense, {march_steps} marching steps", bundle.display());
                let b = bench_skipping(bundle, d, downscale, views, (64, 128), (march_steps, skip_threshold), progress)?;
                println!("{:<8} {:>12} {:>10} {:>14}", "path", "s / frame", "PSNR", "points / ray");
                println!("{:<8} {:>12.3} {:>7.2} dB {:>14.1}", "dense", b.dense_s, b.dense_psnr_db, b.dense_points_per_ray);
                println!("{:<8} {:>12.3} {:>7.2} dB {:>14.1}", "skip", b.skip_s, b.skip_psnr_db, b.skip_points_per_ray);
                println!("{:.1}× faster, PSNR loss {:.2} dB ({} views at {}×{})", b.dense_s / b.skip_s, b.dense_psnr_db - b.skip_psnr_db, b.views, b.width, b.height);
                report.insert("render_dense_s".into(), b.dense_s.into());
                report.insert("render_skip_s".into(), b.skip_s.into());
                report.insert("render_skip_psnr_loss_db".into(), (b.dense_psnr_db - b.skip_psnr_db).into());
                report.insert("skip".into(), serde_json::to_value(b)?);
            }
            None => println!("\nskipping: needs the lego data (--data) for ground truth; not measured"),
        }
    }
    if wanted(BenchPart::Grid) {
        println!("\nhash-grid encoding on {points} points along rays, 2 threads, median of 3 (no MLPs)");
        println!("{:>3} {:>3} {:>5} {:>10} {:>12} {:>18}", "L", "F", "log T", "table MiB", "forward M/s", "bwd + update M/s");
        let mut results = Vec::new();
        for (levels, features_per_level, log2_table_size) in [(16, 2, 19), (16, 2, 17), (8, 4, 17), (8, 2, 17)] {
            let config = HashGridConfig { levels, features_per_level, log2_table_size, ..Default::default() };
            let t = measure_throughput(&config, points, 2, SampleOrder::Rays, 3)?;
            println!(
                "{levels:>3} {features_per_level:>3} {log2_table_size:>5} {:>10.1} {:>12.3} {:>18.3}",
                t.table_mib,
                t.forward_samples_per_s / 1e6,
                t.backward_update_samples_per_s / 1e6
            );
            if config == HashGridConfig::default() {
                report.insert("grid_forward_samples_per_s".into(), t.forward_samples_per_s.into());
                report.insert("grid_backward_update_samples_per_s".into(), t.backward_update_samples_per_s.into());
            }
            results.push(t);
        }
        report.insert("grid".into(), serde_json::to_value(results)?);
    }
    if wanted(BenchPart::NgpRender) {
        match &data {
            Some(d) => {
                let b = super::ngp_bench::bench_ngp_render(ngp_bundle.as_deref(), ngp_steps, d, progress)?;
                println!("\nhash-grid field: {} ({}), val {} at {}×{}, {:.1} points per ray", b.bundle, b.trained, b.view, b.width, b.height, b.points_per_ray);
                let db = |v: f32| if v.is_finite() { format!("{v:.1} dB") } else { "identical".into() };
                println!("{:<27} {:>10} {:>14} {:>10} {:>9} {:>11} {:>11} {:>11} {:>9} {:>15}", "", "s / frame", "onnxruntime s", "encoding s", "ort/burn", "PSNR", "vs burn", "vs whole", "graph MB", "graph points/s");
                println!("{:<27} {:>10.2} {:>14} {:>10} {:>9} {:>8.2} dB {:>11} {:>11} {:>9} {:>15}", "burn", b.burn_s, "", "", "", b.burn_psnr_db, "", "", "", "");
                for l in &b.lowerings {
                    println!(
                        "{:<27} {:>10.2} {:>14.2} {:>10.2} {:>9.2} {:>8.2} dB {:>11} {:>11} {:>9.1} {:>15.0}",
                        l.lowering, l.seconds, l.onnxruntime_s, l.encoding_s, l.ratio_to_burn, l.psnr_db, db(l.psnr_vs_burn_db), l.psnr_vs_whole_graph_db.map_or(String::new(), db), l.graph_mb, l.graph_points_per_s
                    );
                }
                println!("{:<27} {:>10} {:>14} {:>10} {:>9} {:>11} {:>11} {:>11} {:>9} {:>15.0}", "floor (gather + sum)", "", "", "", "", "", "", "", "", b.floor_points_per_s);
                report.insert("ngp_frame_s".into(), b.lowerings[0].seconds.into());
                report.insert("ngp".into(), serde_json::to_value(b)?);
            }
            None => println!("\nngp-render: needs the lego data (--data); not measured"),
        }
    }
    if let Some(path) = json {
        let text = serde_json::to_string_pretty(&serde_json::Value::Object(report))?;
        nerf_core::io::atomic::write_atomic(&path, text.as_bytes())?;
        println!("\nJSON: {}", path.display());
    }
    Ok(())
}

/// The paper network (seeded weights) in burn and through onnxruntime on the same `points`
/// random inputs: best of `repeats` forward passes each.
fn bench_mlp(points: usize, repeats: usize) -> Result<Vec<NetworkBench>> {
    let (plain, net) = paper_network(1)?;
    let (p, d) = random_points(points, 2);
    let burn = bench_mlp_burn(&net, &p, &d, repeats)?;
    let dir = tempfile::tempdir()?;
    let path = dir.path().join("paper.onnx");
    let model = nerf_export::field::mlp::compile(&plain, "coarse", nerf_export::DEFAULT_OPSET, &[])?;
    nerf_core::io::atomic::write_atomic(&path, &prost::Message::encode_to_vec(&model))?;
    let mut ort = OrtNetwork::load(&path, None)?;
    let ort_s = best_of(repeats, || ort.run(&p, &d).map(|_| ()))?;
    Ok(vec![burn, NetworkBench::new("onnxruntime", points, ort_s, plain.spec.macs_per_point())])
}

/// Render one frame per size with the paper network (seeded weights; 64 + 128 samples, dense)
/// through burn and through onnxruntime (the exported graphs, as `nerf-render` runs them).
fn bench_frames(data: Option<&Path>, sizes: &[u32], chunk: usize, progress: bool) -> Result<Vec<FrameBench>> {
    let (camera, pose) = bench_view(data)?;
    let (config, _, _, model) = paper_model(chunk)?;
    let dir = tempfile::tempdir()?;
    let bundle = dir.path().join("bundle");
    write_bundle(&bundle, &field_bundle(&model, &config, &camera, None), &Default::default())?;
    let options = OpenOptions { chunk: Some(chunk), skip_empty_space: false, ..OpenOptions::default() };
    let mut scene = OrtScene::open(&bundle, &options)?;
    let samples = format!("{} + {}", config.sampling.n_coarse, config.sampling.n_fine);
    let mut out = Vec::new();
    for &size in sizes {
        let k = camera.resized(size, size);
        let (burn, burn_s) = burn_frame(&model, &config, &k, &pose, progress);
        let (ort, ort_s) = timed_frame(progress, &format!("onnxruntime {size}×{size}"), k.num_pixels(), |p| scene.render(&k, &pose, p));
        let ort = ort?;
        for (backend, seconds, psnr_vs_burn_db) in [("burn", burn_s, f32::INFINITY), ("onnxruntime", ort_s, psnr(&ort.rays.rgb, &burn.rays.rgb))] {
            out.push(FrameBench { backend: backend.into(), width: size, height: size, samples: samples.clone(), seconds, psnr_vs_burn_db });
        }
    }
    Ok(out)
}

/// Rendering lego val views through onnxruntime (as `nerf-render` does) with the dense path and
/// with empty-space skipping + early termination, both with `n_coarse + n_fine` samples.
#[derive(Debug, Clone, serde::Serialize)]
struct SkipBench {
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
fn bench_skipping(bundle: &Path, data: &Path, downscale: u32, views: usize, samples: (usize, usize), march: (usize, Option<f32>), progress: bool) -> Result<SkipBench> {
    let mut val = load_split(data, Split::Val, downscale, true)?;
    val.views.truncate(views.max(1));
    let measure = |skip: bool| -> Result<(f64, f32, f64)> {
        let options = OpenOptions { skip_empty_space: skip, ..OpenOptions::default() };
        let mut scene = OrtScene::open(bundle, &options)?;
        if skip && scene.occupancy.is_none() {
            bail!("{}: the bundle has no occupancy grid to skip with", bundle.display());
        }
        (scene.options.sampling.n_coarse, scene.options.sampling.n_fine) = samples;
        scene.options.march_steps = march.0;
        if let Some(threshold) = march.1 {
            scene.occupancy = scene.occupancy.take().map(|g| g.with_threshold(threshold));
        }
        let (mut seconds, mut db) = (0.0, 0.0);
        for view in &val.views {
            let label = format!("{} {}", if skip { "skip" } else { "dense" }, view.name);
            let (image, s) = timed_frame(progress, &label, view.camera.num_pixels(), |p| scene.render(&view.camera, &view.pose, p));
            let image = image?;
            seconds += s;
            db += psnr(&image.rays.rgb, view.image.as_ref().expect("loaded with images"));
        }
        let n = val.views.len();
        let points: usize = scene.field.graphs.iter().map(|(_, net)| net.evaluated).sum();
        let pixels: usize = val.views.iter().map(|v| v.camera.num_pixels()).sum();
        Ok((seconds / n as f64, db / n as f32, points as f64 / pixels as f64))
    };
    let (dense_s, dense_psnr_db, dense_points_per_ray) = measure(false)?;
    let (skip_s, skip_psnr_db, skip_points_per_ray) = measure(true)?;
    let k = val.views[0].camera;
    let samples = format!("{} + {}", samples.0, samples.1);
    Ok(SkipBench { views: val.views.len(), width: k.width, height: k.height, samples, dense_s, skip_s, dense_psnr_db, skip_psnr_db, dense_points_per_ray, skip_points_per_ray })
}

