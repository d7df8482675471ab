//! Training configuration, presets, and TOML files that override a preset.

use crate::error::{Error, Result};
use nerf_core::SamplingConfig;
use nerf_core::dataset::Background;
use nerf_core::field::mlp::{EncodingSpec, NetworkSpec};
use nerf_core::field::{FieldKind, FieldShapes};
use nerf_core::field::ngp::hash_grid::GridBound;
use nerf_core::sample::Contraction;
use nerf_core::sample::occupancy::OccupancyConfig;
use nerf_core::io::limits::{self, Origin};
use nerf_core::render::{DEFAULT_MARCH_STEPS, RenderOptions};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Default [`TrainConfig::pass_points`]: the paper step (1024 rays × 192 samples) runs as
/// four passes of 256 rays, two at a time, so only two passes' activations are in memory
/// (docs/benchmarks.md, "Training speed and memory").
pub const DEFAULT_PASS_POINTS: usize = 1 << 16;

/// The named starting points for a configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Preset {
    /// The reference configuration (bmild/nerf lego): 8×256 networks, 1024 rays, 64 + 128
    /// samples, lr 5e-4 decaying 10× per 500k steps.
    Paper,
    /// Sized for a 2-core CPU and a 30-minute budget at 100×100: 6×128 networks (skip after
    /// the 4th layer), 32 + 64 samples, 256 rays per step (many cheap steps beat few big ones
    /// on a CPU), lr 1e-3 decaying 10× per 5k steps.
    CpuFast,
    /// The instant-ngp field: a multiresolution hash grid and two tiny MLPs, trained on packed
    /// samples marched through the occupancy grid (2¹⁶ samples per step, 1024 intervals over
    /// [near, far]), lr 1e-2 (table and MLPs), ×0.33 at 50, 75 and 90% of the run.
    Ngp,
}

impl Preset {
    /// The preset used when none is named: `ngp`, which beats `cpu-fast` on quality per minute
    /// on a 2-core CPU (docs/hash-grid.md and docs/quality.md).
    pub const DEFAULT: Preset = Preset::Ngp;

    /// The preset's name as written in configs.
    pub fn name(&self) -> &'static str {
        match self {
            Preset::Paper => "paper",
            Preset::CpuFast => "cpu-fast",
            Preset::Ngp => "ngp",
        }
    }

    /// The full configuration of this preset.
    pub fn config(&self) -> TrainConfig {
        match self {
            Preset::Paper => TrainConfig {
                preset: *self,
                shapes: FieldShapes { network: NetworkSpec::paper(), ..FieldShapes::default() },
                sampling: SamplingConfig { near: 2.0, far: 6.0, n_coarse: 64, n_fine: 128, lindisp: false, ndc: None },
                white_background: true,
                train_background: None,
                batch_rays: 1024,
                iters: 200_000,
                lr: 5e-4,
                lr_decay_ksteps: 500.0,
                lr_schedule: crate::train::LrSchedule::Exponential,
                lr_min: 0.0,
                lr_anneal_fraction: 0.0,
                adam_beta1: 0.9,
                adam_beta2: 0.999,
                adam_epsilon: 1e-7,
                grad_clip_norm: None,
                precrop_iters: 500,
                precrop_fraction: 0.5,
                seed: 0,
                checkpoint_every: 5_000,
                eval_every_min: 10.0,
                chunk: 4096,
                pass_points: DEFAULT_PASS_POINTS,
                concurrent_passes: 2,
                skip_empty_space: false,
                occupancy: OccupancyConfig::default(),
                field: FieldKind::Mlp,
                target_samples: DEFAULT_TARGET_SAMPLES,
                march_steps: DEFAULT_MARCH_STEPS,
                render_march_steps: None,
                rays_per_image: default_rays_per_image(),
                jitter_pixels: None,
                early_stop_transmittance: 0.0,
                distortion_loss: None,
                appearance: false,
                refine_cameras: false,
                file_keys: Vec::new(),
            },
            Preset::CpuFast => TrainConfig {
                preset: *self,
                shapes: FieldShapes {
                    network: NetworkSpec {
                        depth: 6,
                        width: 128,
                        skips: vec![3],
                        position_encoding: EncodingSpec { n_frequencies: 10, include_input: true },
                        direction_encoding: EncodingSpec { n_frequencies: 4, include_input: true },
                        use_viewdirs: true,
                    },
                    ..FieldShapes::default()
                },
                sampling: SamplingConfig { near: 2.0, far: 6.0, n_coarse: 32, n_fine: 64, lindisp: false, ndc: None },
                batch_rays: 256,
                iters: 20_000,
                lr: 1e-3,
                lr_decay_ksteps: 10.0,
                checkpoint_every: 500,
                eval_every_min: 5.0,
                skip_empty_space: true,
                ..Preset::Paper.config()
            },
            Preset::Ngp => TrainConfig {
                preset: *self,
                field: FieldKind::Ngp,
                sampling: SamplingConfig { near: 2.0, far: 6.0, n_coarse: 64, n_fine: 0, lindisp: false, ndc: None },
                batch_rays: 256,
                iters: 100_000,
                lr: 1e-2,
                lr_decay_ksteps: 10.0,
                // nerfacc's: 1e-2 to half-way through the budget, then ×0.33 at 50, 75 and
                // 90%. Lego, 60 minutes: 31.77 dB (step-count decay) → 32.24 dB over the 100 val
                // views (docs/quality.md).
                lr_schedule: crate::train::LrSchedule::Planned,
                // nerfacc's last rate (1e-2 · 0.33³): the planned schedule's last phase.
                lr_min: 3.6e-4,
                adam_beta1: 0.9,
                adam_beta2: 0.99,
                adam_epsilon: 1e-15,
                precrop_iters: 0,
                // A checkpoint holds the table and its Adam moments (≈ 190 MB at T = 2¹⁹).
                checkpoint_every: 1000,
                eval_every_min: 5.0,
                chunk: 4096,
                skip_empty_space: true,
                occupancy: OccupancyConfig {
                    resolution: 64,
                    bound: 1.5,
                    // σ at which one marching interval (≈ 4/1024 world units) is 1% opaque.
                    threshold: 2.5,
                    decay: 0.95,
                    update_every: 16,
                    warmup_steps: 64,
                    threshold_at_most_mean: true,
                    contraction: None,
                    min_views: 0,
                },
                march_steps: 1024,
                render_march_steps: Some(2048),
                // 1e-4 (nerfacc's) gave lego at 400×400 +0.7 dB after 10 minutes over keeping
                // every sample (docs/quality.md); 0.01 keeps a quarter of fox's samples a ray, so
                // a step holds four times the rays: +1.58 dB on fox, +0.94 on fern, +0.36 on lego
                // at 10 minutes (docs/captures.md).
                early_stop_transmittance: 0.01,
                ..Preset::Paper.config()
            },
        }
    }
}

