//! Checkpoints: `<run>/checkpoints/step-NNNNNNN/{model.bpk, optim.bpk, state.json[, occupancy.bin]}` plus a
//! `latest` file naming the newest. Each checkpoint is written into a temporary directory and
//! renamed into place, then `latest` is replaced atomically, so a crash never leaves a
//! checkpoint that `latest` points to half-written.

use super::TrainConfig;
use crate::field::{NerfMlp, NerfModel};
use burn::optim::ModuleOptimizer;
use burn::store::{BurnpackStore, ModuleSnapshot};
use burn::tensor::{Bytes, Device};
use nerf_core::Rng;
use nerf_core::error::{sync_dir, write_atomic, write_synced};
use nerf_core::occupancy::{self, OccupancyGrid};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

const FORMAT: &str = "nerf-rs-checkpoint-1";

/// Training progress saved with the weights.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckpointState {
    /// Format tag, to reject foreign files clearly.
    pub format: String,
    /// Steps completed.
    pub step: usize,
    /// The batch/jitter RNG after `step` steps.
    pub rng: Rng,
    /// Training seconds spent so far (for time budgets across resumes).
    pub elapsed_s: f64,
}

/// A checkpoint directory.
#[derive(Debug, Clone)]
pub struct Checkpoint {
    /// `<run>/checkpoints/step-…`.
    pub dir: PathBuf,
}

/// `<run>/config.toml`.
pub fn config_path(run: &Path) -> PathBuf {
    run.join("config.toml")
}

/// The checkpoint `latest` names, or `None` for a run that has none yet.
pub fn latest_checkpoint(run: &Path) -> Result<Option<Checkpoint>, String> {
    let latest = run.join("checkpoints").join("latest");
    match std::fs::read_to_string(&latest) {
        Ok(name) => {
            nerf_core::limits::check_plain_file_name(name.trim(), nerf_core::limits::Origin::Field(&latest, "checkpoint name")).map_err(|e| e.to_string())?;
            let dir = run.join("checkpoints").join(name.trim());
            if !dir.is_dir() {
                return Err(format!("{}: names {}, which does not exist", latest.display(), dir.display()));
            }
            Ok(Some(Checkpoint { dir }))
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(format!("{}: {e}", latest.display())),
    }
}

fn read(path: &Path) -> Result<Vec<u8>, String> {
    std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))
}

impl Checkpoint {
    /// Write model, optimizer and state for `state.step`, then point `latest` at it.
    pub fn save(
        run: &Path,
        model: &NerfModel,
        optim: &ModuleOptimizer,
        occupancy: Option<&OccupancyGrid>,
        state: &CheckpointState,
    ) -> Result<Checkpoint, String> {
        let root = run.join("checkpoints");
        std::fs::create_dir_all(&root).map_err(|e| format!("{}: {e}", root.display()))?;
        let name = format!("step-{:07}", state.step);
        let dir = root.join(&name);
        let tmp_name = format!(".{name}.tmp-{}", std::process::id());
        let tmp = root.join(&tmp_name);
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir_all(&tmp).map_err(|e| format!("{}: {e}", tmp.display()))?;
        let mut store = BurnpackStore::from_bytes(None);
        model.save_into(&mut store).map_err(|e| format!("saving model: {e}"))?;
        let model_bytes = store.get_bytes().map_err(|e| format!("saving model: {e}"))?;
        let optim_bytes = optim.into_bytes().map_err(|e| format!("saving optimizer: {e}"))?;
        let write = |file: &str, bytes: &[u8]| write_synced(&tmp.join(file), bytes).map_err(|e| e.to_string());
        write("model.bpk", &model_bytes)?;
        write("optim.bpk", &optim_bytes)?;
        if let Some(grid) = occupancy {
            write(occupancy::FILE_NAME, &grid.to_bytes())?;
        }
        write("state.json", serde_json::to_string_pretty(state).expect("state serialises").as_bytes())?;
        sync_dir(&tmp);
        let latest = root.join("latest");
        if dir.exists() {
            // Replacing the checkpoint `latest` may name (the same step saved again): point
            // `latest` at the complete new copy first, so it never names a missing directory.
            if std::fs::read_to_string(&latest).is_ok_and(|l| l.trim() == name) {
                write_atomic(&latest, tmp_name.as_bytes()).map_err(|e| e.to_string())?;
            }
            std::fs::remove_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        }
        std::fs::rename(&tmp, &dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        sync_dir(&root);
        write_atomic(&latest, name.as_bytes()).map_err(|e| e.to_string())?;
        // Keep the newest two (the one just written and its predecessor); remove what killed
        // saves left behind (`.step-*.tmp-*` directories, `.latest.tmp-*` files).
        if let Ok(entries) = std::fs::read_dir(&root) {
            let mut old = Vec::new();
            for path in entries.filter_map(|e| e.ok().map(|e| e.path())) {
                let file = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
                if file.starts_with(".step-") || file.starts_with(".latest.tmp-") {
                    let _ = if path.is_dir() { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) };
                } else if path.is_dir() && file.starts_with("step-") && path != dir {
                    old.push(path);
                }
            }
            old.sort();
            for p in old.iter().rev().skip(1) {
                let _ = std::fs::remove_dir_all(p);
            }
        }
        Ok(Checkpoint { dir })
    }

