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
use crate::train::packed::{composite_packed, composite_packed_backward, visible_samples_in_rounds};
use crate::train::distortion::{distortion_backward, step_coordinates};
use crate::train::occupancy;
use burn::module::Module;
use burn::optim::{AdamConfig, ModuleOptimizer};
use burn::tensor::Device;
use nerf_core::camera::point_at;
use nerf_core::dataset::{Background, RayBatcher, SplitData};
use super::adam::{SparseAdam, SparseAdamConfig};
use nerf_core::field::ngp::hash_grid::HashGridGradient;
use nerf_core::field::ngp::hash_grid::GridBound;
use nerf_core::field::ngp::spherical_harmonics::{SH4_DIM, sh4, sh4_backward};
use nerf_core::render::packed::PackedSamples;
use crate::train::cameras::{CAMERAS_FILE, CameraCorrections, CorrectionGradient};
use nerf_core::render::metrics::psnr_from_mse;
use nerf_core::sample::occupancy::OccupancyGrid;
use nerf_core::render::grid::{march_segments, occupied_samples};
use nerf_core::{Rays, Rng};
use std::time::Instant;

/// A step's rays, their targets, their backgrounds and the training image of each.
type DrawnRays = (Rays, Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<u32>);

/// Fewest and most rays in one step, whatever the samples per ray.
const MIN_RAYS: usize = 64;
const MAX_RAYS: usize = 1 << 14;
/// Samples per ray and round when a step measures where its rays' light is spent.
const EARLY_STOP_ROUND: usize = 32;

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
    /// One pose correction per training image, when the run refines its cameras.
    cameras: Option<CameraCorrections>,
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
        let names = || train.views.iter().map(|v| v.name.clone()).collect();
        let appearance = config.appearance.then(|| Appearance::new(names(), config.shapes.ngp.color_hidden));
        let cameras = config.refine_cameras.then(|| CameraCorrections::new(names()));
        let mut occupancy = OccupancyGrid::from_config(&config.occupancy);
        let min_views = config.occupancy.min_views;
        if min_views > 0 && config.sampling.ndc.is_some() {
            eprintln!("note: [occupancy] min_views = {min_views} is not applied: this run marches NDC rays (forward-facing)");
        } else if min_views > 0 {
            let views: Vec<_> = train.views.iter().map(|v| (v.camera, v.pose)).collect();
            let unseen = occupancy.mark_unseen(&views, min_views);
            if unseen == occupancy.len() {
                // Every ray would march through empty cells only: nothing would ever train.
                let problem = format!("[occupancy] min_views = {min_views}: no cell of the occupancy grid is seen by that many of the {} training cameras; lower it", views.len());
                return Err(Error::Config(problem));
            }
            eprintln!("occupancy grid: {unseen} of {} cells seen by fewer than {min_views} training cameras, left empty", occupancy.len());
        }
        Ok(NgpTrainer {
            rng: Rng::new(config.seed),
            occupancy,
            batcher: RayBatcher::new(train)?,
            field: Some(field),
            optim,
            table_adam,
            grad,
            step: 0,
            config,
            samples_per_ray,
            appearance,
            cameras,
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
    fn draw_rays(&mut self) -> DrawnRays {
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
            let pose = match &self.cameras {
                Some(c) => c.corrected(index, &view.pose),
                None => view.pose,
            };
            let drawn = if self.config.jitter_pixels == Some(true) {
                Rays::for_image_points(&view.camera, &pose, jittered(&pixels, &mut self.rng))
            } else {
                Rays::for_pixels(&view.camera, &pose, &pixels)
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
        let (unit, features, mut grid_s) = if self.config.early_stop_transmittance > 0.0 {
            // σ a round at a time, so that samples behind a ray's surface are mostly never encoded.
            let (mut unit, mut features, mut grid_s) = (Vec::new(), Vec::new(), 0.0);
            let (kept, position) = visible_samples_in_rounds(&samples, self.config.early_stop_transmittance, EARLY_STOP_ROUND, |batch| {
                let points: Vec<[f32; 3]> = batch.iter().map(|&i| points[i]).collect();
                let encode = Instant::now();
                let (u, f) = field.encode(&points);
                grid_s += encode.elapsed().as_secs_f64();
                let sigma = mlps.density(&f);
                unit.extend(u);
                features.extend(f);
                sigma
            });
            let width = field.grid.output_dim();
            samples = kept;
            let features = position.iter().flat_map(|&p| &features[p * width..(p + 1) * width]).copied().collect();
            (position.iter().map(|&p| unit[p]).collect(), features, grid_s)
        } else {
            let encode = Instant::now();
            let (unit, features) = field.encode(&points);
            (unit, features, encode.elapsed().as_secs_f64())
        };
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
        let (mut grad_sigma, grad_rgb) = composite_packed_backward(&samples, &sigma, &rgb, &backgrounds, &grad_color);
        let distortion = self.config.distortion_weight();
        if distortion > 0.0 {
            // λ · the mean over rays of each ray's distortion, distances in marching steps.
            let segments = march_segments(s.near, s.far, self.config.march_steps, self.occupancy.contraction());
            let steps: usize = segments.iter().map(|s| s.steps).sum();
            let grad_loss = vec![distortion / rays.len() as f32; rays.len()];
            let grad = distortion_backward(&samples, &sigma, &step_coordinates(&segments, &samples.t), 1.0 / steps as f32, &grad_loss);
            grad_sigma.iter_mut().zip(grad).for_each(|(g, d)| *g += d);
        }
        let forward_done = Instant::now();
        let mut grad_sh = vec![0.0f32; if self.cameras.is_some() { n * SH4_DIM } else { 0 }];
        let (mlp_grads, grad_features) = mlps.backward(&features, &sh, codes, &saved, &grad_rgb, &grad_sigma, self.cameras.is_some().then_some(&mut grad_sh[..]));
        if let Some(cameras) = &mut self.cameras {
            // Before the table's update: the gradient is the table's as it was in the forward pass.
            let grad_unit = field.grid.position_gradient(&unit, &grad_features);
            let grad = ray_gradients(cameras, &rays, &samples, &image_of_ray, &field.spec.bound, &grad_unit, &grad_sh);
            if let Some(lr) = crate::train::cameras::learning_rate(self.step - 1) {
                cameras.step(&grad, lr as f32);
            }
        }
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
        let poses: Vec<_> = self.batcher.data().views.iter().map(|v| v.pose).collect();
        files.extend(self.cameras.as_ref().map(|c| (CAMERAS_FILE, c.to_bytes(&poses))));
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
        if self.cameras.is_some() {
            let cameras = CameraCorrections::read(&checkpoint.dir)?;
            if cameras.images() != self.cameras.as_ref().map_or(&[][..], |c| c.images()) {
                let problem = "its corrections are for other training images than this run's data (the images changed since it was saved)".to_string();
                return Err(Error::invalid(&checkpoint.dir.join(CAMERAS_FILE), problem));
            }
            self.cameras = Some(cameras);
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

/// The cameras' gradient from the samples' gradients: per ray, the points' (`grad_unit`, with
/// respect to their unit-cube coordinates, taken back through `bound`) give the origin's and,
/// times each sample's t, the direction's; the harmonics' (`grad_sh`, `[n, 16]`) reach the
/// direction through its normalisation.
fn ray_gradients(cameras: &CameraCorrections, rays: &Rays, samples: &PackedSamples, image_of_ray: &[u32], bound: &GridBound, grad_unit: &[[f32; 3]], grad_sh: &[f32]) -> CorrectionGradient {
    let mut grad = cameras.zero_gradient();
    for r in 0..rays.len() {
        let (o, d) = (rays.origins[r], rays.directions[r]);
        let (mut g_origin, mut g_direction) = ([0.0f32; 3], [0.0f32; 3]);
        let mut g_sh = [0.0f32; SH4_DIM];
        for i in samples.ray(r) {
            let t = samples.t[i];
            let g = bound.to_unit_backward(point_at(o, d, t), grad_unit[i]);
            for a in 0..3 {
                g_origin[a] += g[a];
                g_direction[a] += t * g[a];
            }
            g_sh.iter_mut().zip(&grad_sh[i * SH4_DIM..(i + 1) * SH4_DIM]).for_each(|(s, g)| *s += g);
        }
        if samples.ray(r).is_empty() {
            continue;
        }
        // u = d/|d|: ∂L/∂d = (g_u − (g_u·u)·u)/|d|.
        let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let u = d.map(|v| v / norm);
        let g_u = sh4_backward(u, &g_sh);
        let along = g_u[0] * u[0] + g_u[1] * u[1] + g_u[2] * u[2];
        for a in 0..3 {
            g_direction[a] += (g_u[a] - along * u[a]) / norm;
        }
        cameras.add_ray(&mut grad, image_of_ray[r] as usize, d, g_origin, g_direction);
    }
    grad
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

    /// The camera of [`ray_loss`]'s rays, looking at the origin from 2.2 away.
    fn test_pose() -> nerf_core::Pose {
        nerf_core::Pose::from_mat4(glam::Mat4::look_at_rh(glam::Vec3::new(0.3, 0.4, 2.2), glam::Vec3::ZERO, glam::Vec3::Y).inverse())
    }

    /// Every pixel of the 16×16 camera of [`ray_loss_at`], or four of them.
    fn test_pixels(all: bool) -> Vec<(u32, u32)> {
        if all { (0..256).map(|k| (k % 16, k / 16)).collect() } else { vec![(3, 5), (8, 8), (12, 6), (6, 14)] }
    }

    /// The loss of rays through `pixels` of image 0 at `pose`, drawn through `cameras`'
    /// correction, fixed samples along them: `(loss, the corrections' gradient, the colours)`
    /// through the same passes as a step.
    fn ray_loss_at(field: &NgpField, cameras: &CameraCorrections, pose: &nerf_core::Pose, pixels: &[(u32, u32)], samples: &PackedSamples, targets: &[[f32; 3]]) -> (f64, CorrectionGradient, Vec<[f32; 3]>) {
        let camera = nerf_core::PinholeCamera::from(nerf_core::Intrinsics { width: 16, height: 16, focal: 18.0 });
        let rays = Rays::for_pixels(&camera, &cameras.corrected(0, pose), pixels);
        let mut points = Vec::new();
        for r in 0..rays.len() {
            points.extend(samples.ray(r).map(|i| point_at(rays.origins[r], rays.directions[r], samples.t[i])));
        }
        let (unit, features) = field.encode(&points);
        let viewdirs = rays.view_directions();
        let mut sh = Vec::new();
        for r in 0..rays.len() {
            samples.ray(r).for_each(|_| sh.extend(sh4(viewdirs[r])));
        }
        let mlps = field.fused();
        let ((rgb, sigma), saved) = mlps.forward_train(&features, &sh, None);
        let backgrounds = vec![[1.0; 3]; rays.len()];
        let (colors, _) = composite_packed(samples, &sigma, &rgb, &backgrounds);
        let (mse, grad_color) = mean_squared_error(&colors, targets);
        let (grad_sigma, grad_rgb) = composite_packed_backward(samples, &sigma, &rgb, &backgrounds, &grad_color);
        let mut grad_sh = vec![0.0; sh.len()];
        let (_, grad_features) = mlps.backward(&features, &sh, None, &saved, &grad_rgb, &grad_sigma, Some(&mut grad_sh));
        let grad_unit = field.grid.position_gradient(&unit, &grad_features);
        let image_of_ray = vec![0; rays.len()];
        // the loss in f64 from the f32 colours, for the finite differences
        let loss = colors.iter().zip(targets).map(|(c, t)| (0..3).map(|k| ((c[k] - t[k]) as f64).powi(2)).sum::<f64>()).sum::<f64>() / (3 * colors.len()) as f64;
        assert!((loss - mse as f64).abs() < 1e-5);
        (loss, ray_gradients(cameras, &rays, samples, &image_of_ray, &field.spec.bound, &grad_unit, &grad_sh), colors)
    }

    fn ray_loss(field: &NgpField, cameras: &CameraCorrections, samples: &PackedSamples, targets: &[[f32; 3]]) -> (f64, CorrectionGradient) {
        let (loss, grad, _) = ray_loss_at(field, cameras, &test_pose(), &test_pixels(false), samples, targets);
        (loss, grad)
    }

    /// A small field of order-1 features and `per_ray` samples along each of `rays` rays from
    /// t = 1.4 (through the box ±1 from [`test_pose`]).
    fn test_field(bound: nerf_core::field::ngp::hash_grid::GridBound, rays: usize, per_ray: usize, max_resolution: u32) -> (NgpField, PackedSamples) {
        use nerf_core::field::ngp::NgpSpec;
        use nerf_core::field::ngp::hash_grid::HashGridConfig;
        let spec = NgpSpec {
            grid: HashGridConfig { levels: 3, features_per_level: 2, log2_table_size: 12, base_resolution: 2, max_resolution },
            bound,
            density_hidden: 16,
            geometry_features: 7,
            color_hidden: 16,
        };
        let mut field = NgpField::new(spec, 3, &crate::backend::cpu()).unwrap();
        let mut rng = Rng::new(4);
        field.grid.params_mut().iter_mut().for_each(|v| *v = rng.uniform() * 2.0 - 1.0);
        let t: Vec<f32> = (0..rays).flat_map(|r| (0..per_ray).map(move |k| 1.4 + 1.44 / per_ray as f32 * k as f32 + 0.01 * (r % 4) as f32)).collect();
        let samples = PackedSamples { delta: vec![1.44 / per_ray as f32; t.len()], t, offsets: (0..=rays).map(|r| r * per_ray).collect() };
        (field, samples)
    }

    #[test]
    fn refinement_recovers_a_misrecorded_camera_against_a_fixed_field() {
        use nerf_core::field::ngp::hash_grid::GridBound;
        let (field, samples) = test_field(GridBound::cube(1.0), 256, 24, 12);
        // Colours that vary across the image (an untrained colour MLP is a flat grey).
        let mut plain = field.to_plain();
        plain.layers.iter_mut().filter(|l| l.name.starts_with("color")).for_each(|l| l.weight.iter_mut().for_each(|w| *w *= 4.0));
        let field = NgpField::from_plain(&plain, &crate::backend::cpu()).unwrap();
        let pixels = test_pixels(true);
        // The photo is taken from the true pose; the pose recorded is 3° off (about an axis
        // across the view) and 0.05 aside; only the correction learns, the field stays.
        let truth = test_pose();
        let error = glam::Mat3::from_axis_angle(glam::Vec3::new(1.0, 0.5, 0.0).normalize(), 3f32.to_radians());
        let (r, c) = (error * truth.rotation(), truth.origin() + glam::Vec3::new(0.05, 0.0, -0.02));
        let recorded = nerf_core::Pose([0, 1, 2].map(|i| [r.col(0)[i], r.col(1)[i], r.col(2)[i], c[i]]));
        let none = CameraCorrections::new(vec!["a".into()]);
        let (_, _, photo) = ray_loss_at(&field, &none, &truth, &pixels, &samples, &vec![[0.5; 3]; 256]);
        let spread = photo.iter().map(|c| c[0]).fold(0.0f32, f32::max) - photo.iter().map(|c| c[0]).fold(1.0f32, f32::min);
        assert!(spread > 0.3, "the photo is nearly flat: red spans {spread}");
        let angle = |p: &nerf_core::Pose| {
            let m = p.rotation().transpose() * truth.rotation();
            ((m.x_axis.x + m.y_axis.y + m.z_axis.z - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
        };
        let mut cameras = none.clone();
        let (first, ..) = ray_loss_at(&field, &cameras, &recorded, &pixels, &samples, &photo);
        for _ in 0..300 {
            let (_, grad, _) = ray_loss_at(&field, &cameras, &recorded, &pixels, &samples, &photo);
            cameras.step(&grad, 2e-3);
        }
        let (last, ..) = ray_loss_at(&field, &cameras, &recorded, &pixels, &samples, &photo);
        let refined = cameras.corrected(0, &recorded);
        let (before, after) = (angle(&recorded), angle(&refined));
        let (moved_before, moved_after) = ((recorded.origin() - truth.origin()).length(), (refined.origin() - truth.origin()).length());
        // A small sideways shift looks much like a small turn from 2 units away: the turn is
        // recovered, and the centre (held by the translation penalty) does not wander.
        assert!(after < 0.3 * before && moved_after < moved_before + 0.01 && last < 0.1 * first, "rotation error {before:.2}° → {after:.2}°, centre {moved_before:.3} → {moved_after:.3}, loss {first:.2e} → {last:.2e}");
    }

    #[test]
    fn the_cameras_gradient_through_a_step_matches_finite_differences() {
        use nerf_core::field::ngp::hash_grid::GridBound;
        for bound in [GridBound::cube(1.0), GridBound::contracted(nerf_core::sample::Contraction::Linf)] {
            // A table of order 1 (densities and colours that vary with position), 12 samples per
            // ray from 1.4 to 2.8, about the field's box ±1 (the contracted one's inner cube and
            // shell).
            let (field, samples) = test_field(bound, 4, 12, 5);
            let targets = [[0.2, 0.5, 0.9], [0.7, 0.1, 0.3], [0.4, 0.4, 0.4], [0.9, 0.8, 0.1]];
            let mut cameras = CameraCorrections::new(vec!["a".into()]);
            cameras.step(&{
                // Away from zero, where the rotation's Jacobian is not the identity.
                let mut g = cameras.zero_gradient();
                cameras.add_ray(&mut g, 0, [0.3, -0.2, 0.9], [0.5, -0.4, 0.2], [1.0, 0.3, -0.7]);
                g
            }, 0.05);
            let (_, grad) = ray_loss(&field, &cameras, &samples, &targets);
            let mut checked = 0;
            for a in 0..6 {
                let eps = 1e-3f32;
                let at = |delta: f32| ray_loss(&field, &cameras.nudged(0, a, delta), &samples, &targets).0;
                let numeric = (at(eps) - at(-eps)) / (2.0 * eps as f64);
                let got = grad.of(0)[a] as f64;
                // The trilinear cells and the ReLUs are piecewise linear: a step can cross a kink.
                assert!((got - numeric).abs() < 5e-2 * numeric.abs() + 1e-4, "{bound:?} parameter {a}: {got} vs {numeric}");
                checked += (numeric.abs() > 1e-3) as usize;
            }
            assert!(checked >= 5, "{bound:?}: only {checked} of 6 gradients are away from zero");
        }
    }

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