/// Everything that defines a training run; written to `<run>/config.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    /// The preset this configuration started from.
    pub preset: Preset,
    /// Near/far and samples per ray.
    pub sampling: SamplingConfig,
    /// Composite on white (Blender scenes).
    pub white_background: bool,
    /// What training rays are composited on: `white`, `black` or `random` (a new colour per
    /// ray, the hash-grid field only). Absent: decided when the run starts (random for the
    /// hash-grid field on captures, whose opaque photos it teaches full opacity; otherwise
    /// `white_background`'s colour) and recorded here.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_background: Option<Background>,
    /// Rays per step, all from one random training image.
    pub batch_rays: usize,
    /// Steps to train for.
    pub iters: usize,
    /// Initial Adam learning rate.
    pub lr: f64,
    /// The learning rate falls 10× every this many thousand steps (`exponential` schedule).
    pub lr_decay_ksteps: f64,
    /// How the learning rate moves over the run (a run's config.toml from before the key:
    /// `exponential`, see [`TrainConfig::from_run_toml`]).
    #[serde(default)]
    pub lr_schedule: crate::train::LrSchedule,
    /// The learning rate never falls below this: a long run keeps learning instead of
    /// freezing (the exponential decay is 1e-5 after 30k steps). 0 = no floor.
    #[serde(default)]
    pub lr_min: f64,
    /// Over this last fraction of the run (of its time budget, or of `iters`), the
    /// `exponential` schedule's rate falls a further 10×, exponentially: the end of a run
    /// settles at a small step whatever its length. 0 = none.
    #[serde(default)]
    pub lr_anneal_fraction: f64,
    /// Adam β₁.
    pub adam_beta1: f32,
    /// Adam β₂.
    pub adam_beta2: f32,
    /// Adam ε.
    pub adam_epsilon: f32,
    /// Clip the gradient to this global L2 norm (off when absent).
    pub grad_clip_norm: Option<f32>,
    /// For this many first steps, rays come from the image centre only.
    pub precrop_iters: usize,
    /// Fraction of the image (per side) used while precropping.
    pub precrop_fraction: f32,
    /// Seed for initialisation, batches and sample jitter.
    pub seed: u64,
    /// Steps between checkpoints (one is always written at the end).
    pub checkpoint_every: usize,
    /// Minutes between quick validation renders (one val view) for the PSNR curve; 0 = never.
    pub eval_every_min: f64,
    /// Rays per network call when rendering.
    pub chunk: usize,
    /// Most samples (coarse + fine, per ray × rays) in one forward/backward pass. A larger
    /// batch is split into passes by rays and their gradients are summed before the update: the
    /// same step, with the activations of one pass in memory at a time.
    pub pass_points: usize,
    /// Passes in flight at once, each on its own autodiff graph (their activations are in
    /// memory together). Two keep both cores busy: burn's elementwise kernels use one thread.
    pub concurrent_passes: usize,
    /// Keep an occupancy grid and send only samples in occupied cells to the networks (in
    /// training and rendering).
    pub skip_empty_space: bool,
    /// The occupancy grid's size and update schedule (used with `skip_empty_space`).
    pub occupancy: OccupancyConfig,
    /// Which field to train: `mlp` (the coarse/fine networks of `[network]`) or `ngp` (the
    /// hash-grid field of `[ngp]`).
    #[serde(default)]
    pub field: FieldKind,
    /// Each kind's shape, one section per kind (`[network]`, `[ngp]`); `field` says which is
    /// trained.
    #[serde(flatten)]
    pub shapes: FieldShapes,
    /// Samples per step of the hash-grid field: the rays of a step are as many as fit, judged
    /// by the samples per ray of the previous step (with `field = "ngp"`).
    #[serde(default = "default_target_samples")]
    pub target_samples: usize,
    /// Intervals over [near, far] when marching through the occupancy grid (training the
    /// hash-grid field, and rendering any field with a grid); NDC runs take at most
    /// [`NDC_MARCH_STEPS`](crate::train::NDC_MARCH_STEPS).
    #[serde(default = "default_march_steps")]
    pub march_steps: usize,
    /// Intervals over [near, far] when rendering through the occupancy grid (eval, render,
    /// validation views and the exported bundle's `march_steps`). Absent: `march_steps`. A
    /// field trained on jittered intervals is a continuous density, and a finer quadrature of
    /// it is closer to what training saw on average (lego, 60 minutes: 1024 → 2048 steps
    /// +0.09 dB, 4096 no better; docs/quality.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub render_march_steps: Option<usize>,
    /// Rays a hash-grid step draws from each randomly chosen training image (with
    /// `field = "ngp"`): 1 spreads a step's rays over as many images as it has rays (as nerfacc
    /// and instant-ngp draw them; no better on lego, docs/quality.md).
    #[serde(default = "default_rays_per_image")]
    pub rays_per_image: usize,
    /// Training rays pass through a uniformly random point of their pixel instead of its
    /// centre (instant-ngp's training rays), so the field learns the pixel's area, whose mean an
    /// area-downscaled pixel is. The hash-grid field only. Absent: decided when the run starts
    /// (on for the hash-grid field on images downscaled by `--downscale`, off at their own
    /// resolution) and recorded here. Lego, 10 minutes: at 100×100 26.44 → 28.30 dB, at
    /// 400×400 30.08 → 29.20 dB (docs/quality.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub jitter_pixels: Option<bool>,
    /// A hash-grid step keeps, along each ray, only the samples with at least this much light in
    /// front of them (nerfacc's `early_stop_eps`): the density MLP runs on every marched sample,
    /// the colour MLP, the backward pass and `target_samples` count only the kept ones. 0 keeps
    /// every sample. A config file without the key (runs from before it) takes the preset's.
    #[serde(default)]
    pub early_stop_transmittance: f32,
    /// Weight of mip-NeRF 360's distortion loss ([`crate::train::distortion`]) beside the
    /// photometric MSE, a mean over a step's rays of each ray's loss in marching-step
    /// distances (0 to 1 over the march): density floating in front of a surface costs
    /// something even where it fits the training photos. The hash-grid field only; 0: off.
    /// Absent: decided when the run starts ([`CAPTURE_DISTORTION_LOSS`] for photos marched in
    /// the world, in the cube or contracted; 0 for Blender scenes, NDC rays and the MLP field)
    /// and recorded here. A run from before the key resumes without it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distortion_loss: Option<f32>,
    /// Learn a code per training image that the colour MLP sees (nerfacto's appearance
    /// embedding, [`crate::field::ngp::appearance`]), for captures whose exposure or white
    /// balance changes between photos; renders and bundles use the codes' mean. The hash-grid
    /// field only. Absent: off.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub appearance: bool,
    /// Learn a pose correction per training image with the field (nerfstudio's camera
    /// optimiser, [`crate::train::cameras`]), for captures whose poses are good but not
    /// perfect; renders of the training views use the refined poses. The hash-grid field only,
    /// on world rays (not NDC). Absent: off.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub refine_cameras: bool,
    /// The keys the `--config` file set (dotted: `occupancy.min_views`), which settings
    /// decided when a run starts leave as the file has them. Not written to `config.toml`.
    #[serde(skip)]
    pub file_keys: Vec<String>,
}

