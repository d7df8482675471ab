//! One training step of the hash-grid field (instant-ngp / nerfacc style): rays from several
//! random training images, samples marched through the occupancy grid's occupied cells (a
//! jittered fine step), the field on exactly those samples, compositing and its gradient in
//! plain Rust ([`nerf_core::render::gradient`]), then the MLPs' backward pass
//! ([`super::fused`]), the features' gradient scattered into the table, sparse Adam on the
//! table and burn's Adam on the MLPs.

use super::appearance::{APPEARANCE_FILE, Appearance, FixedAppearance, RenderedAppearance};
use super::field::NgpField;
use super::fused::RowCodes;
use super::state::{GRID_FILE, load_grid, state_to_bytes};
use crate::config::TrainConfig;
use crate::error::{Error, Result};
use crate::field::seam::{FieldTrainer, StepStats, StepTiming, TrainedField};
use crate::run_dir::{Checkpoint, CheckpointState, RunDir};
use crate::train::packed::{composite_packed, composite_packed_backward, visible_samples};
use crate::train::occupancy;
use burn::module::Module;
use burn::optim::{AdamConfig, ModuleOptimizer};
use burn::tensor::Device;
use nerf_core::camera::point_at;
use nerf_core::dataset::{Background, RayBatcher, SplitData};
use super::adam::{SparseAdam, SparseAdamConfig};
use nerf_core::field::ngp::hash_grid::HashGridGradient;
use nerf_core::field::ngp::spherical_harmonics::{SH4_DIM, sh4};
use nerf_core::render::metrics::psnr_from_mse;
use nerf_core::sample::occupancy::OccupancyGrid;
use nerf_core::render::grid::occupied_samples;
use nerf_core::{Rays, Rng};
use std::time::Instant;

/// Fewest and most rays in one step, whatever the samples per ray.
const MIN_RAYS: usize = 64;
const MAX_RAYS: usize = 1 << 14;

/// Trains a [`NgpField`].
pub struct NgpTrainer {
    config: TrainConfig,
    /// `None` only inside [`FieldTrainer::step`].
    field: Option<NgpField>,
    optim: ModuleOptimizer,
    table_adam: SparseAdam,
    grad: HashGridGradient,
    rng: Rng,
    step: usize,
    batcher: RayBatcher,
    occupancy: OccupancyGrid,
    /// Samples per ray in the last step (sets the next step's ray count).
    samples_per_ray: f32,
    /// One code per training image, when the run learns appearance.
    appearance: Option<Appearance>,
}

impl NgpTrainer {
    /// A fresh trainer on `train` data (the table from `config.seed`, the MLPs from the device's
    /// seed).
    pub fn new(config: TrainConfig, train: SplitData, device: Device) -> Result<Self> {
        config.validate()?;
        device.seed(config.seed);
        let field = NgpField::new(config.shapes.ngp, config.seed, &device).map_err(Error::Config)?;
        let optim = AdamConfig::new().with_beta_1(config.adam_beta1).with_beta_2(config.adam_beta2).with_epsilon(config.adam_epsilon).init();
        let table_adam = SparseAdam::new(table_adam_config(&config), &field.grid);
        let grad = HashGridGradient::new(&field.grid);
        let samples_per_ray = (config.target_samples as f32 / config.batch_rays.max(1) as f32).max(1.0);
        let appearance = config.appearance.then(|| Appearance::new(train.views.iter().map(|v| v.name.clone()).collect(), config.shapes.ngp.color_hidden));
        Ok(NgpTrainer {
            rng: Rng::new(config.seed),
            occupancy: OccupancyGrid::from_config(&config.occupancy),
            batcher: RayBatcher::new(train)?,
            field: Some(field),
            optim,
            table_adam,
            grad,
            step: 0,
            config,
            samples_per_ray,
            appearance,
        })
    }

    fn field(&self) -> &NgpField {
        self.field.as_ref().expect("field present outside a step")
    }

