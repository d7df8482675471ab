//! The run loop: start or resume a run directory, then step until the iteration count or the
//! time budget is reached, with checkpoints, the PSNR curve (and its plot) and a progress bar.

use crate::field::FieldTrainer;
use crate::config::TrainConfig;
use crate::error::{Error, Result};
use crate::live::{ProgressLog, SnapshotOptions, Snapshots};
use crate::run_dir::{RunDir, RunSource};
use indicatif::{ProgressBar, ProgressStyle};
use nerf_core::dataset::{Background, CaptureFormat, CaptureSplit, LoadOptions, SceneFrame, SplitData, default_contraction, detect_format, load_dataset};
use nerf_core::field::FieldKind;
use nerf_core::sample::Contraction;
use std::path::PathBuf;
use std::time::Instant;

/// Most marching intervals over an NDC ray's [0, 1], which spans the frustum to infinity
/// evenly in disparity. Fern, 3 minutes of the `ngp` preset: 21.99 dB at 256, 21.15 at 512,
/// 19.88 at 1024 (more intervals, more samples per ray, fewer rays per step).
pub const NDC_MARCH_STEPS: usize = 256;

/// What `nerf train` was asked to do.
#[derive(Debug, Clone)]
pub struct TrainOptions {
    /// Dataset directory (Blender, instant-ngp/nerfstudio or LLFF).
    pub data: PathBuf,
    /// Its format (`None`: detected from the files).
    pub format: Option<CaptureFormat>,
    /// Run directory (config, checkpoints, curve).
    pub run: PathBuf,
    /// NDC rays for a new run: `None` decides from the data (LLFF, forward-facing).
    pub ndc: Option<bool>,
    /// A contracted world for a new run (`--contract`): `None` decides from the data for the
    /// ngp field ([`nerf_core::dataset::contraction_by_default`]); a configuration that
    /// contracts already (`occupancy.contraction`) stays contracted.
    pub contract: Option<bool>,
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

/// Batches whose PSNR the progress bar and the curve average.
const RECENT_STEPS: usize = 50;

/// Train (or resume) a run as `options` say.
pub fn train(options: &TrainOptions) -> Result<TrainSummary> {
    train_live(options, None)
}

/// [`train`], also writing live snapshots of the field as `snapshots` says, for the viewer
/// ([`crate::live`]; `nerf train --serve`).
pub fn train_live(options: &TrainOptions, snapshots: Option<SnapshotOptions>) -> Result<TrainSummary> {
    let run = RunDir::create(&options.run)?;
    let (mut trainer, val_data, elapsed_before) = start_or_resume(&run, options)?;
    let config = trainer.config().clone();
    let clock = Clock { before_s: elapsed_before, start: Instant::now() };
    let budget_s = options.time_budget_min.map(|m| m * 60.0);
    let bar = progress_bar(options.progress, config.iters, trainer.steps_done());
    let mut curve = run.open_curve()?;
    let mut recent = RecentPsnr::default();
    let mut next_eval_s = if config.eval_every_min > 0.0 { clock.seconds() + config.eval_every_min * 60.0 } else { f64::INFINITY };
    let mut val_psnr = None;
    let mut progress = ProgressLog::new(&run, snapshots.is_some(), trainer.steps_done());
    let mut live = snapshots.map(|o| Snapshots::new(&run, o, clock.seconds())).transpose()?;
    let say = |m: String| bar.println(m);
    let mut loss = None;
    while trainer.steps_done() < config.iters && !budget_s.is_some_and(|b| clock.seconds() >= b) {
        let done = budget_s.map_or(0.0, |b| clock.seconds() / b).max(trainer.steps_done() as f64 / config.iters as f64);
        let lr = config.learning_rate(trainer.steps_done(), done);
        let stats = trainer.step(lr);
        if !stats.loss.is_finite() {
            trainer.save(&run, clock.seconds())?;
            return Err(Error::Diverged { step: trainer.steps_done(), loss: stats.loss });
        }
        loss = Some(stats.loss);
        recent.push(stats.psnr);
        let now = clock.seconds();
        if progress.due(now) {
            let p = progress.progress(trainer.as_ref(), now, budget_s, loss, recent.mean(), val_psnr);
            progress.write(&p, now);
        }
        if let Some(live) = live.as_mut().filter(|l| l.due(now)) {
            live.write(trainer.as_ref(), now, &say);
        }
        bar.set_position(trainer.steps_done() as u64);
        let budget = budget_s.map(|b| format!(" | {:.1}/{:.0} min", clock.seconds() / 60.0, b / 60.0)).unwrap_or_default();
        bar.set_message(format!("loss {:.4} psnr {:.2} lr {lr:.1e}{budget}", stats.loss, recent.mean()));
        if trainer.steps_done() % config.checkpoint_every == 0 {
            trainer.save(&run, clock.seconds())?;
        }
        if clock.seconds() >= next_eval_s {
            if let Some(val) = &val_data {
                val_psnr = Some(validate(trainer.as_ref(), val, &bar));
            }
            curve.record(trainer.steps_done(), clock.minutes(), recent.mean(), val_psnr)?;
            refresh_curve_plot(&run, &bar);
            next_eval_s += config.eval_every_min * 60.0;
            if let Some(live) = &mut live {
                live.write(trainer.as_ref(), clock.seconds(), &say);
            }
        }
    }
    trainer.save(&run, clock.seconds())?;
    bar.finish();
    if let Some(val) = &val_data {
        val_psnr = Some(trainer.view_psnr(val, 0));
    }
    curve.record(trainer.steps_done(), clock.minutes(), recent.mean(), val_psnr)?;
    refresh_curve_plot(&run, &bar);
    if let Some(live) = &mut live {
        live.write(trainer.as_ref(), clock.seconds(), &say);
        eprintln!("{}", live.summary(clock.start.elapsed().as_secs_f64()));
    }
    let mut last = progress.progress(trainer.as_ref(), clock.seconds(), budget_s, loss, recent.mean(), val_psnr);
    last.done = true;
    last.remaining_s = Some(0.0);
    progress.write(&last, clock.seconds());
    Ok(TrainSummary { steps: trainer.steps_done(), train_psnr: recent.mean(), val_psnr, minutes: clock.minutes() })
}

/// Set up `run` (configuration, camera, data source) and a trainer on its training split,
/// restored from the latest checkpoint if there is one; also the validation split, if any,
/// and the minutes already trained.
fn start_or_resume(run: &RunDir, options: &TrainOptions) -> Result<(Box<dyn FieldTrainer>, Option<SplitData>, f64)> {
    let checkpoint = run.latest_checkpoint()?;
    let mut config = match &checkpoint {
        // A resumed run keeps the configuration it started with.
        Some(_) => run.read_config()?,
        None => options.config.clone(),
    };
    if let Some(iters) = options.iters {
        config.iters = iters;
    }
    // A new run fits its scene into the field's cube; a resumed one keeps the recorded fit.
    let recorded = match &checkpoint {
        Some(_) => run.read_source()?.and_then(|s| s.placement),
        None => None,
    };
    let format = match options.format {
        Some(f) => f,
        None => detect_format(&options.data)?,
    };
    if checkpoint.is_none() {
        config = decide_contraction(config, options, format)?;
    }
    let frame = match &recorded {
        Some(p) => SceneFrame::Recorded(p.transform),
        None => SceneFrame::Fit { bound: config.occupancy.bound, ndc: options.ndc, contraction: config.occupancy.contraction },
    };
    let deciding_background = config.train_background.is_none();
    if deciding_background {
        // A new colour per ray, as instant-ngp trains: a capture's opaque photos teach the field
        // to be opaque, and an RGBA scene's alpha to be empty where it is transparent, instead
        // of "empty or white" (on white, a dark scene can teach the colour MLP to stay dead
        // where density grows: the generated spheres rendered grey). A run from before this
        // key resumes as it started.
        let random = checkpoint.is_none() && config.field.trains_on_random_backgrounds();
        config.train_background = Some(if random { Background::Random } else { Background::from_white(config.white_background) });
    }
    if config.jitter_pixels.is_none() {
        // A downscaled pixel is the mean of its area, which jittered rays learn (a run from
        // before this key resumes as it started).
        config.jitter_pixels = Some(checkpoint.is_none() && options.downscale > 1 && config.field.trains_on_jittered_rays());
    }
    let load = move |split, frame, background| {
        let load = LoadOptions { format: Some(format), downscale: options.downscale, images: true, background, frame };
        load_dataset(&options.data, split, &load)
    };
    let train = load(CaptureSplit::Train, frame, config.train_background.expect("decided above"))?;
    if deciding_background && format == CaptureFormat::Blender && train.data.views.iter().all(|v| v.alpha.is_none()) {
        // Opaque Blender images have their background painted in: an empty ray on
        // white_background's colour explains it (the pixels are the same either way).
        config.train_background = Some(Background::from_white(config.white_background));
    }
    for w in &train.warnings {
        eprintln!("warning: {w}");
    }
    let placement = recorded.unwrap_or(train.placement);
    if checkpoint.is_none()
        && let Some((near, far)) = placement.near_far
    {
        // A capture's depth range comes from its bounds or the cube, not the preset's 2..6;
        // forward-facing ones sample NDC rays over [0, 1].
        config.sampling.near = near;
        config.sampling.far = far;
        config.sampling.ndc = placement.ndc;
        if placement.ndc.is_some() {
            config.march_steps = config.march_steps.min(NDC_MARCH_STEPS);
            config.render_march_steps = config.render_march_steps.map(|s| s.min(NDC_MARCH_STEPS));
        }
        let space = if placement.ndc.is_some() { "NDC rays" } else { "the field's frame" };
        eprintln!("{} capture: near {near:.4}, far {far:.4} in {space} (scale {:.4})", placement.format, placement.transform.scale);
    }
    let world_photos = format != CaptureFormat::Blender && placement.ndc.is_none();
    if checkpoint.is_none() {
        // Photos in the cube (fox): coarser intervals and smaller steps, haze kept out of what
        // one camera alone sees. Contracted captures march their own growing segments.
        let in_the_cube = world_photos && config.occupancy.contraction.is_none();
        let changed = config.decide_cube_capture(in_the_cube, train.data.views.len());
        if !changed.is_empty() {
            eprintln!("photos in the cube: {} (a --config file that sets a key keeps its value)", changed.join(", "));
        }
    }
    if config.distortion_loss.is_none() {
        // Photos marched in the world (a 360° capture, in the cube or contracted) train against
        // floaters; Blender scenes and NDC rays lost with it. A run from before the key resumes
        // as it started, without it.
        config.distortion_loss = Some(if checkpoint.is_none() { config.decided_distortion_loss(world_photos) } else { 0.0 });
        if config.distortion_weight() > 0.0 {
            eprintln!("distortion loss {} against floaters (photos in the world; distortion_loss = 0 in a --config file turns it off)", config.distortion_weight());
        }
    }
    if config.refine_cameras && placement.ndc.is_some() {
        let problem = "camera refinement corrects rays in the world, and this capture trains on NDC rays (forward-facing): train with --ndc false, or without --refine-cameras";
        return Err(Error::invalid(&options.data, problem));
    }
    let train_data = train.data;
    let camera = train_data.camera().ok_or_else(|| Error::invalid(&options.data, "the train split has no views"))?;
    let transform = placement.transform;
    if checkpoint.is_none() {
        // A new run records what defines it; a resumed one reads it and keeps it as it was
        // (an --iters or a decided background of this invocation stay in memory).
        run.write_config(&config)?;
        run.write_camera(&camera)?;
        // Where the data came from and how it is placed: eval, render and export use this.
        let data = std::path::absolute(&options.data).unwrap_or(options.data.clone());
        run.write_source(&RunSource { data, downscale: options.downscale, placement: Some(placement) })?;
    }
    // The validation curve is optional: a scene without val views still trains.
    // Validation views are scored as eval scores them: on the render background.
    let val_data = match load(CaptureSplit::Val, SceneFrame::Recorded(transform), Background::from_white(config.white_background)).map(|d| d.data) {
        Ok(v) if !v.views.is_empty() => Some(v),
        Ok(_) => None,
        Err(e) => {
            eprintln!("note: no validation curve ({e})");
            None
        }
    };
    let mut trainer = crate::field::trainer(config, train_data)?;
    let mut elapsed_before = 0.0;
    if let Some(c) = &checkpoint {
        elapsed_before = trainer.resume(c)?;
        eprintln!("resuming {} at step {}", run.root().display(), trainer.steps_done());
    }
    Ok((trainer, val_data, elapsed_before))
}

/// A new run's world: contracted as `--contract` asks, else as the data decides for the ngp
/// field (printed, with how to keep the cube); a configuration that contracts stays so.
fn decide_contraction(config: TrainConfig, options: &TrainOptions, format: CaptureFormat) -> Result<TrainConfig> {
    let contract = |config: TrainConfig| config.contracted(Contraction::Linf).map_err(|e| Error::Config(format!("--contract: {e}")));
    let contracted = config.occupancy.contraction.is_some();
    match options.contract {
        Some(true) if !contracted => contract(config),
        Some(false) if contracted => Err(Error::Config("--contract false, but the configuration contracts (occupancy.contraction): drop one of them".into())),
        None if !contracted && config.field == FieldKind::Ngp => match default_contraction(&options.data, format, options.ndc)? {
            Some(why) => {
                eprintln!("contracting the world around the capture ({why}); --contract false keeps the cube");
                contract(config)
            }
            None => Ok(config),
        },
        _ => Ok(config),
    }
}

/// PSNR of the first validation view, printed above the progress bar.
fn validate(trainer: &dyn FieldTrainer, val: &SplitData, bar: &ProgressBar) -> f32 {
    let p = trainer.view_psnr(val, 0);
    let occupied = trainer.occupancy().map(|g| format!(", {:.1}% of the grid occupied", 100.0 * g.occupied_fraction())).unwrap_or_default();
    bar.println(format!("step {}: val {} PSNR {p:.2} dB{occupied}", trainer.steps_done(), val.views[0].name));
    p
}

/// Redraw `curve.png` from `curve.csv`. A plot that cannot be drawn is a warning: training
/// (and its checkpoints) matter more than the picture.
fn refresh_curve_plot(run: &RunDir, bar: &ProgressBar) {
    if let Err(e) = crate::plot::write_run_curve(run) {
        bar.println(format!("warning: {} not updated: {e}", run.curve_plot_path().display()));
    }
}

/// Training time across resumes.
struct Clock {
    before_s: f64,
    start: Instant,
}

impl Clock {
    fn seconds(&self) -> f64 {
        self.before_s + self.start.elapsed().as_secs_f64()
    }

    fn minutes(&self) -> f64 {
        self.seconds() / 60.0
    }
}

/// The PSNR of the last [`RECENT_STEPS`] batches.
#[derive(Default)]
struct RecentPsnr(Vec<f32>);

impl RecentPsnr {
    fn push(&mut self, psnr: f32) {
        self.0.push(psnr);
        if self.0.len() > RECENT_STEPS {
            self.0.remove(0);
        }
    }

    fn mean(&self) -> f32 {
        self.0.iter().sum::<f32>() / self.0.len().max(1) as f32
    }
}

fn progress_bar(show: bool, iters: usize, step: usize) -> ProgressBar {
    let bar = if show { ProgressBar::new(iters as u64) } else { ProgressBar::hidden() };
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}<{eta_precise}] {wide_bar} {pos}/{len} {per_sec} {msg}")
            .expect("valid template"),
    );
    bar.set_position(step as u64);
    bar.reset_eta();
    bar
}