/// The `ngp` preset's `early_stop_transmittance` until it became 0.01: what a run recorded
/// without the key resumes with.
const NGP_EARLY_STOP_BEFORE_0_01: f32 = 1e-4;

/// The distortion weight of a new hash-grid run on photos marched in the world (mip-NeRF 360's
/// 0.01). At 10 minutes fox gains 0.51 dB and bird 0.42 dB with it, lego loses 0.20 dB and fern
/// (NDC) 0.33 dB (docs/captures.md).
pub const CAPTURE_DISTORTION_LOSS: f32 = 0.01;

/// What a new hash-grid run on photos in the cube changes from the `ngp` preset
/// ([`TrainConfig::decide_cube_capture`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CubeCapture {
    /// Intervals over [near, far] in training (the preset's 1024): a step holds more rays.
    pub march_steps: usize,
    /// Samples a step (the preset's 2¹⁶): twice the steps, each half as large.
    pub target_samples: usize,
    /// `[occupancy] min_views` (the preset's 0): cells fewer than two training cameras see stay
    /// empty, so coarser intervals do not grow haze where one photo at most fixes the density.
    pub min_views: usize,
}

/// Fox at 30 minutes: 32.58 dB → 32.90 dB with all three, and +1.04 dB over the default of
/// before issue 40 (docs/captures.md, "Fox: photos in the cube march coarser intervals in
/// smaller steps").
pub const CUBE_CAPTURE: CubeCapture = CubeCapture { march_steps: 512, target_samples: 1 << 15, min_views: 2 };