    /// The field without autodiff (a copy of the table; for renders and export).
    pub fn field_snapshot(&self) -> NgpField {
        let f = self.field();
        let appearance = self.appearance.as_ref().map(|a| RenderedAppearance::new(a.clone(), FixedAppearance::Mean).expect("the mean always exists"));
        NgpField { spec: f.spec, grid: f.grid.clone(), mlps: f.mlps.valid(), appearance }
    }

    /// Re-measure the grid's densities with the density MLP.
    fn update_occupancy(&mut self) {
        let field = self.field.as_ref().expect("field present outside a step");
        occupancy::update(&mut self.occupancy, &self.config.occupancy, &mut self.rng, |points| field.density(points));
    }

    /// This step's rays, their target colours, the backgrounds they are composited on and the
    /// training image each came from: about `target_samples / samples_per_ray` rays,
    /// `rays_per_image` from each of several random images. With random backgrounds each ray
    /// gets its own colour, and the target is the (premultiplied) pixel over it.
    fn draw_rays(&mut self) -> (Rays, Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<u32>) {
        let n_rays = ((self.config.target_samples as f32 / self.samples_per_ray.max(1.0)) as usize).clamp(MIN_RAYS, MAX_RAYS);
        let images = n_rays.div_ceil(self.config.rays_per_image.max(1));
        let background = self.config.train_background.unwrap_or(Background::from_white(self.config.white_background));
        let mut rays = Rays::with_capacity(n_rays);
        let mut targets = Vec::with_capacity(n_rays);
        let mut backgrounds = Vec::with_capacity(n_rays);
        let mut image_of_ray = Vec::with_capacity(n_rays);
        for k in 0..images {
            let part = n_rays * (k + 1) / images - n_rays * k / images;
            let (index, pixels, target) = self.batcher.next_batch(&mut self.rng, part, None);
            let view = &self.batcher.data().views[index];
            let drawn = if self.config.jitter_pixels == Some(true) {
                Rays::for_image_points(&view.camera, &view.pose, jittered(&pixels, &mut self.rng))
            } else {
                Rays::for_pixels(&view.camera, &view.pose, &pixels)
            };
            rays.extend(self.config.sampling.warp_rays(drawn));
            image_of_ray.resize(rays.len(), index as u32);
            for (&(i, j), mut t) in pixels.iter().zip(target) {
                let b = match background {
                    Background::White => [1.0; 3],
                    Background::Black => [0.0; 3],
                    Background::Random => {
                        let b = [self.rng.uniform(), self.rng.uniform(), self.rng.uniform()];
                        let a = view.alpha.as_ref().map_or(1.0, |a| a[(j * view.camera.width + i) as usize]);
                        t = [0, 1, 2].map(|c| t[c] + (1.0 - a) * b[c]);
                        b
                    }
                };
                targets.push(t);
                backgrounds.push(b);
            }
        }
        (rays, targets, backgrounds, image_of_ray)
    }
}

fn table_adam_config(config: &TrainConfig) -> SparseAdamConfig {
    SparseAdamConfig { learning_rate: config.lr as f32, beta1: config.adam_beta1, beta2: config.adam_beta2, epsilon: config.adam_epsilon }
}

impl FieldTrainer for NgpTrainer {
    fn config(&self) -> &TrainConfig {
        &self.config
    }

    fn steps_done(&self) -> usize {
        self.step
    }

