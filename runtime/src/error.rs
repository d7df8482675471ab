//! The runtime's error: every failure names the file (or the library) and the problem.

use std::path::PathBuf;

/// A failure of the onnxruntime renderer.
#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    /// onnxruntime's shared library could not be found or loaded.
    #[error("{0}")]
    Library(String),
    /// A bundle file is missing, unreadable or does not follow the contract.
    #[error("{path}: {problem}")]
    Bundle {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        problem: String,
    },
    /// onnxruntime failed on a graph.
    #[error("{path}: onnxruntime: {message}")]
    Ort {
        /// The graph.
        path: PathBuf,
        /// onnxruntime's message.
        message: String,
    },
    /// Reading or writing a file of the core's formats (frames, grids, datasets).
    #[error(transparent)]
    Core(#[from] nerf_core::Error),
    /// Anything else (options), already phrased for the user.
    #[error("{0}")]
    Other(String),
}

impl RuntimeError {
    /// A problem with `path`.
    pub fn bundle(path: impl Into<PathBuf>, problem: impl Into<String>) -> Self {
        RuntimeError::Bundle { path: path.into(), problem: problem.into() }
    }
}

/// `Result` with [`RuntimeError`].
pub type Result<T> = std::result::Result<T, RuntimeError>;
