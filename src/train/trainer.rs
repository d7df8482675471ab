//! The training loop: one random image per step, rays through random pixels (centre crop
//! first), coarse + fine networks, MSE on both, Adam with exponential decay, checkpoints.

use super::checkpoint::{Checkpoint, config_path, latest_checkpoint, new_state};
use super::{TrainConfig, learning_rate};
use crate::field::{NerfMlp, NerfModel};
use crate::inference::{BurnField, encoded_tensor, vec3_tensor};
use crate::volume::{VolumeOutput, composite, deltas_tensor};
use burn::module::{Module, ModuleMapper, Param};
use burn::optim::{AdamConfig, GradientsAccumulator, GradientsParams, ModuleOptimizer};
use burn::grad_clipping::GradientClippingConfig;
use burn::tensor::{Device, IndexingUpdateOp, Int, Tensor, TensorData};
use nerf_core::occupancy::{OccupancyGrid, render_image_with};
use indicatif::{ProgressBar, ProgressStyle};
use nerf_core::dataset::{RayBatcher, Split, SplitData, load_split};
use nerf_core::metrics::psnr_from_mse;
use nerf_core::render::RenderOptions;
use nerf_core::sampling::{DenseSamples, importance, stratified};
use nerf_core::{Rays, Rng};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What `nerf train` was asked to do.
#[derive(Debug, Clone)]
pub struct TrainOptions {
    /// Blender scene directory.
    pub data: PathBuf,
    /// Run directory (config, checkpoints, curve).
    pub run: PathBuf,
    /// The configuration for a new run (a resumed run keeps its saved one).
    pub config: TrainConfig,
    /// Image downscale factor.
    pub downscale: u32,
    /// Stop after this many minutes of training in total (across resumes).
    pub time_budget_min: Option<f64>,
    /// Override the configured number of steps.
    pub iters: Option<usize>,
    /// Show a progress bar.
    pub progress: bool,
}

/// What a training run reached.
#[derive(Debug, Clone)]
pub struct TrainSummary {
    /// Steps completed (including resumed ones).
    pub steps: usize,
    /// Mean fine PSNR over the last steps' batches.
    pub train_psnr: f32,
    /// Last quick validation PSNR (one val view), if one was measured.
    pub val_psnr: Option<f32>,
    /// Minutes spent training in total.
    pub minutes: f64,
}

/// Loss and PSNR of one step.
#[derive(Debug, Clone, Copy)]
pub struct StepStats {
    /// MSE(coarse) + MSE(fine).
    pub loss: f32,
    /// PSNR of the fine (or only) output on the batch.
    pub psnr: f32,
    /// Where the step's time went.
    pub timing: StepTiming,
}

/// Seconds spent in each phase of a step.
#[derive(Debug, Clone, Copy, Default)]
pub struct StepTiming {
    /// Occupancy update (when due), batch, rays, sampling and both forward passes (with the
    /// loss read back).
    pub forward_s: f64,
    /// Backpropagation.
    pub backward_s: f64,
    /// The Adam update.
    pub update_s: f64,
}

/// A model, its optimizer and the data it learns from.
pub struct Trainer {
    /// The configuration in force.
    pub config: TrainConfig,
    /// The networks (on the autodiff device); only `None` inside [`Trainer::step`].
    model: Option<NerfModel>,
    optim: ModuleOptimizer,
    /// Batch and jitter randomness.
    pub rng: Rng,
    /// Steps completed.
    pub step: usize,
    device: Device,
    batcher: RayBatcher,
    /// Where the scene is, when empty-space skipping is on.
    occupancy: Option<OccupancyGrid>,
}

impl Trainer {
    /// A fresh trainer on `train` data.
    pub fn new(config: TrainConfig, train: SplitData, device: Device) -> Result<Self, String> {
        config.validate()?;
        device.seed(config.seed);
        let model = NerfModel::new(&config.network, config.sampling.n_fine > 0, &device);
        let mut adam = AdamConfig::new()
            .with_beta_1(config.adam_beta1)
            .with_beta_2(config.adam_beta2)
            .with_epsilon(config.adam_epsilon);
        if let Some(norm) = config.grad_clip_norm {
            adam = adam.with_grad_clipping(Some(GradientClippingConfig::Norm(norm)));
        }
        let batcher = RayBatcher::new(train).map_err(|e| e.to_string())?;
        let occupancy = config.skip_empty_space.then(|| OccupancyGrid::from_config(&config.occupancy));
        Ok(Trainer { rng: Rng::new(config.seed), optim: adam.init(), model: Some(model), config, step: 0, device, batcher, occupancy })
    }

