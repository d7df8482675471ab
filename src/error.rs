//! The training library's error type: every failure names the file (or setting) and the problem.

use std::path::{Path, PathBuf};

/// A failure of training, evaluation, export or benchmarking.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// From the burn-free core: I/O, JSON, images, dataset and grid files (the file is named).
    #[error(transparent)]
    Core(#[from] nerf_core::Error),
    /// From the ONNX compiler.
    #[error(transparent)]
    Export(#[from] nerf_export::ExportError),
    /// From onnxruntime (LPIPS in `nerf eval`).
    #[error(transparent)]
    Runtime(#[from] nerf_runtime::RuntimeError),
    /// A file of a run (or given by the user) is readable but wrong: a malformed `config.toml`,
    /// a truncated or foreign checkpoint, a directory that is not a run.
    #[error("{path}: {problem}")]
    Invalid {
        /// The file or directory.
        path: PathBuf,
        /// What is wrong with it.
        problem: String,
    },
    /// A configuration value is out of range.
    #[error("{0}")]
    Config(String),
    /// Network weights that do not fit their description.
    #[error("invalid network: {0}")]
    Network(String),
    /// Training diverged (the run is checkpointed first).
    #[error("the loss became {loss} at step {step}: lower lr or enable grad_clip_norm")]
    Diverged {
        /// Steps completed.
        step: usize,
        /// The loss of the last step.
        loss: f32,
    },
    /// Drawing a plot failed (the font or the chart library; not the data, whose problems are
    /// [`Error::Invalid`] naming the file).
    #[error("drawing a plot: {0}")]
    Plot(String),
    /// An external program (COLMAP, ffmpeg, the PyTorch comparison of `nerf bench`) failed.
    #[error("{program}: {problem}")]
    External {
        /// The program.
        program: PathBuf,
        /// What went wrong.
        problem: String,
    },
}

/// `Result` with the library's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Core(nerf_core::Error::io(path, source))
    }

    /// A content problem in `path`.
    pub fn invalid(path: &Path, problem: impl Into<String>) -> Self {
        Error::Invalid { path: path.to_path_buf(), problem: problem.into() }
    }
}
