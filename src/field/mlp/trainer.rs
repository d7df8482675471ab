//! One training step: a random image, rays through random pixels (centre crop first), coarse
//! + fine networks rendered differentiably, MSE on both, one Adam update.

use super::volume::{VolumeOutput, composite, deltas_tensor};
use super::{NerfMlp, NerfModel, encoded_tensor};
use crate::config::TrainConfig;
use crate::error::Result;
use crate::field::seam::{FieldTrainer, StepStats, StepTiming, TrainedField};
use crate::inference::vec3_tensor;
use crate::run_dir::{Checkpoint, CheckpointState, RunDir};
use crate::train::occupancy;
use burn::grad_clipping::GradientClippingConfig;
use burn::module::{Module, ModuleMapper, Param};
use burn::optim::{AdamConfig, GradientsAccumulator, GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, IndexingUpdateOp, Int, Tensor, TensorData};
use nerf_core::dataset::{RayBatcher, SplitData};
use nerf_core::render::metrics::psnr_from_mse;
use nerf_core::sample::occupancy::OccupancyGrid;
use nerf_core::sample::stratified::{DenseSamples, importance, stratified};
use nerf_core::{Rays, Rng};
use std::time::Instant;

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
    pub fn new(config: TrainConfig, train: SplitData, device: Device) -> Result<Self> {
        config.validate()?;
        device.seed(config.seed);
        let model = NerfModel::new(&config.shapes.network, config.sampling.n_fine > 0, &device);
        let mut adam = AdamConfig::new()
            .with_beta_1(config.adam_beta1)
            .with_beta_2(config.adam_beta2)
            .with_epsilon(config.adam_epsilon);
        if let Some(norm) = config.grad_clip_norm {
            adam = adam.with_grad_clipping(Some(GradientClippingConfig::Norm(norm)));
        }
        let batcher = RayBatcher::new(train)?;
        let occupancy = config.skip_empty_space.then(|| OccupancyGrid::from_config(&config.occupancy));
        Ok(Trainer { rng: Rng::new(config.seed), optim: adam.init(), model: Some(model), config, step: 0, device, batcher, occupancy })
    }

    /// Restore model, optimizer, step and RNG from a checkpoint.
    pub fn resume(&mut self, checkpoint: &Checkpoint) -> Result<f64> {
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
    pub fn save(&self, run: &RunDir, elapsed_s: f64) -> Result<Checkpoint> {
        let state = CheckpointState::new(self.step, self.rng.clone(), elapsed_s);
        let files = [("model.bpk", Checkpoint::model_bytes(self.model())?), ("optim.bpk", Checkpoint::optimizer_bytes(&self.optim)?)];
        run.save_checkpoint(&files, self.occupancy.as_ref(), &state)
    }

    /// The occupancy grid, when empty-space skipping is on.
    pub fn occupancy(&self) -> Option<&OccupancyGrid> {
        self.occupancy.as_ref()
    }

    /// Re-measure the grid's densities with the fine (or only) network.
    fn update_occupancy(&mut self) {
        let Some(mut grid) = self.occupancy.take() else { return };
        let snapshot = self.model().valid();
        let net = snapshot.last();
        let device = snapshot.coarse_device();
        occupancy::update(&mut grid, &self.config.occupancy, &mut self.rng, |points| {
            let x = encoded_tensor(&net.spec().position_encoding, points, &device);
            net.density(x).into_data().try_to_vec::<f32>().expect("f32 densities")
        });
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
    pub fn step(&mut self, lr: f64) -> StepStats {
        let start = Instant::now();
        if self.occupancy.is_some() && occupancy::due(&self.config.occupancy, self.step) {
            self.update_occupancy();
        }
        let cfg = &self.config;
        let precrop = (self.step < cfg.precrop_iters).then_some(cfg.precrop_fraction);
        let batch = self.batcher.next_batch(&mut self.rng, cfg.batch_rays, precrop);
        let data = self.batcher.data();
        let view = &data.views[batch.0];
        let rays = cfg.sampling.warp_rays(Rays::for_pixels(&view.camera, &view.pose, &batch.1));
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
        self.model = Some(self.optim.step(lr, model, accumulated.grads()));
        self.step += 1;
        timing.update_s = mark.elapsed().as_secs_f64();
        StepStats { loss: loss_value, psnr: psnr_from_mse(mse_value), samples: rays.len() * samples_per_ray, timing }
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

impl FieldTrainer for Trainer {
    fn config(&self) -> &TrainConfig {
        &self.config
    }

    fn steps_done(&self) -> usize {
        self.step
    }

    fn step(&mut self, lr: f64) -> StepStats {
        Trainer::step(self, lr)
    }

    fn save(&self, run: &RunDir, elapsed_s: f64) -> Result<Checkpoint> {
        Trainer::save(self, run, elapsed_s)
    }

    fn resume(&mut self, checkpoint: &Checkpoint) -> Result<f64> {
        Trainer::resume(self, checkpoint)
    }

    fn snapshot(&self) -> Box<dyn TrainedField> {
        Box::new(self.model().valid())
    }

    fn occupancy(&self) -> Option<&OccupancyGrid> {
        Trainer::occupancy(self)
    }
}