/// Default [`TrainConfig::target_samples`].
pub const DEFAULT_TARGET_SAMPLES: usize = 1 << 16;

fn default_target_samples() -> usize {
    DEFAULT_TARGET_SAMPLES
}

fn default_march_steps() -> usize {
    DEFAULT_MARCH_STEPS
}

fn default_rays_per_image() -> usize {
    256
}

impl Default for TrainConfig {
    fn default() -> Self {
        Preset::DEFAULT.config()
    }
}

impl TrainConfig {
    /// The same run over a contracted world ([`nerf_core::sample::contraction`]): the hash
    /// grid's and the occupancy grid's cube becomes the contracted one, ±2. Only the hash-grid
    /// field contracts.
    pub fn contracted(mut self, contraction: Contraction) -> std::result::Result<Self, String> {
        if self.field != FieldKind::Ngp {
            return Err(format!("a contracted scene needs the ngp field (field = {:?})", self.field.name()));
        }
        self.shapes.ngp.bound = GridBound::contracted(contraction);
        self.occupancy.bound = nerf_core::sample::contraction::CONTRACTED_HALF_SIZE;
        self.occupancy.contraction = Some(contraction);
        // Renders march as training does (the ngp preset's 1024 steps: 256 per segment). The
        // growing segments already sample the far world sparsely; the cube's 2048 render steps
        // bought bird's test frames 0.03 dB for twice the time (docs/captures.md).
        self.render_march_steps = Some(self.march_steps);
        Ok(self)
    }

    /// A run's recorded `config.toml`: as [`from_toml_str`](Self::from_toml_str), except that
    /// keys from before a preset changed read as runs were trained then (`lr_schedule`:
    /// `exponential`; an `ngp` run's `early_stop_transmittance`: 1e-4), so an old run resumes as
    /// it started.
    pub fn from_run_toml(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let mut table: toml::Table = toml::from_str(&text).map_err(|e| Error::invalid(path, e.to_string()))?;
        table.entry("lr_schedule").or_insert_with(|| toml::Value::String("exponential".into()));
        let early_stop_recorded = table.contains_key("early_stop_transmittance");
        let mut config = Self::from_toml_str(&toml::to_string(&table).expect("a parsed table serialises"), None).map_err(|e| match e {
            Error::Config(problem) => Error::invalid(path, problem),
            other => other,
        })?;
        if !early_stop_recorded && config.preset == Preset::Ngp {
            config.early_stop_transmittance = NGP_EARLY_STOP_BEFORE_0_01;
        }
        Ok(config)
    }