    /// The saved training state.
    pub fn state(&self) -> Result<CheckpointState, String> {
        let path = self.dir.join("state.json");
        let bytes = nerf_core::limits::read_bounded(&path, nerf_core::limits::MAX_JSON_BYTES).map_err(|e| e.to_string())?;
        let state: CheckpointState = serde_json::from_slice(&bytes)
            .map_err(|e| format!("{}: not a checkpoint state ({e})", path.display()))?;
        if state.format != FORMAT {
            return Err(format!("{}: format {:?}, expected {FORMAT:?}", path.display(), state.format));
        }
        Ok(state)
    }

    /// Load the weights into `model` (which must have the checkpoint's shapes).
    pub fn load_model(&self, model: &mut NerfModel) -> Result<(), String> {
        let path = self.dir.join("model.bpk");
        let bytes = read(&path)?;
        let mut store = BurnpackStore::from_bytes(Some(Bytes::from_bytes_vec(bytes)));
        let result = model
            .load_from(&mut store)
            .map_err(|e| format!("{}: cannot load weights (truncated or foreign file?): {e}", path.display()))?;
        if !result.errors.is_empty() || !result.missing.is_empty() {
            return Err(format!(
                "{}: weights do not match the network in config.toml: {} errors, missing {:?}",
                path.display(),
                result.errors.len(),
                result.missing
            ));
        }
        Ok(())
    }

    /// The occupancy grid saved with the weights, if the run skips empty space.
    pub fn load_occupancy(&self) -> Result<Option<OccupancyGrid>, String> {
        let path = self.dir.join(occupancy::FILE_NAME);
        if !path.exists() {
            return Ok(None);
        }
        OccupancyGrid::load(&path).map(Some).map_err(|e| e.to_string())
    }

    /// Load the optimizer state into `optim`.
    pub fn load_optimizer(&self, optim: ModuleOptimizer) -> Result<ModuleOptimizer, String> {
        let path = self.dir.join("optim.bpk");
        let bytes = read(&path)?;
        // The record parser can panic on some malformed inputs; turn that into an error too.
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| optim.from_bytes(Bytes::from_bytes_vec(bytes))))
            .map_err(|_| format!("{}: corrupt optimizer state", path.display()))?
            .map_err(|e| format!("{}: cannot load optimizer state (truncated or foreign file?): {e}", path.display()))
    }
}

/// A new state record for `step`.
pub fn new_state(step: usize, rng: Rng, elapsed_s: f64) -> CheckpointState {
    CheckpointState { format: FORMAT.into(), step, rng, elapsed_s }
}

/// Load a run's configuration and latest model onto `device` (for eval, render, export).
pub fn load_model(run: &Path, device: &Device) -> Result<(TrainConfig, NerfModel, CheckpointState, Option<OccupancyGrid>), String> {
    let config_file = config_path(run);
    if !config_file.exists() {
        return Err(format!("{}: no such file: is {} a training run directory?", config_file.display(), run.display()));
    }
    let config = TrainConfig::from_toml_file(&config_file, None)?;
    let checkpoint = latest_checkpoint(run)?
        .ok_or_else(|| format!("{}: the run has no checkpoint yet", run.join("checkpoints").display()))?;
    let state = checkpoint.state()?;
    let mut model = NerfModel::new(&config.network, config.sampling.n_fine > 0, device);
    checkpoint.load_model(&mut model)?;
    let occupancy = if config.skip_empty_space { checkpoint.load_occupancy()? } else { None };
    Ok((config, model, state, occupancy))
}

impl NerfModel {
    /// Fresh coarse (and, with `fine`, fine) networks of shape `spec`.
    pub fn new(spec: &nerf_core::network::NetworkSpec, fine: bool, device: &Device) -> Self {
        NerfModel { coarse: NerfMlp::new(spec, device), fine: fine.then(|| NerfMlp::new(spec, device)) }
    }
}