    fn step(&mut self, lr: f64) -> StepStats {
        let start = Instant::now();
        if occupancy::due(&self.config.occupancy, self.step) {
            self.update_occupancy();
        }
        let (rays, targets, backgrounds, image_of_ray) = self.draw_rays();
        let s = &self.config.sampling;
        let mut samples = occupied_samples(&self.occupancy, &rays, s.near, s.far, self.config.march_steps, Some(&mut self.rng));
        self.step += 1;
        if samples.t.is_empty() {
            self.samples_per_ray = 1.0 / rays.len() as f32;
            // Nothing occupied along these rays: they render the background, nothing to learn.
            let mse = mean_squared_error(&backgrounds, &targets).0;
            return StepStats { loss: mse, psnr: psnr_from_mse(mse), samples: 0, timing: StepTiming { forward_s: start.elapsed().as_secs_f64(), ..StepTiming::default() } };
        }
        let mut points = Vec::with_capacity(samples.t.len());
        for r in 0..rays.len() {
            for i in samples.ray(r) {
                points.push(point_at(rays.origins[r], rays.directions[r], samples.t[i]));
            }
        }
        let mut field = self.field.take().expect("field present");
        let mlps = field.fused();
        let encode = Instant::now();
        let (mut unit, mut features) = field.encode(&points);
        let mut grid_s = encode.elapsed().as_secs_f64();
        if self.config.early_stop_transmittance > 0.0 {
            let (kept, index) = visible_samples(&samples, &mlps.density(&features), self.config.early_stop_transmittance);
            let width = field.grid.output_dim();
            features = index.iter().flat_map(|&i| &features[i * width..(i + 1) * width]).copied().collect();
            unit = index.iter().map(|&i| unit[i]).collect();
            samples = kept;
        }
        let n = samples.t.len();
        self.samples_per_ray = n.max(1) as f32 / rays.len() as f32;
        let viewdirs = rays.view_directions();
        let mut sh = Vec::with_capacity(n * SH4_DIM);
        let mut code_of_row = Vec::with_capacity(if self.appearance.is_some() { n } else { 0 });
        for r in 0..rays.len() {
            let ray_sh = sh4(viewdirs[r]);
            samples.ray(r).for_each(|_| sh.extend_from_slice(&ray_sh));
            if self.appearance.is_some() {
                code_of_row.resize(code_of_row.len() + samples.ray(r).len(), image_of_ray[r]);
            }
        }
        let codes = self.appearance.as_ref().map(|a| RowCodes { codes: a.codes(), code_of_row: &code_of_row });
        let ((rgb, sigma), saved) = mlps.forward_train(&features, &sh, codes);
        let (colors, _) = composite_packed(&samples, &sigma, &rgb, &backgrounds);
        let (mse, grad_color) = mean_squared_error(&colors, &targets);
        let (grad_sigma, grad_rgb) = composite_packed_backward(&samples, &sigma, &rgb, &backgrounds, &grad_color);
        let forward_done = Instant::now();
        let (mlp_grads, grad_features) = mlps.backward(&features, &sh, codes, &saved, &grad_rgb, &grad_sigma);
        let scatter = Instant::now();
        field.grid.backward(&unit, &grad_features, &mut self.grad);
        grid_s += scatter.elapsed().as_secs_f64();
        let params = mlp_grads.to_params(&field.mlps, &crate::backend::cpu());
        let backward_done = Instant::now();
        self.table_adam.config.learning_rate = lr as f32;
        self.table_adam.step(&mut field.grid, &mut self.grad);
        grid_s += backward_done.elapsed().as_secs_f64();
        field.mlps = self.optim.step(lr, field.mlps, params);
        if let Some(a) = &mut self.appearance {
            a.step(&mlp_grads.codes, lr as f32, self.config.adam_beta1, self.config.adam_beta2, self.config.adam_epsilon);
        }
        self.field = Some(field);
        let timing = StepTiming {
            forward_s: (forward_done - start).as_secs_f64(),
            backward_s: (backward_done - forward_done).as_secs_f64(),
            update_s: backward_done.elapsed().as_secs_f64(),
            grid_s,
        };
        StepStats { loss: mse, psnr: psnr_from_mse(mse), samples: n, timing }
    }

    fn save(&self, run: &RunDir, elapsed_s: f64) -> Result<Checkpoint> {
        let state = CheckpointState { samples_per_ray: Some(self.samples_per_ray), ..CheckpointState::new(self.step, self.rng.clone(), elapsed_s) };
        let field = self.field();
        let mut files = vec![
            ("model.bpk", Checkpoint::model_bytes(&field.mlps)?),
            ("optim.bpk", Checkpoint::optimizer_bytes(&self.optim)?),
            (GRID_FILE, state_to_bytes(&field.grid, &self.table_adam)),
        ];
        files.extend(self.appearance.as_ref().map(|a| (APPEARANCE_FILE, a.to_bytes())));
        run.save_checkpoint(&files, Some(&self.occupancy), &state)
    }