    /// Restore model, optimizer, step and RNG from a checkpoint.
    pub fn resume(&mut self, checkpoint: &Checkpoint) -> Result<f64, String> {
        let state = checkpoint.state()?;
        checkpoint.load_model(self.model.as_mut().expect("model present"))?;
        self.optim = checkpoint.load_optimizer(self.optim.clone())?;
        self.step = state.step;
        self.rng = state.rng;
        if self.occupancy.is_some() {
            self.occupancy = checkpoint.load_occupancy()?.or(self.occupancy.take());
        }
        Ok(state.elapsed_s)
    }

    /// Save a checkpoint of the current state into `run`.
    pub fn save(&self, run: &Path, elapsed_s: f64) -> Result<Checkpoint, String> {
        let state = new_state(self.step, self.rng.clone(), elapsed_s);
        Checkpoint::save(run, self.model(), &self.optim, self.occupancy.as_ref(), &state)
    }

    /// The occupancy grid, when empty-space skipping is on.
    pub fn occupancy(&self) -> Option<&OccupancyGrid> {
        self.occupancy.as_ref()
    }

    /// Re-measure the density at one random point per grid cell with the fine (or only) network.
    fn update_occupancy(&mut self) {
        let Some(mut grid) = self.occupancy.take() else { return };
        let points = grid.random_cell_points(&mut self.rng);
        let snapshot = self.model().valid();
        let net = snapshot.fine.as_ref().unwrap_or(&snapshot.coarse);
        let device = snapshot.coarse_device();
        let mut sigma = Vec::with_capacity(points.len());
        for chunk in points.chunks(1 << 16) {
            let x = encoded_tensor(&net.spec().position_encoding, chunk, &device);
            sigma.extend(net.density(x).into_data().try_to_vec::<f32>().expect("f32 densities"));
        }
        grid.update(&sigma, self.config.occupancy.decay);
        self.occupancy = Some(grid);
    }

    /// The networks being trained.
    pub fn model(&self) -> &NerfModel {
        self.model.as_ref().expect("model present outside a step")
    }

    /// One optimisation step on a fresh random batch.
    ///
    /// The batch runs as several passes over disjoint rays (at most `pass_points` samples
    /// each, a multiple of `concurrent_passes` of them). Each pass's loss is weighted by its
    /// share of the rays, so the summed gradients are those of the whole batch's loss. Passes
    /// run `concurrent_passes` at a time on their own autodiff graphs: burn's elementwise
    /// kernels are single-threaded, so one pass's elementwise work overlaps the other's GEMMs.
    pub fn step(&mut self) -> StepStats {
        let start = Instant::now();
        let o = &self.config.occupancy;
        if self.occupancy.is_some() && self.step >= o.warmup_steps && (self.step - o.warmup_steps) % o.update_every == 0 {
            self.update_occupancy();
        }
        let cfg = &self.config;
        let precrop = (self.step < cfg.precrop_iters).then_some(cfg.precrop_fraction);
        let batch = self.batcher.next_batch(&mut self.rng, cfg.batch_rays, precrop);
        let data = self.batcher.data();
        let rays = Rays::for_pixels(&data.intrinsics, &data.views[batch.0].pose, &batch.1);
        let samples_per_ray = cfg.sampling.n_coarse + cfg.sampling.n_fine;
        let concurrent = cfg.concurrent_passes;
        let passes = (rays.len() * samples_per_ray).div_ceil(cfg.pass_points).next_multiple_of(concurrent).min(rays.len());
        let rays_per_pass = rays.len().div_ceil(passes);
        // Drawn for the whole batch, so the coarse samples do not depend on the split.
        let coarse = stratified(&cfg.sampling, rays.len(), Some(&mut self.rng));
        // One draw from the step's generator however many passes there are.
        let mut pass_rngs = self.rng.fork();
        let work: Vec<PassWork> = (0..rays.len())
            .step_by(rays_per_pass)
            .map(|first| {
                let end = (first + rays_per_pass).min(rays.len());
                PassWork {
                    rays: rays.slice(first..end),
                    target: batch.2[first..end].to_vec(),
                    coarse: coarse.slice(first..end),
                    share: (end - first) as f32 / rays.len() as f32,
                    rng: pass_rngs.fork(),
                }
            })
            .collect();

        let model = self.model.take().expect("model present");
        let context = PassContext { config: &self.config, occupancy: self.occupancy.as_ref(), device: &self.device };
        let mut accumulated = GradientsAccumulator::<NerfModel>::new();
        let (mut loss_value, mut mse_value) = (0.0, 0.0);
        // The occupancy update, batch, rays and samples count as forward time.
        let mut mark = Instant::now();
        let mut timing = StepTiming { forward_s: (mark - start).as_secs_f64(), ..StepTiming::default() };
        let mut work = work.into_iter();
        loop {
            let wave: Vec<PassWork> = work.by_ref().take(concurrent).collect();
            if wave.is_empty() {
                break;
            }
            let results = run_concurrently(wave, |pass| context.run(&model, pass));
            let (mut forward, mut backward) = (0.0, 0.0);
            for result in results {
                accumulated.accumulate(&model, result.grads);
                loss_value += result.loss;
                mse_value += result.mse_last;
                forward += result.forward_s;
                backward += result.backward_s;
            }
            // The wave's wall time, split in the proportion its passes spent in each phase.
            let now = Instant::now();
            let wall = (now - mark).as_secs_f64();
            timing.forward_s += wall * forward / (forward + backward).max(f64::MIN_POSITIVE);
            timing.backward_s += wall * backward / (forward + backward).max(f64::MIN_POSITIVE);
            mark = now;
        }
        let lr = learning_rate(self.config.lr, self.config.lr_decay_ksteps, self.step);
        self.model = Some(self.optim.step(lr, model, accumulated.grads()));
        self.step += 1;
        timing.update_s = mark.elapsed().as_secs_f64();
        StepStats { loss: loss_value, psnr: psnr_from_mse(mse_value), timing }
    }

