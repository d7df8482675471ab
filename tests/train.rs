//! Training end to end: loss falls, PSNR rises, resume is exact, runs are deterministic.

mod common;

use common::{lego_dir, small_scene, tiny_config};
use nerf::train::{TrainOptions, train};
use nerf::field::mlp::Trainer;
use nerf_core::dataset::{Split, load_split};
use std::path::Path;

/// Every weight and bias of both networks, in layer order.
fn model_weights(m: &nerf::field::mlp::NerfModel) -> Vec<f32> {
    let mut all = Vec::new();
    for net in std::iter::once(&m.coarse).chain(m.fine.as_ref()) {
        for l in net.to_plain().layers {
            all.extend(l.weight);
            all.extend(l.bias);
        }
    }
    all
}

/// One step at the configured schedule's learning rate.
fn step(t: &mut Trainer) -> nerf::field::StepStats {
    let lr = t.config.learning_rate(t.step, t.step as f64 / t.config.iters as f64);
    t.step(lr)
}

/// Train `steps` steps; the mean loss of the first and of the last 20.
fn train_steps(t: &mut Trainer, steps: usize) -> (f32, f32) {
    let losses: Vec<f32> = (0..steps).map(|_| step(t).loss).collect();
    assert!(losses.iter().all(|l| l.is_finite()), "non-finite loss: {losses:?}");
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
    (mean(&losses[..20]), mean(&losses[steps - 20..]))
}

/// PSNR of the trainer's current field on view `index`, rendered as `nerf eval` renders it.
fn view_psnr(t: &Trainer, val: &nerf_core::dataset::SplitData, index: usize) -> f32 {
    let t: &dyn nerf::field::FieldTrainer = t;
    t.view_psnr(val, index)
}

fn new_trainer(data: &Path, config: nerf::config::TrainConfig, downscale: u32) -> Trainer {
    let train = load_split(data, Split::Train, downscale, true).unwrap();
    Trainer::new(config, train, nerf::backend::cpu_autodiff()).unwrap()
}

#[test]
fn generated_scene_loss_falls_and_val_psnr_rises() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene(dir.path());
    let val = load_split(&scene, Split::Val, 1, true).unwrap();
    let mut t = new_trainer(&scene, tiny_config(), 1);
    let before = view_psnr(&t, &val, 0);
    let (first, last) = train_steps(&mut t, 300);
    let after = view_psnr(&t, &val, 0);
    assert!(last < 0.3 * first, "loss {first} → {last}");
    // 300 steps of a 4×64 network on 32×32 views reach ≈ 19.5 dB (measured); blank ≈ 7.4 dB.
    assert!(after > 17.0 && after > before + 5.0, "val PSNR {before} → {after}");
}

#[test]
fn lego_brief_training_beats_a_blank_image() {
    let data = lego_dir();
    assert!(data.join("transforms_train.json").exists(), "lego data missing at {}", data.display());
    let val = load_split(&data, Split::Val, 8, true).unwrap();
    let target = val.views[0].image.as_ref().unwrap();
    let white = vec![[1.0f32; 3]; target.len()];
    let blank = nerf_core::render::metrics::psnr(&white, target);
    let mut config = tiny_config();
    config.precrop_iters = 100;
    let mut t = new_trainer(&data, config, 8);
    let (first, last) = train_steps(&mut t, 250);
    let after = view_psnr(&t, &val, 0);
    assert!(last < 0.7 * first, "loss {first} → {last}");
    // 50×50 lego: a blank white image scores ≈ `blank`; the model must be clearly better.
    assert!(after > 15.0 && after > blank + 3.0, "val PSNR {after} (blank white {blank})");
}

#[test]
fn passes_add_up_to_the_whole_batch() {
    // Without fine samples a step's samples do not depend on how its batch is split, so one
    // pass, four sequential passes and four passes two at a time must take the same step.
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene(dir.path());
    let run = |pass_points: usize, concurrent_passes: usize| {
        let mut config = tiny_config();
        config.sampling.n_fine = 0;
        config.precrop_iters = 0;
        config.skip_empty_space = false;
        config.pass_points = pass_points;
        config.concurrent_passes = concurrent_passes;
        let rays = config.batch_rays;
        let mut t = new_trainer(&scene, config, 1);
        let losses: Vec<f32> = (0..3).map(|_| step(&mut t).loss).collect();
        assert_eq!(t.step, 3);
        (rays, losses, model_weights(t.model()))
    };
    let (rays, one_loss, one) = run(usize::MAX, 1);
    let samples = rays * tiny_config().sampling.n_coarse;
    for (label, (_, loss, weights)) in [("4 sequential", run(samples / 4, 1)), ("4, 2 at a time", run(samples / 4, 2))] {
        for (a, b) in one_loss.iter().zip(&loss) {
            assert!((a - b).abs() <= 1e-5 * a.abs(), "{label} passes: loss {b} vs {a} in one pass");
        }
        let worst = one.iter().zip(&weights).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(worst < 1e-5, "{label} passes: weights differ by {worst} from one pass");
    }
}

#[test]
fn resume_continues_exactly_and_runs_are_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene(dir.path());
    let mut config = tiny_config();
    config.iters = 6;
    config.checkpoint_every = 3;
    // The occupancy grid updates on both sides of the resume point, so it must be restored too.
    config.skip_empty_space = true;
    config.occupancy.warmup_steps = 2;
    config.occupancy.update_every = 2;
    let options = |run: &str, iters: usize| TrainOptions {
        format: None,
        data: scene.clone(),
        run: dir.path().join(run),
        config: config.clone(),
        ndc: None,
        contract: None,
        downscale: 1,
        time_budget_min: None,
        iters: Some(iters),
        progress: false,
    };
    // Straight through, twice: identical.
    train(&options("a", 6)).unwrap();
    train(&options("b", 6)).unwrap();
    // Stopped after 3 and resumed to 6.
    train(&options("c", 3)).unwrap();
    let resumed = train(&options("c", 6)).unwrap();
    assert_eq!(resumed.steps, 6);

    let load = |run: &str| {
        let nerf::field::RunCheckpoint { model, state, occupancy: grid, .. } =
            nerf::field::load_latest(&nerf::run_dir::RunDir::open(&dir.path().join(run)).unwrap(), &nerf::backend::cpu()).unwrap();
        (model_weights(model.as_any().downcast_ref::<nerf::field::mlp::NerfModel>().unwrap()), state, grid.expect("the run skips empty space"))
    };
    let (a, sa, grid_a) = load("a");
    let (b, _, _) = load("b");
    let (c, sc, grid_c) = load("c");
    assert_eq!(grid_a, grid_c, "resumed occupancy grid");
    assert!(grid_a.occupied_fraction() < 1.0, "the grid was updated");
    assert_eq!(sa.step, 6);
    assert_eq!(a, b, "same seed, same weights");
    assert_eq!(sa.rng, sc.rng, "resumed RNG state");
    let max_diff = a.iter().zip(&c).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max);
    assert!(max_diff < 1e-6, "resumed run differs by {max_diff}");

    // A different seed gives different weights.
    let mut other = new_trainer(&scene, nerf::config::TrainConfig { seed: 99, ..config.clone() }, 1);
    step(&mut other);
    let mut same = new_trainer(&scene, config, 1);
    step(&mut same);
    assert_ne!(model_weights(other.model()), model_weights(same.model()));
}