    fn resume(&mut self, checkpoint: &Checkpoint) -> Result<f64> {
        let state = checkpoint.state()?;
        let mut field = self.field.take().expect("field present");
        let loaded = checkpoint.load_model(&mut field.mlps);
        let grid = load_grid(checkpoint, &self.config.shapes.ngp.grid, table_adam_config(&self.config));
        self.field = Some(field);
        loaded?;
        let (grid, adam) = grid?;
        self.field.as_mut().expect("field present").grid = grid;
        self.table_adam = adam;
        self.optim = checkpoint.load_optimizer(self.optim.clone())?;
        if self.appearance.is_some() {
            let codes = Appearance::read(&checkpoint.dir, self.config.shapes.ngp.color_hidden)?;
            if codes.images() != self.appearance.as_ref().map_or(&[][..], |a| a.images()) {
                let problem = "its codes are for other training images than this run's data (the images changed since it was saved)".to_string();
                return Err(Error::invalid(&checkpoint.dir.join(APPEARANCE_FILE), problem));
            }
            self.appearance = Some(codes);
        }
        if let Some(o) = checkpoint.load_occupancy()? {
            self.occupancy = o;
        }
        self.step = state.step;
        self.rng = state.rng;
        if let Some(s) = state.samples_per_ray.filter(|s| s.is_finite() && *s > 0.0) {
            self.samples_per_ray = s;
        }
        Ok(state.elapsed_s)
    }

    fn snapshot(&self) -> Box<dyn TrainedField> {
        Box::new(self.field_snapshot())
    }

    fn occupancy(&self) -> Option<&OccupancyGrid> {
        Some(&self.occupancy)
    }
}

/// MSE over rays and channels, and its gradient with respect to each ray's colour.
fn mean_squared_error(colors: &[[f32; 3]], targets: &[[f32; 3]]) -> (f32, Vec<[f32; 3]>) {
    let count = (3 * colors.len()).max(1) as f32;
    let mut sum = 0.0f64;
    let grad = colors
        .iter()
        .zip(targets)
        .map(|(c, t)| {
            [0, 1, 2].map(|k| {
                let d = c[k] - t[k];
                sum += (d * d) as f64;
                2.0 * d / count
            })
        })
        .collect();
    ((sum / count as f64) as f32, grad)
}

/// A uniformly random point of each pixel's area, `(i, j) ± 0.5` (a pixel's ray is at its
/// integer coordinates).
fn jittered<'a>(pixels: &'a [(u32, u32)], rng: &'a mut Rng) -> impl ExactSizeIterator<Item = (f32, f32)> + 'a {
    pixels.iter().map(move |&(i, j)| (i as f32 + rng.uniform() - 0.5, j as f32 + rng.uniform() - 0.5))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jittered_points_cover_their_pixel_and_repeat_with_the_seed() {
        let pixels: Vec<(u32, u32)> = (0..4000).map(|k| (k % 7, k / 7)).collect();
        let points: Vec<(f32, f32)> = jittered(&pixels, &mut Rng::new(3)).collect();
        let offsets: Vec<f32> = pixels.iter().zip(&points).flat_map(|(&(i, j), &(x, y))| [x - i as f32, y - j as f32]).collect();
        assert!(offsets.iter().all(|o| (-0.5..0.5).contains(o)));
        // Uniform over the pixel: the offsets span it and average to its centre.
        let (low, high) = offsets.iter().fold((0.0f32, 0.0f32), |(l, h), &o| (l.min(o), h.max(o)));
        assert!(low < -0.49 && high > 0.49, "{low} {high}");
        assert!((offsets.iter().sum::<f32>() / offsets.len() as f32).abs() < 0.01);
        assert_eq!(jittered(&pixels, &mut Rng::new(3)).collect::<Vec<_>>(), points);
        assert_ne!(jittered(&pixels, &mut Rng::new(4)).collect::<Vec<_>>(), points);
    }
}