    /// PSNR of the current model on one view, rendered deterministically.
    pub fn view_psnr(&self, data: &SplitData, index: usize) -> f32 {
        let view = &data.views[index];
        let Some(target) = &view.image else { return f32::NAN };
        let snapshot = self.model().valid();
        let field = BurnField { model: &snapshot, device: snapshot.coarse_device() };
        let options = render_options(&self.config);
        let Ok(image) = render_image_with(field, self.occupancy.as_ref(), &data.intrinsics, &view.pose, &options, &mut |_, _| {});
        nerf_core::metrics::psnr(&image.rays.rgb, target)
    }
}

/// The rays of one pass of a step, with their targets and randomness.
struct PassWork {
    rays: Rays,
    target: Vec<[f32; 3]>,
    /// The rays' stratified samples.
    coarse: DenseSamples,
    /// This pass's fraction of the step's rays (its loss weight).
    share: f32,
    rng: Rng,
}

/// What one pass returns.
struct PassResult {
    grads: GradientsParams,
    /// Weighted loss and last-stage MSE (summed over passes they give the batch's).
    loss: f32,
    mse_last: f32,
    forward_s: f64,
    backward_s: f64,
}

/// What every pass of a step reads.
struct PassContext<'a> {
    config: &'a TrainConfig,
    occupancy: Option<&'a OccupancyGrid>,
    device: &'a Device,
}

