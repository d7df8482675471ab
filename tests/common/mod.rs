//! Shared fixtures for the integration tests.
#![allow(dead_code)]

use nerf::config::{Preset, TrainConfig};
use nerf_core::dataset::{SyntheticSceneConfig, generate_scene};
use nerf_core::field::ngp::hash_grid::HashGridConfig;
use nerf::train::{TrainOptions, train};
use std::path::{Path, PathBuf};
use std::process::Command;

/// The lego scene shipped beside the project (CI has it too).
pub fn lego_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/nerf_synthetic/lego")
}

/// A small network and batch so a test trains in seconds.
pub fn tiny_config() -> TrainConfig {
    let mut c = Preset::CpuFast.config();
    c.shapes.network.depth = 4;
    c.shapes.network.width = 64;
    c.shapes.network.skips = vec![2];
    c.batch_rays = 256;
    c.sampling.n_coarse = 16;
    c.sampling.n_fine = 32;
    c.checkpoint_every = 10_000;
    c.eval_every_min = 0.0;
    c.chunk = 4096;
    c.precrop_iters = 50;
    c
}

/// The `ngp` preset shrunk so that a test trains in seconds.
pub fn tiny_ngp() -> TrainConfig {
    let mut c = Preset::Ngp.config();
    c.shapes.ngp.grid = HashGridConfig { levels: 8, features_per_level: 2, log2_table_size: 14, base_resolution: 8, max_resolution: 128 };
    c.shapes.ngp.density_hidden = 32;
    c.shapes.ngp.color_hidden = 32;
    c.target_samples = 1 << 13;
    c.march_steps = 256;
    // The step-count decay: the planned schedule's 100-step warm-up is longer than these runs,
    // and it plans over `iters`, which the resume tests change between stops.
    c.lr_schedule = nerf::train::LrSchedule::Exponential;
    c.render_march_steps = Some(320);
    c.occupancy.resolution = 32;
    c.occupancy.warmup_steps = 16;
    c.occupancy.update_every = 8;
    c.checkpoint_every = 10_000;
    c.eval_every_min = 0.0;
    c.iters = 80;
    c
}

/// A generated 32×32 scene in `dir`.
pub fn small_scene(dir: &Path) -> PathBuf {
    let scene = dir.join("scene");
    let cfg = SyntheticSceneConfig { width: 32, height: 32, n_train: 20, n_val: 3, n_test: 2, seed: 1 };
    generate_scene(&scene, &cfg).expect("scene generation");
    scene
}

/// Run the `nerf` binary: (success, stdout + stderr); a panic fails the test.
pub fn nerf(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_nerf")).args(args).output().expect("run nerf");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(!text.contains("panicked"), "nerf {args:?} panicked:\n{text}");
    (out.status.success(), text)
}

/// Run the `nerf-render` binary (built by `cargo test --workspace` next to these tests):
/// (success, stdout + stderr); a panic fails the test.
pub fn nerf_render(args: &[&str]) -> (bool, String) {
    let exe = std::env::current_exe().unwrap();
    let bin = exe.parent().and_then(Path::parent).unwrap().join("nerf-render");
    assert!(bin.is_file(), "{} is missing: build it with `cargo build --release -p nerf-runtime` (cargo test --workspace does)", bin.display());
    let out = Command::new(&bin).args(args).output().expect("run nerf-render");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(!text.contains("panicked"), "nerf-render {args:?} panicked:\n{text}");
    (out.status.success(), text)
}

/// A generated scene and a run trained on it for 20 steps: (scene, run).
pub fn trained_run(dir: &Path) -> (PathBuf, PathBuf) {
    let scene = small_scene(dir);
    let run = dir.join("run");
    let mut config = tiny_config();
    config.iters = 20;
    train(&TrainOptions { format: None, data: scene.clone(), run: run.clone(), config, ndc: None, contract: None, downscale: 1, time_budget_min: None, iters: None, progress: false })
        .unwrap();
    (scene, run)
}

/// The Python with numpy, onnx and onnxruntime (`scripts/env.sh` sets `NERF_PYTHON`).
pub fn python() -> String {
    std::env::var("NERF_PYTHON").unwrap_or_else(|_| "python3".into())
}

/// A path as `&str`.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The largest `|a − b| / scale(a)` over two outputs of the same points, failing the test when
/// their lengths differ or they are empty: `zip` alone would compare a short or empty output as
/// no difference at all. `what` names the comparison in the failure.
pub fn max_difference(what: &str, a: &[f32], b: &[f32], scale: impl Fn(f32) -> f32) -> f32 {
    assert_eq!(a.len(), b.len(), "{what}: {} values against {}", a.len(), b.len());
    assert!(!a.is_empty(), "{what}: no values to compare");
    a.iter().zip(b).map(|(x, y)| (x - y).abs() / scale(*x)).fold(0.0, f32::max)
}
