//! The one onnxruntime environment of the process (ort allows only one, ever), loaded from
//! `libonnxruntime.so` at run time (`load-dynamic`): no onnxruntime at build time.

use crate::error::{Result, RuntimeError};
use ort::environment::Environment;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The environment variable naming the library file (ort's own convention).
pub const DYLIB_ENV: &str = "ORT_DYLIB_PATH";

/// How to get the library, for error messages.
pub const HOW_TO_INSTALL: &str = "run `bash scripts/setup.sh` (installs the PyPI onnxruntime wheel, which carries \
     libonnxruntime.so, into ~/.cache/nerf-rs/venv), or `pip install onnxruntime==1.31.1` anywhere and set \
     ORT_DYLIB_PATH=<site-packages>/onnxruntime/capi/libonnxruntime.so.1.31.1";

/// Where to look for the library: `$ORT_DYLIB_PATH`, else the wheel installed by
/// `scripts/setup.sh` under `$NERF_HOME` (default `~/.cache/nerf-rs`): `venv/lib/python3*/
/// site-packages/onnxruntime/capi/libonnxruntime.so*`.
pub fn library_path() -> Result<PathBuf> {
    if let Some(path) = std::env::var_os(DYLIB_ENV).filter(|p| !p.is_empty()) {
        let path = PathBuf::from(path);
        if !path.is_file() {
            return Err(RuntimeError::Library(format!("{DYLIB_ENV}={} does not name a file: {HOW_TO_INSTALL}", path.display())));
        }
        return Ok(path);
    }
    let home = std::env::var_os("NERF_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| Path::new(&h).join(".cache/nerf-rs")));
    let venv_lib = home.map(|h| h.join("venv/lib"));
    if let Some(found) = venv_lib.as_deref().and_then(find_in_venv) {
        return Ok(found);
    }
    let looked = venv_lib.map(|p| format!(" and {}/python3*/site-packages/onnxruntime/capi", p.display())).unwrap_or_default();
    Err(RuntimeError::Library(format!("onnxruntime library not found (looked at ${DYLIB_ENV}{looked}): {HOW_TO_INSTALL}")))
}

fn find_in_venv(lib: &Path) -> Option<PathBuf> {
    let mut candidates: Vec<PathBuf> = std::fs::read_dir(lib)
        .ok()?
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("python3"))
        .flat_map(|e| std::fs::read_dir(e.path().join("site-packages/onnxruntime/capi")).into_iter().flatten().flatten())
        .map(|e| e.path())
        .filter(|p| p.file_name().is_some_and(|n| n.to_string_lossy().starts_with("libonnxruntime.so")))
        .collect();
    // The fully versioned name (libonnxruntime.so.1.31.1) sorts last.
    candidates.sort();
    candidates.pop()
}

static ENVIRONMENT: OnceLock<std::result::Result<Environment, String>> = OnceLock::new();

/// The process's onnxruntime environment, created on first use.
pub fn environment() -> Result<&'static Environment> {
    ENVIRONMENT
        .get_or_init(|| {
            let path = library_path().map_err(|e| e.to_string())?;
            let builder = ort::init_from(&path).map_err(|e| format!("{}: cannot load onnxruntime: {e}; {HOW_TO_INSTALL}", path.display()))?;
            builder.with_name("nerf-render").build().map_err(|e| format!("{}: cannot create the onnxruntime environment: {e}", path.display()))
        })
        .as_ref()
        .map_err(|e| RuntimeError::Library(e.clone()))
}