impl PassContext<'_> {
    /// Forward and backward over one pass's rays, on a graph of its own.
    fn run(&self, model: &NerfModel, mut work: PassWork) -> PassResult {
        let start = Instant::now();
        // Fresh autodiff leaves for the parameters (same ids and data): the pass's graph does not
        // join the other passes' graphs, whose lock it would otherwise share.
        let model = model.clone().map(&mut FreshLeaves);
        let target = vec3_tensor(&work.target, self.device);
        let rays = &work.rays;
        let viewdirs = rays.view_directions();
        let sampling = &self.config.sampling;
        let coarse = &work.coarse;
        let coarse_out = self.render_stage(&model.coarse, rays, &viewdirs, coarse);
        let mse_coarse = (coarse_out.rgb.clone() - target.clone()).square().mean();
        let (loss, mse_last) = match &model.fine {
            Some(fine_net) => {
                // The new samples come from detached weights: no gradient flows through them.
                let w = coarse_out.weights.clone().detach().into_data().try_to_vec::<f32>().expect("f32 weights");
                let extra = importance(coarse, &w, sampling.n_fine, Some(&mut work.rng));
                let all = coarse.merge_sorted(&extra);
                let fine_out = self.render_stage(fine_net, rays, &viewdirs, &all);
                let mse_fine = (fine_out.rgb - target).square().mean();
                (mse_coarse + mse_fine.clone(), mse_fine)
            }
            None => (mse_coarse.clone(), mse_coarse),
        };
        let loss = loss * work.share;
        let loss_value = loss.clone().into_scalar::<f32>();
        let mse_last = work.share * mse_last.into_scalar::<f32>();
        let forward_done = Instant::now();
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        PassResult {
            grads,
            loss: loss_value,
            mse_last,
            forward_s: (forward_done - start).as_secs_f64(),
            backward_s: forward_done.elapsed().as_secs_f64(),
        }
    }

    fn render_stage(&self, net: &NerfMlp, rays: &Rays, viewdirs: &[[f32; 3]], samples: &DenseSamples) -> VolumeOutput {
        let (n_rays, n) = (samples.n_rays, samples.n_samples);
        let spec = net.spec();
        let device = self.device;
        let points = samples.points(&rays.origins, &rays.directions);
        let occupied = self.occupancy.map(|grid| grid.occupied_indices(&points));
        // The inputs need no gradient, so they are encoded here rather than as graph ops.
        let (rgb, sigma) = match occupied {
            Some(mut keep) if keep.len() < points.len() => {
                // Only occupied samples reach the network; the rest keep σ = 0 (and colour 0).
                // A batch with nothing occupied still evaluates its first sample, so the graph is
                // never empty (burn has no zero-row tensors here).
                if keep.is_empty() {
                    keep.push(0);
                }
                let packed: Vec<[f32; 3]> = keep.iter().map(|&i| points[i]).collect();
                let dirs: Vec<[f32; 3]> = keep.iter().map(|&i| viewdirs[i / n]).collect();
                let (rgb, sigma) = net.forward_encoded(
                    encoded_tensor(&spec.position_encoding, &packed, device),
                    encoded_tensor(&spec.direction_encoding, &dirs, device),
                    1,
                );
                let index: Vec<i64> = keep.iter().map(|&i| i as i64).collect();
                let index = Tensor::<1, Int>::from_data(TensorData::new(index, [keep.len()]), device);
                let total = points.len();
                (
                    Tensor::<2>::zeros([total, 3], device).select_assign(0, index.clone(), rgb, IndexingUpdateOp::Add),
                    Tensor::<1>::zeros([total], device).select_assign(0, index, sigma, IndexingUpdateOp::Add),
                )
            }
            _ => net.forward_encoded(
                encoded_tensor(&spec.position_encoding, &points, device),
                encoded_tensor(&spec.direction_encoding, viewdirs, device),
                n,
            ),
        };
        composite(
            sigma.reshape([n_rays, n]),
            rgb.reshape([n_rays, n, 3]),
            deltas_tensor(samples, &rays.directions, device),
            self.config.white_background,
        )
    }
}

/// Replaces every parameter by a new autodiff leaf on the same data, keeping its id.
struct FreshLeaves;

impl ModuleMapper for FreshLeaves {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        param.map(|tensor| tensor.detach().require_grad())
    }
}

/// `f` on every item, all at once on rayon's pool; results in input order.
fn run_concurrently<T: Send, R: Send>(items: Vec<T>, f: impl Fn(T) -> R + Sync + Send) -> Vec<R> {
    use rayon::prelude::*;
    items.into_par_iter().with_max_len(1).map(f).collect()
}

/// How a run's networks are rendered at test time.
pub fn render_options(config: &TrainConfig) -> RenderOptions {
    RenderOptions {
        sampling: config.sampling.clone(),
        white_background: config.white_background,
        chunk: config.chunk,
        // Runs that skip empty space also stop marching behind opaque surfaces.
        min_transmittance: config.skip_empty_space.then_some(nerf_core::render::DEFAULT_MIN_TRANSMITTANCE),
        march_steps: nerf_core::render::DEFAULT_MARCH_STEPS,
    }
}

impl NerfModel {
    /// The device the coarse network's weights live on.
    pub fn coarse_device(&self) -> Device {
        self.coarse.devices().into_iter().next().unwrap_or_else(crate::backend::cpu)
    }
}