    /// A preset, overridden by the keys of a TOML file (which may itself name a `preset`).
    pub fn from_toml_file(path: &Path, preset: Option<Preset>) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::from_toml_str(&text, preset).map_err(|e| match e {
            Error::Config(problem) => Error::invalid(path, problem),
            other => other,
        })
    }

    /// As [`from_toml_file`](Self::from_toml_file), from text.
    pub fn from_toml_str(text: &str, preset: Option<Preset>) -> Result<Self> {
        let overrides: toml::Table = toml::from_str(text).map_err(|e| Error::Config(e.to_string()))?;
        let preset = match overrides.get("preset") {
            Some(v) => Preset::deserialize(v.clone()).map_err(|e| Error::Config(format!("preset: {e}")))?,
            None => preset.unwrap_or(Preset::DEFAULT),
        };
        let mut base = toml::Table::try_from(preset.config()).expect("a preset serialises");
        let file_keys = dotted_keys(&overrides, "");
        merge(&mut base, overrides);
        let mut config: TrainConfig = toml::Value::Table(base).try_into().map_err(|e: toml::de::Error| Error::Config(e.to_string()))?;
        config.validate()?;
        config.file_keys = file_keys;
        Ok(config)
    }

    /// The learning rate at `step`, `done` (in [0, 1]: the larger of the steps' and the time
    /// budget's share) of the way through the run: never below `lr_min` until the final anneal.
    pub fn learning_rate(&self, step: usize, done: f64) -> f64 {
        match self.lr_schedule {
            crate::train::LrSchedule::Exponential => {
                let rate = crate::train::learning_rate(self.lr, self.lr_decay_ksteps, step).max(self.lr_min);
                rate * crate::train::final_anneal(self.lr_anneal_fraction, done)
            }
            crate::train::LrSchedule::Planned => crate::train::planned_learning_rate(self.lr, step, done).max(self.lr_min),
        }
    }

    /// The distortion loss's weight: the recorded one, 0 where none was decided.
    pub fn distortion_weight(&self) -> f32 {
        self.distortion_loss.unwrap_or(0.0)
    }

    /// The `distortion_loss` a new run without the key takes: [`CAPTURE_DISTORTION_LOSS`] for
    /// the hash-grid field on photos marched in the world (`world_photos`: not a Blender scene,
    /// not NDC rays), where floaters hide the object from views far from the photos; else 0.
    pub fn decided_distortion_loss(&self, world_photos: bool) -> f32 {
        if world_photos && self.field == FieldKind::Ngp { CAPTURE_DISTORTION_LOSS } else { 0.0 }
    }

    /// A new hash-grid run on photos in the cube (`photos_in_the_cube`: not a Blender scene, not
    /// NDC rays, not contracted) takes [`CUBE_CAPTURE`]'s settings, each where the `--config`
    /// file did not set it and it still holds the `ngp` preset's value; `training_views`
    /// cameras (fewer than two keep `min_views`). Returns the keys changed, as `key = value`.
    pub fn decide_cube_capture(&mut self, photos_in_the_cube: bool, training_views: usize) -> Vec<String> {
        if !photos_in_the_cube || self.field != FieldKind::Ngp || self.preset != Preset::Ngp {
            return Vec::new();
        }
        let preset = Preset::Ngp.config();
        let CubeCapture { march_steps, target_samples, min_views } = CUBE_CAPTURE;
        let file_keys = &self.file_keys;
        let mut changed = Vec::new();
        // `key` as the file writes it, `label` as the terminal says it.
        let mut decide = |value: &mut usize, preset: usize, decided: usize, key: &str, label: &str| {
            if *value == preset && !file_keys.iter().any(|k| k == key) {
                *value = decided;
                changed.push(format!("{label} = {decided}"));
            }
        };
        decide(&mut self.march_steps, preset.march_steps, march_steps, "march_steps", "march_steps");
        decide(&mut self.target_samples, preset.target_samples, target_samples, "target_samples", "target_samples");
        if training_views >= min_views {
            decide(&mut self.occupancy.min_views, preset.occupancy.min_views, min_views, "occupancy.min_views", "[occupancy] min_views");
        }
        changed
    }

    /// The configuration as TOML.
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("a TrainConfig always serialises")
    }

    /// How the run's networks are rendered at test time (`nerf eval`/`render`, validation views).
    pub fn render_options(&self) -> RenderOptions {
        let mut options = RenderOptions::new(self.sampling.clone(), self.white_background, self.chunk, self.skip_empty_space);
        options.march_steps = self.render_steps();
        options
    }

    /// Intervals over [near, far] when rendering: `render_march_steps`, else `march_steps`.
    pub fn render_steps(&self) -> usize {
        self.render_march_steps.unwrap_or(self.march_steps)
    }

    /// Rejects values the trainer cannot run with.
    pub fn validate(&self) -> Result<()> {
        self.check().map_err(Error::Config)
    }

    fn check(&self) -> std::result::Result<(), String> {
        self.shapes.check(self.field)?;
        let s = &self.sampling;
        limits::check_sampling(s, Origin::Key("sampling")).map_err(|e| e.to_string())?;
        limits::check_chunk(self.chunk, s.n_coarse + s.n_fine, Origin::Key("chunk")).map_err(|e| e.to_string())?;
        limits::check_grid_resolution(self.occupancy.resolution, Origin::Key("occupancy.resolution")).map_err(|e| e.to_string())?;
        if s.n_coarse < 3 && s.n_fine > 0 {
            return Err("sampling: hierarchical sampling needs n_coarse ≥ 3".into());
        }
        if self.batch_rays == 0 || self.chunk == 0 || self.pass_points == 0 || self.concurrent_passes == 0 || self.rays_per_image == 0 {
            return Err("batch_rays, chunk, pass_points, concurrent_passes and rays_per_image must be positive".into());
        }
        if !(self.lr > 0.0 && self.lr_decay_ksteps > 0.0) {
            return Err("lr and lr_decay_ksteps must be positive".into());
        }
        if !(0.0..=self.lr).contains(&self.lr_min) {
            return Err(format!("lr_min = {}: must be in [0, lr = {}]", self.lr_min, self.lr));
        }
        if !(0.0..1.0).contains(&self.lr_anneal_fraction) {
            return Err(format!("lr_anneal_fraction = {}: must be in [0, 1)", self.lr_anneal_fraction));
        }
        let o = &self.occupancy;
        if !(o.bound > 0.0) || !(o.threshold >= 0.0) || !(o.decay > 0.0 && o.decay <= 1.0) || o.update_every == 0 {
            return Err("occupancy: need bound > 0, threshold ≥ 0, 0 < decay ≤ 1, update_every ≥ 1".into());
        }
        if !(self.precrop_fraction > 0.0 && self.precrop_fraction <= 1.0) {
            return Err("precrop_fraction must be in (0, 1]".into());
        }
        if self.appearance && self.field != FieldKind::Ngp {
            return Err(format!("appearance: per-image appearance codes are the ngp field's (field = {:?})", self.field.name()));
        }
        if self.refine_cameras && self.field != FieldKind::Ngp {
            return Err(format!("refine_cameras: camera refinement is the ngp field's (field = {:?})", self.field.name()));
        }
        if !(0.0..1.0).contains(&self.early_stop_transmittance) {
            return Err(format!("early_stop_transmittance = {}: must be in [0, 1)", self.early_stop_transmittance));
        }
        if let Some(weight) = self.distortion_loss {
            if !(weight >= 0.0 && weight.is_finite()) {
                return Err(format!("distortion_loss = {weight}: must be a finite weight ≥ 0"));
            }
            if weight > 0.0 && self.field != FieldKind::Ngp {
                return Err(format!("distortion_loss: the distortion loss is the ngp field's (field = {:?})", self.field.name()));
            }
        }
        limits::check_count(self.march_steps, limits::MAX_SAMPLES_PER_RAY, "steps", Origin::Key("march_steps")).map_err(|e| e.to_string())?;
        if let Some(steps) = self.render_march_steps {
            limits::check_count(steps, limits::MAX_SAMPLES_PER_RAY, "steps", Origin::Key("render_march_steps")).map_err(|e| e.to_string())?;
        }
        if !self.field.trains_on_random_backgrounds() && self.train_background.is_some_and(|b| b != Background::from_white(self.white_background)) {
            let random: Vec<&str> = FieldKind::ALL.iter().filter(|k| k.trains_on_random_backgrounds()).map(|k| k.name()).collect();
            return Err(format!("train_background: the {} field trains on white_background's colour (random needs field = {random:?})", self.field.name()));
        }
        if self.jitter_pixels == Some(true) && !self.field.trains_on_jittered_rays() {
            let jittered: Vec<&str> = FieldKind::ALL.iter().filter(|k| k.trains_on_jittered_rays()).map(|k| k.name()).collect();
            return Err(format!("jitter_pixels: the {} field trains through pixel centres (jitter needs field = {jittered:?})", self.field.name()));
        }
        if let Some((section, bound)) = self.shapes.field_box(self.field) {
            // A field defined inside its box only is marched through the occupancy grid, whose
            // cube that box must be.
            if !self.skip_empty_space || s.n_fine > 0 {
                return Err(format!("field = {:?} is marched through the occupancy grid: it needs skip_empty_space = true and sampling.n_fine = 0", self.field.name()));
            }
            if (bound.min, bound.max) != ([-o.bound; 3], [o.bound; 3]) {
                return Err(format!("{section}.bound {:?}..{:?} must be the occupancy grid's cube ±{} (occupancy.bound)", bound.min, bound.max, o.bound));
            }
            if bound.contraction != o.contraction {
                return Err(format!("{section}.bound.contraction {:?} must be the occupancy grid's (occupancy.contraction {:?})", bound.contraction, o.contraction));
            }
        }
        if self.target_samples == 0 || self.target_samples > limits::MAX_POINTS_PER_CALL {
            return Err(format!("target_samples must be in 1..={}", limits::MAX_POINTS_PER_CALL));
        }
        Ok(())
    }
}

