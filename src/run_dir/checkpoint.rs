//! Checkpoints: `<run>/checkpoints/step-NNNNNNN/{model.bpk, optim.bpk, state.json[, occupancy.bin][, the field's own files]}` plus a
//! `latest` file naming the newest. Each checkpoint directory is written whole or not at all
//! ([`write_dir_atomic`]) before `latest` is replaced atomically, so a crash never leaves a
//! checkpoint that `latest` points to half-written.

use crate::error::{Error, Result};
use burn::optim::ModuleOptimizer;
use burn::store::{BurnpackStore, ModuleSnapshot};
use burn::tensor::Bytes;
use nerf_core::Rng;
use nerf_core::sample::occupancy::{self, OccupancyGrid};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The `format` of `state.json`.
pub const FORMAT: &str = "nerf-rs-checkpoint-1";
/// Checkpoint directories are named `step-` and the step, seven digits.
pub const PREFIX: &str = "step-";

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
    /// The hash-grid trainer's samples per ray in its last step, which sets the next step's
    /// ray count (absent for the NeRF MLPs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub samples_per_ray: Option<f32>,
}

impl CheckpointState {
    /// The state after `step` steps.
    pub fn new(step: usize, rng: Rng, elapsed_s: f64) -> Self {
        CheckpointState { format: FORMAT.into(), step, rng, elapsed_s, samples_per_ray: None }
    }
}

/// A checkpoint directory.
#[derive(Debug, Clone)]
pub struct Checkpoint {
    /// `<run>/checkpoints/step-…`.
    pub dir: PathBuf,
}

/// The bytes of a checkpoint file.
pub fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

impl Checkpoint {
    /// Whether `name` is a checkpoint directory's name (`step-` and digits).
    pub fn is_name(name: &str) -> bool {
        name.strip_prefix(PREFIX).is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
    }

    /// The step in the directory's name.
    pub fn step(&self) -> Option<usize> {
        self.dir.file_name()?.to_str()?.strip_prefix(PREFIX)?.parse().ok()
    }

    /// The weights of `model` as a checkpoint's `model.bpk`.
    pub fn model_bytes<M: ModuleSnapshot>(model: &M) -> Result<Vec<u8>> {
        let mut store = BurnpackStore::from_bytes(None);
        model.save_into(&mut store).map_err(|e| Error::Network(format!("saving the model: {e}")))?;
        Ok(store.get_bytes().map_err(|e| Error::Network(format!("saving the model: {e}")))?.to_vec())
    }

    /// The optimizer's state as a checkpoint's `optim.bpk`.
    pub fn optimizer_bytes(optim: &ModuleOptimizer) -> Result<Vec<u8>> {
        Ok(optim.into_bytes().map_err(|e| Error::Network(format!("saving the optimizer: {e}")))?.to_vec())
    }

    /// The saved training state.
    pub fn state(&self) -> Result<CheckpointState> {
        let path = self.dir.join("state.json");
        let bytes = nerf_core::io::limits::read_bounded(&path, nerf_core::io::limits::MAX_JSON_BYTES)?;
        let state: CheckpointState =
            serde_json::from_slice(&bytes).map_err(|e| Error::invalid(&path, format!("not a checkpoint state ({e})")))?;
        if state.format != FORMAT {
            return Err(Error::invalid(&path, format!("format {:?}, expected {FORMAT:?}", state.format)));
        }
        Ok(state)
    }

    /// Load the weights into `model` (which must have the checkpoint's shapes).
    pub fn load_model<M: ModuleSnapshot>(&self, model: &mut M) -> Result<()> {
        let path = self.dir.join("model.bpk");
        let bytes = read(&path)?;
        let mut store = BurnpackStore::from_bytes(Some(Bytes::from_bytes_vec(bytes)));
        let result = model
            .load_from(&mut store)
            .map_err(|e| Error::invalid(&path, format!("cannot load weights (truncated or foreign file?): {e}")))?;
        if !result.errors.is_empty() || !result.missing.is_empty() {
            let problem = format!("weights do not match the network in config.toml: {} errors, missing {:?}", result.errors.len(), result.missing);
            return Err(Error::invalid(&path, problem));
        }
        Ok(())
    }

    /// The occupancy grid saved with the weights, if the run skips empty space.
    pub fn load_occupancy(&self) -> Result<Option<OccupancyGrid>> {
        let path = self.dir.join(occupancy::FILE_NAME);
        if !path.exists() {
            return Ok(None);
        }
        Ok(Some(OccupancyGrid::load(&path)?))
    }

    /// Load the optimizer state into `optim`.
    pub fn load_optimizer(&self, optim: ModuleOptimizer) -> Result<ModuleOptimizer> {
        let path = self.dir.join("optim.bpk");
        let bytes = read(&path)?;
        // The record parser can panic on some malformed inputs; turn that into an error too.
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| optim.from_bytes(Bytes::from_bytes_vec(bytes))))
            .map_err(|_| Error::invalid(&path, "corrupt optimizer state"))?
            .map_err(|e| Error::invalid(&path, format!("cannot load optimizer state (truncated or foreign file?): {e}")))
    }
}
