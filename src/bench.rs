//! `nerf bench`: training-step timings measured in one run, so ratios between them are fair on
//! a shared, noisy machine.

use crate::train::{Preset, StepTiming, Trainer};
use nerf_core::dataset::{Split, SyntheticSceneConfig, generate_scene, load_split};
use std::path::Path;

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