/// Every leaf key of `table`, dotted under `prefix`.
fn dotted_keys(table: &toml::Table, prefix: &str) -> Vec<String> {
    let mut keys = Vec::new();
    for (key, value) in table {
        let path = if prefix.is_empty() { key.clone() } else { format!("{prefix}.{key}") };
        match value {
            toml::Value::Table(t) => keys.extend(dotted_keys(t, &path)),
            _ => keys.push(path),
        }
    }
    keys
}

fn merge(base: &mut toml::Table, overrides: toml::Table) {
    for (key, value) in overrides {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            (_, v) => {
                base.insert(key, v);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn configs_written_before_the_kind_sections_still_read() {
        // A cpu-fast config.toml as runs wrote it before `field` and `[ngp]` existed: the MLP,
        // its own section, the other kinds' shapes at their defaults.
        let mut old = toml::Table::try_from(Preset::CpuFast.config()).unwrap();
        old.remove("field");
        old.remove("ngp");
        old.remove("target_samples");
        old.remove("march_steps");
        let c = TrainConfig::from_toml_str(&toml::to_string(&old).unwrap(), None).unwrap();
        assert_eq!(c.field, FieldKind::Mlp);
        assert_eq!(c.shapes, Preset::CpuFast.config().shapes);
        assert!(old.contains_key("network") && !toml::Table::try_from(&c).unwrap()["ngp"].as_table().unwrap().is_empty());
    }

    #[test]
    fn the_step_keys_read_from_the_preset_and_are_checked() {
        // A config file without `rays_per_image` and `early_stop_transmittance` takes the
        // preset's: 256 rays an image, and for ngp runs the early stop.
        let mut old = toml::Table::try_from(Preset::Ngp.config()).unwrap();
        old.remove("rays_per_image");
        old.remove("early_stop_transmittance");
        let c = TrainConfig::from_toml_str(&toml::to_string(&old).unwrap(), None).unwrap();
        assert_eq!((c.rays_per_image, c.early_stop_transmittance, c.jitter_pixels), (256, 0.01, None));
        assert_eq!(Preset::CpuFast.config().early_stop_transmittance, 0.0);
        // A run recorded without the key resumes with the early stop it trained with: the ngp
        // preset's 1e-4 of then; an MLP run's stays 0; a recorded key is kept.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("config.toml");
        std::fs::write(&path, toml::to_string(&old).unwrap()).unwrap();
        assert_eq!(TrainConfig::from_run_toml(&path).unwrap().early_stop_transmittance, 1e-4);
        let mut mlp = toml::Table::try_from(Preset::CpuFast.config()).unwrap();
        mlp.remove("early_stop_transmittance");
        std::fs::write(&path, toml::to_string(&mlp).unwrap()).unwrap();
        assert_eq!(TrainConfig::from_run_toml(&path).unwrap().early_stop_transmittance, 0.0);
        std::fs::write(&path, Preset::Ngp.config().to_toml()).unwrap();
        assert_eq!(TrainConfig::from_run_toml(&path).unwrap().early_stop_transmittance, 0.01);
        for (key, bad) in [
            ("early_stop_transmittance", "1.0"),
            ("early_stop_transmittance", "-0.1"),
            ("rays_per_image", "0"),
            ("distortion_loss", "-0.01"),
            ("distortion_loss", "nan"),
            ("distortion_loss", "0.01\npreset = 'cpu-fast'"),
            // The MLP field trains through pixel centres, as nerf-pytorch does.
            ("jitter_pixels", "true\npreset = 'cpu-fast'"),
        ] {
            let err = TrainConfig::from_toml_str(&format!("{key} = {bad}"), None).unwrap_err().to_string();
            assert!(err.contains(key), "{key} = {bad}: {err}");
        }
    }

    #[test]
    fn the_distortion_loss_is_decided_for_photos_in_the_world() {
        let ngp = Preset::Ngp.config();
        assert_eq!((ngp.distortion_loss, ngp.distortion_weight()), (None, 0.0));
        assert_eq!((ngp.decided_distortion_loss(true), ngp.decided_distortion_loss(false)), (CAPTURE_DISTORTION_LOSS, 0.0));
        assert_eq!(Preset::CpuFast.config().decided_distortion_loss(true), 0.0);
        // A recorded weight is read back as it was, 0 included; a config without it decides.
        let recorded = TrainConfig { distortion_loss: Some(0.0), ..ngp.clone() };
        assert_eq!(TrainConfig::from_toml_str(&recorded.to_toml(), None).unwrap().distortion_loss, Some(0.0));
        assert_eq!(TrainConfig::from_toml_str(&ngp.to_toml(), None).unwrap().distortion_loss, None);
        let set = TrainConfig::from_toml_str("distortion_loss = 0.003", None).unwrap();
        assert_eq!((set.distortion_loss, set.distortion_weight()), (Some(0.003), 0.003));
    }

    #[test]
    fn photos_in_the_cube_take_the_cube_settings_where_the_file_and_the_code_leave_the_preset() {
        let cube = |mut c: TrainConfig, in_the_cube: bool, views: usize| {
            let changed = c.decide_cube_capture(in_the_cube, views);
            ((c.march_steps, c.target_samples, c.occupancy.min_views), changed.len())
        };
        let CubeCapture { march_steps, target_samples, min_views } = CUBE_CAPTURE;
        let ngp = Preset::Ngp.config();
        let preset = (ngp.march_steps, ngp.target_samples, ngp.occupancy.min_views);
        assert_ne!(preset, (march_steps, target_samples, min_views), "the cube changes nothing");
        assert_eq!(cube(ngp.clone(), true, 40), ((march_steps, target_samples, min_views), 3));
        // Not in the cube (Blender, NDC, contracted), or another field: the preset's.
        assert_eq!(cube(ngp.clone(), false, 40), (preset, 0));
        assert_eq!(cube(Preset::CpuFast.config(), true, 40).1, 0);
        // One training camera cannot see a cell twice: min_views stays.
        assert_eq!(cube(ngp.clone(), true, 1), ((march_steps, target_samples, preset.2), 2));
        // A key the file sets keeps the file's value, even the preset's own.
        let file = TrainConfig::from_toml_str("march_steps = 1024\n[occupancy]\nmin_views = 0\n", None).unwrap();
        assert_eq!(file.file_keys, ["march_steps", "occupancy.min_views"]);
        assert_eq!(cube(file, true, 40), ((1024, target_samples, 0), 1));
        // A value set in code (not the preset's) is kept too.
        let coded = TrainConfig { target_samples: 1 << 13, ..ngp };
        assert_eq!(cube(coded, true, 40), ((march_steps, 1 << 13, min_views), 2));
    }

    #[test]
    fn rendering_marches_its_own_steps_or_the_training_ones() {
        let ngp = Preset::Ngp.config();
        assert_eq!((ngp.march_steps, ngp.render_steps(), ngp.render_options().march_steps), (1024, 2048, 2048));
        // Without the key (the other presets), rendering marches as training does.
        let fast = TrainConfig::from_toml_str("preset = 'cpu-fast'
march_steps = 300", None).unwrap();
        assert_eq!((fast.render_march_steps, fast.render_options().march_steps), (None, 300));
        assert!(!fast.to_toml().contains("render_march_steps"));
        for bad in ["0", "5000"] {
            let err = TrainConfig::from_toml_str(&format!("render_march_steps = {bad}"), None).unwrap_err().to_string();
            assert!(err.contains("render_march_steps"), "{bad}: {err}");
        }
    }

    #[test]
    fn toml_overrides_a_preset_and_round_trips() {
        let c = TrainConfig::from_toml_str("preset = 'paper'\nbatch_rays = 256\n[sampling]\nn_fine = 0\n", None).unwrap();
        assert_eq!(c.shapes.network, NetworkSpec::paper());
        assert_eq!(c.batch_rays, 256);
        assert_eq!(c.sampling.n_fine, 0);
        assert_eq!(c.sampling.n_coarse, 64);
        let again = TrainConfig::from_toml_str(&c.to_toml(), None).unwrap();
        // Every key is in the file the second time; only which ones the file set differs.
        assert_eq!(TrainConfig { file_keys: c.file_keys.clone(), ..again }, c);
        let err = TrainConfig::from_toml_str("batch_rayz = 3", None).unwrap_err().to_string();
        assert!(err.contains("batch_rayz"), "{err}");
        let err = TrainConfig::from_toml_str("[sampling]\nnear = 7.0", None).unwrap_err().to_string();
        assert!(err.contains("near"), "{err}");
    }

    #[test]
    fn the_schedule_key_picks_the_learning_rate() {
        let exponential = TrainConfig::from_toml_str("lr = 0.01\nlr_decay_ksteps = 10.0\nlr_schedule = 'exponential'", None).unwrap();
        assert_eq!(exponential.lr_schedule, crate::train::LrSchedule::Exponential);
        // 10k steps: 10× lower, however far through the run.
        assert!((exponential.learning_rate(10_000, 0.1) - 1e-3).abs() < 1e-12);
        // The ngp preset's.
        let planned = TrainConfig::from_toml_str("lr = 0.01", None).unwrap();
        assert_eq!(planned.lr_schedule, crate::train::LrSchedule::Planned);
        assert_eq!(planned.learning_rate(10_000, 0.1), 0.01);
        assert!((planned.learning_rate(10_000, 0.6) - 0.0033).abs() < 1e-12);
        let err = TrainConfig::from_toml_str("lr_schedule = 'cosine'", None).unwrap_err().to_string();
        assert!(err.contains("cosine") && err.contains("planned"), "{err}");
    }

    #[test]
    fn a_run_from_before_the_schedule_key_resumes_on_the_step_count_decay() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("config.toml");
        let mut old = toml::Table::try_from(Preset::Ngp.config()).unwrap();
        old.remove("lr_schedule");
        std::fs::write(&path, toml::to_string(&old).unwrap()).unwrap();
        assert_eq!(TrainConfig::from_run_toml(&path).unwrap().lr_schedule, crate::train::LrSchedule::Exponential);
        // A run that recorded its schedule keeps it; a new override file takes the preset's.
        std::fs::write(&path, Preset::Ngp.config().to_toml()).unwrap();
        assert_eq!(TrainConfig::from_run_toml(&path).unwrap().lr_schedule, crate::train::LrSchedule::Planned);
        std::fs::write(&path, "seed = 3").unwrap();
        assert_eq!(TrainConfig::from_toml_file(&path, None).unwrap().lr_schedule, crate::train::LrSchedule::Planned);
        std::fs::write(&path, "seed = 'x'").unwrap();
        let err = TrainConfig::from_run_toml(&path).unwrap_err().to_string();
        assert!(err.contains("config.toml") && err.contains("seed"), "{err}");
    }

    #[test]
    fn the_learning_rate_stops_at_its_floor() {
        // The planned schedule's last phase (1e-2 · 0.33³ = 3.594e-4) is held at the floor.
        assert_eq!(Preset::Ngp.config().learning_rate(30_000, 0.95), 3.6e-4);
        let ngp = TrainConfig { lr_schedule: crate::train::LrSchedule::Exponential, ..Preset::Ngp.config() };
        // 1e-2 · 0.1^(14k/10k) = 3.98e-4 is above the floor, 20k steps (1e-4) below it.
        assert!((ngp.learning_rate(14_000, 0.5) - 1e-2 * 0.1f64.powf(1.4)).abs() < 1e-12);
        assert_eq!(ngp.learning_rate(20_000, 0.5), 3.6e-4);
        assert_eq!(ngp.learning_rate(1_000_000, 1.0), 3.6e-4);
        // The reference presets have none.
        assert!(Preset::Paper.config().learning_rate(5_000_000, 1.0) < 1e-13);
        // A config file from before the key takes its preset's floor.
        let mut old = toml::Table::try_from(ngp.clone()).unwrap();
        old.remove("lr_min");
        assert_eq!(TrainConfig::from_toml_str(&toml::to_string(&old).unwrap(), None).unwrap().lr_min, 3.6e-4);
        for (key, bad) in [("lr_min", "-1e-4"), ("lr_min", "0.5"), ("lr_anneal_fraction", "1.0"), ("lr_anneal_fraction", "-0.1")] {
            let err = TrainConfig::from_toml_str(&format!("preset = 'ngp'\n{key} = {bad}"), None).unwrap_err().to_string();
            assert!(err.contains(key), "{key} = {bad}: {err}");
        }
        // The last tenth of the run falls from the floor to a tenth of it.
        let annealed = TrainConfig { lr_anneal_fraction: 0.1, ..ngp };
        assert!((annealed.learning_rate(30_000, 0.9) - 3.6e-4).abs() < 1e-12);
        assert!((annealed.learning_rate(30_000, 0.95) - 3.6e-4 / 10f64.sqrt()).abs() < 1e-12);
        assert!((annealed.learning_rate(30_000, 1.0) - 3.6e-5).abs() < 1e-12);
        assert!((annealed.learning_rate(0, 0.95) - 1e-2 / 10f64.sqrt()).abs() < 1e-12);
    }
}
