//! Crashes mid-write: `nerf train` and `nerf export` killed with SIGKILL at seeded random
//! moments, some of them while a checkpoint or a bundle is being written. A resumed run must
//! continue from the last complete checkpoint with that checkpoint's weights (and end where an
//! uninterrupted run ends, bit for bit), and no reader may ever see a half-written file.

mod common;

use common::{nerf, s, small_scene, tiny_config};
use nerf::field::{RunCheckpoint, load_latest};
use nerf::run_dir::RunDir;
use nerf::config::TrainConfig;
use nerf_core::Rng;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A small network checkpointed after every step (each checkpoint fsyncs its files, which
/// dominates a step here), with a small grid updated every other step.
fn crash_config() -> TrainConfig {
    let mut c = tiny_config();
    c.batch_rays = 32;
    c.sampling.n_coarse = 8;
    c.sampling.n_fine = 8;
    c.precrop_iters = 0;
    c.iters = 30;
    c.checkpoint_every = 1;
    c.occupancy.resolution = 16;
    c.occupancy.warmup_steps = 4;
    c.occupancy.update_every = 2;
    c
}

fn start(args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_nerf")).args(args).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().expect("start nerf")
}

/// Wait until `child` has a temporary entry `<prefix>*.tmp-<its pid>` in `dir` (a write under
/// way) or exits; true when the entry appeared.
fn wait_for_temporary(dir: &Path, prefix: &str, child: &mut Child, limit: Duration) -> bool {
    let suffix = format!(".tmp-{}", child.id());
    let t0 = Instant::now();
    while t0.elapsed() < limit {
        if has_entry(dir, prefix, &suffix) {
            return true;
        }
        if child.try_wait().unwrap().is_some() {
            return false;
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    false
}

/// Kills of `nerf train` before the run may finish.
const KILLS: usize = 6;

/// Whether the name of an entry of `dir` starts with `prefix` and ends with `suffix`.
fn has_entry(dir: &Path, prefix: &str, suffix: &str) -> bool {
    let matches = |name: &str| name.starts_with(prefix) && name.ends_with(suffix);
    std::fs::read_dir(dir).is_ok_and(|mut e| e.any(|e| e.is_ok_and(|e| matches(&e.file_name().to_string_lossy()))))
}

/// The step of the checkpoint `latest` names (`None` before the first, or while it names a
/// temporary copy).
fn latest_step(run: &Path) -> Option<usize> {
    let name = std::fs::read_to_string(run.join("checkpoints/latest")).ok()?;
    name.trim().strip_prefix("step-")?.parse().ok()
}

/// SIGKILL `child` (if it still runs); its stderr and whether it had finished by itself.
fn kill(mut child: Child) -> (String, bool) {
    let finished = child.try_wait().unwrap().is_some();
    let _ = child.kill();
    let out = child.wait_with_output().unwrap();
    (String::from_utf8_lossy(&out.stderr).into_owned(), finished && out.status.success())
}

/// Every file of a directory (no sub-directories expected) by name.
fn snapshot(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| {
            let e = e.unwrap();
            (e.file_name().to_string_lossy().into_owned(), std::fs::read(e.path()).unwrap())
        })
        .collect()
}

/// The checkpoint `latest` names loads completely (state, weights, grid); its step.
fn check_latest(run: &Path) -> Option<usize> {
    let run = RunDir::open(run).unwrap_or_else(|e| panic!("after a kill: {e}"));
    run.latest_checkpoint().unwrap_or_else(|e| panic!("after a kill: {e}"))?;
    let RunCheckpoint { state, occupancy: grid, .. } =
        load_latest(&run, &nerf::backend::cpu()).unwrap_or_else(|e| panic!("after a kill, the latest checkpoint does not load: {e}"));
    assert!(grid.is_some(), "the checkpoint lost its occupancy grid");
    Some(state.step)
}

#[test]
fn killed_training_resumes_from_the_last_complete_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene(dir.path());
    let config_file = dir.path().join("crash.toml");
    let config = crash_config();
    std::fs::write(&config_file, config.to_toml()).unwrap();
    let train = |run: &Path| start(&["train", "--data", s(&scene), "--config", s(&config_file), "--out", s(run)]);

    // The uninterrupted run, timed to place the kills.
    let reference = dir.path().join("reference");
    let t0 = Instant::now();
    let (text, ok) = wait_exit(train(&reference));
    assert!(ok, "{text}");
    let full_s = t0.elapsed().as_secs_f64();

    let run = dir.path().join("run");
    let checkpoints = run.join("checkpoints");
    let step_s = full_s / config.iters as f64;
    let mut rng = Rng::new(11);
    let (mut kills, mut in_write, mut resumed) = (0, 0, 0);
    loop {
        let before = if run.join("config.toml").exists() { check_latest(&run) } else { None };
        let mut child = train(&run);
        if kills == KILLS {
            let (text, ok) = wait_exit(child);
            assert!(ok, "the last resume failed:\n{text}");
            assert!(text.contains(&format!("at step {}", before.unwrap())), "{text}");
            break;
        }
        // Let it train 1–4 steps past where it resumed, then kill it: on even rounds at a random
        // moment of the next step, on odd ones as soon as a checkpoint write is seen (plus a
        // random fraction of a millisecond).
        let target = before.unwrap_or(0) + 1 + rng.below(4);
        while latest_step(&run).is_none_or(|s| s < target) && child.try_wait().unwrap().is_none() {
            std::thread::sleep(Duration::from_millis(1));
        }
        if kills % 2 == 0 {
            std::thread::sleep(Duration::from_secs_f64(step_s * rng.uniform() as f64));
        } else if wait_for_temporary(&checkpoints, ".step-", &mut child, Duration::from_secs(30)) {
            std::thread::sleep(Duration::from_micros((1000.0 * rng.uniform()) as u64));
        }
        let writing = has_entry(&checkpoints, ".step-", &format!(".tmp-{}", child.id()));
        let (text, finished) = kill(child);
        assert!(!finished, "the run ended before the kill: raise crash_config's iters");
        kills += 1;
        in_write += writing as usize;
        // The process resumed from the checkpoint `latest` named when it started.
        if let Some(step) = before {
            if text.contains("resuming") {
                assert!(text.contains(&format!("at step {step}")), "resumed elsewhere than step {step}:\n{text}");
                resumed += 1;
            }
        }
        // `latest` names a complete checkpoint, and eval and export accept the run.
        assert!(check_latest(&run).is_some(), "no checkpoint after kill {kills}");
        let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&dir.path().join("bundle"))]);
        assert!(ok, "export after kill {kills}: {text}");
        let (ok, text) = nerf(&["eval", "--run", s(&run), "--data", s(&scene), "--limit", "1", "--out", s(&dir.path().join(format!("eval-{kills}")))]);
        assert!(ok, "eval after kill {kills}: {text}");
    }
    eprintln!("{kills} kills ({in_write} during a checkpoint write, {resumed} after a resume); uninterrupted run {full_s:.1} s");
    assert!(in_write >= 2, "too few kills landed inside a checkpoint write ({in_write})");

    // Same weights, grid, step and RNG as the uninterrupted run, bit for bit: resuming restores
    // everything (the Adam state too, or the weights would drift) and training is
    // deterministic. The .bpk files themselves differ: burn stores a random id per parameter.
    let load = |run: &Path| load_latest(&RunDir::open(run).unwrap(), &nerf::backend::cpu()).unwrap();
    let RunCheckpoint { model: got, state: got_state, occupancy: got_grid, .. } = load(&run);
    let RunCheckpoint { model: want, state: want_state, occupancy: want_grid, .. } = load(&reference);
    let (got, want) = (got.as_any().downcast_ref::<nerf::field::mlp::NerfModel>().unwrap(), want.as_any().downcast_ref::<nerf::field::mlp::NerfModel>().unwrap());
    assert!(got.coarse.to_plain() == want.coarse.to_plain(), "coarse weights differ from the uninterrupted run's");
    assert!(got.fine.as_ref().map(|f| f.to_plain()) == want.fine.as_ref().map(|f| f.to_plain()), "fine weights differ");
    assert!(got_grid == want_grid, "occupancy grids differ");
    assert_eq!((got_state.step, got_state.rng), (want_state.step, want_state.rng));
    let leftovers: Vec<PathBuf> = std::fs::read_dir(&checkpoints).unwrap().map(|e| e.unwrap().path()).filter(|p| p.file_name().unwrap().to_string_lossy().starts_with('.')).collect();
    assert!(leftovers.is_empty(), "temporaries left after a clean end: {leftovers:?}");
}