/// Train (or resume) a run as `options` say.
pub fn train(options: &TrainOptions) -> Result<TrainSummary, String> {
    std::fs::create_dir_all(&options.run).map_err(|e| format!("{}: {e}", options.run.display()))?;
    let checkpoint = latest_checkpoint(&options.run)?;
    let mut config = match &checkpoint {
        // A resumed run keeps the configuration it started with.
        Some(_) => TrainConfig::from_toml_file(&config_path(&options.run), None)?,
        None => options.config.clone(),
    };
    if let Some(iters) = options.iters {
        config.iters = iters;
    }
    nerf_core::error::write_atomic(&config_path(&options.run), config.to_toml().as_bytes()).map_err(|e| e.to_string())?;

    let train_data = load_split(&options.data, Split::Train, options.downscale, true).map_err(|e| e.to_string())?;
    let camera = serde_json::to_string_pretty(&train_data.intrinsics).expect("intrinsics serialise");
    let camera_file = crate::evaluate::camera_path(&options.run);
    nerf_core::error::write_atomic(&camera_file, camera.as_bytes()).map_err(|e| e.to_string())?;
    // Where the data came from, so `nerf export` can include the test poses.
    let source = crate::export::RunSource { data: std::path::absolute(&options.data).unwrap_or(options.data.clone()), downscale: options.downscale };
    nerf_core::error::write_atomic(&crate::export::source_path(&options.run), serde_json::to_string_pretty(&source).expect("serialises").as_bytes())
        .map_err(|e| e.to_string())?;
    // The validation curve is optional: a scene without val views still trains.
    let val_data = match load_split(&options.data, Split::Val, options.downscale, true) {
        Ok(v) if !v.views.is_empty() => Some(v),
        Ok(_) => None,
        Err(e) => {
            eprintln!("note: no validation curve ({e})");
            None
        }
    };
    let mut trainer = Trainer::new(config.clone(), train_data, crate::backend::cpu_autodiff())?;
    let mut elapsed_before = 0.0;
    if let Some(c) = &checkpoint {
        elapsed_before = trainer.resume(c)?;
        eprintln!("resuming {} at step {}", options.run.display(), trainer.step);
    }

    let budget_s = options.time_budget_min.map(|m| m * 60.0);
    let bar = if options.progress { ProgressBar::new(config.iters as u64) } else { ProgressBar::hidden() };
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}<{eta_precise}] {wide_bar} {pos}/{len} {per_sec} {msg}")
            .expect("valid template"),
    );
    bar.set_position(trainer.step as u64);
    bar.reset_eta();

    let curve_path = options.run.join("curve.csv");
    let mut curve = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&curve_path)
        .map_err(|e| format!("{}: {e}", curve_path.display()))?;
    if curve.metadata().map(|m| m.len() == 0).unwrap_or(false) {
        let _ = writeln!(curve, "step,minutes,train_psnr,val_psnr");
    }

    let start = Instant::now();
    let elapsed = || elapsed_before + start.elapsed().as_secs_f64();
    let mut recent: Vec<f32> = Vec::new();
    let mut next_eval_s = if config.eval_every_min > 0.0 { elapsed() + config.eval_every_min * 60.0 } else { f64::INFINITY };
    let mut val_psnr = None;
    while trainer.step < config.iters {
        if budget_s.is_some_and(|b| elapsed() >= b) {
            break;
        }
        let stats = trainer.step();
        if !stats.loss.is_finite() {
            trainer.save(&options.run, elapsed())?;
            return Err(format!("the loss became {} at step {}: lower lr or enable grad_clip_norm", stats.loss, trainer.step));
        }
        recent.push(stats.psnr);
        if recent.len() > 50 {
            recent.remove(0);
        }
        let mean_psnr = recent.iter().sum::<f32>() / recent.len() as f32;
        bar.set_position(trainer.step as u64);
        let budget = budget_s.map(|b| format!(" | {:.1}/{:.0} min", elapsed() / 60.0, b / 60.0)).unwrap_or_default();
        bar.set_message(format!("loss {:.4} psnr {:.2}{budget}", stats.loss, mean_psnr));
        if trainer.step % config.checkpoint_every == 0 {
            trainer.save(&options.run, elapsed())?;
        }
        if elapsed() >= next_eval_s {
            if let Some(val) = &val_data {
                let p = trainer.view_psnr(val, 0);
                val_psnr = Some(p);
                let occupied = trainer.occupancy().map(|g| format!(", {:.1}% of the grid occupied", 100.0 * g.occupied_fraction())).unwrap_or_default();
                bar.println(format!("step {}: val {} PSNR {p:.2} dB{occupied}", trainer.step, val.views[0].name));
            }
            let _ = writeln!(curve, "{},{:.2},{:.3},{}", trainer.step, elapsed() / 60.0, mean_psnr, val_psnr.map(|p| format!("{p:.3}")).unwrap_or_default());
            next_eval_s += config.eval_every_min * 60.0;
        }
    }
    trainer.save(&options.run, elapsed())?;
    bar.finish();
    let train_psnr = recent.iter().sum::<f32>() / recent.len().max(1) as f32;
    if let Some(val) = &val_data {
        let p = trainer.view_psnr(val, 0);
        val_psnr = Some(p);
    }
    let _ = writeln!(curve, "{},{:.2},{:.3},{}", trainer.step, elapsed() / 60.0, train_psnr, val_psnr.map(|p| format!("{p:.3}")).unwrap_or_default());
    Ok(TrainSummary { steps: trainer.step, train_psnr, val_psnr, minutes: elapsed() / 60.0 })
}