/// Wait for `child` to exit by itself: (stderr, success).
fn wait_exit(child: Child) -> (String, bool) {
    let out = child.wait_with_output().unwrap();
    (String::from_utf8_lossy(&out.stderr).into_owned(), out.status.success())
}

#[test]
fn killed_export_leaves_the_old_bundle() {
    let dir = tempfile::tempdir().unwrap();
    let (_, run) = common::trained_run(dir.path());
    let bundle = dir.path().join("bundle");
    // The old bundle (opset 17) and, written elsewhere, the new one (opset 18): they differ.
    let export = |out: &Path, opset: &str| nerf(&["export", "--run", s(&run), "--out", s(out), "--opset", opset]);
    assert!(export(&bundle, "17").0);
    let old = snapshot(&bundle);
    let new_dir = dir.path().join("new");
    assert!(export(&new_dir, "18").0);
    let new = snapshot(&new_dir);
    assert_ne!(old, new);

    let mut rng = Rng::new(5);
    let t0 = Instant::now();
    wait_exit(start(&["export", "--run", s(&run), "--out", s(&new_dir), "--opset", "18"]));
    let export_s = t0.elapsed().as_secs_f64();
    let (mut saw_old, mut saw_new, mut in_write) = (0, 0, 0);
    for k in 0..8 {
        let mut child = start(&["export", "--run", s(&run), "--out", s(&bundle), "--opset", "18"]);
        if k % 2 == 0 {
            std::thread::sleep(Duration::from_secs_f64(export_s * rng.uniform() as f64));
        } else if wait_for_temporary(dir.path(), ".bundle.tmp-", &mut child, Duration::from_secs(30)) {
            in_write += 1;
            std::thread::sleep(Duration::from_micros((3000.0 * rng.uniform()) as u64));
        }
        kill(child);
        // A complete bundle, the old or the new, whatever the moment of the kill.
        let now = snapshot(&bundle);
        if now == old {
            saw_old += 1;
        } else {
            assert!(now == new, "after kill {k} the bundle is neither the old nor the new one: {:?}", now.keys().collect::<Vec<_>>());
            saw_new += 1;
        }
        let scene = nerf_bundle::read_scene(&bundle).unwrap();
        for g in scene.graph_files() {
            nerf_bundle::read_model(&bundle.join(g.file)).unwrap();
        }
        nerf_bundle::read_occupancy(&bundle, &scene).unwrap().expect("the grid");
    }
    eprintln!("export killed 8 times ({in_write} while writing): old bundle {saw_old}×, new {saw_new}×; one export {export_s:.2} s");
    // Whatever killed exports left beside the bundle, the next export removes.
    let (ok, text) = export(&bundle, "17");
    assert!(ok, "{text}");
    assert_eq!(snapshot(&bundle), old);
    let stale: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).filter(|n| n.to_string_lossy().starts_with(".bundle.")).collect();
    assert!(stale.is_empty(), "left behind: {stale:?}");
}
