//! The one onnxruntime environment of the process (ort allows only one, ever), loaded from
//! `libonnxruntime.so` at run time (`load-dynamic`): no onnxruntime at build time.

use crate::error::{Result, RuntimeError};
use ort::environment::Environment;
use ort::ep::ExecutionProvider;
use ort::session::builder::SessionBuilder;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The environment variable naming the library file (ort's own convention).
pub const DYLIB_ENV: &str = "ORT_DYLIB_PATH";

/// How to get the library, for error messages.
pub const HOW_TO_INSTALL: &str = "run `bash scripts/setup.sh` (installs the PyPI onnxruntime wheel, which carries \
     libonnxruntime.so, into ~/.cache/nerf-rs/venv), or `pip install onnxruntime==1.31.1` anywhere and set \
     ORT_DYLIB_PATH=<site-packages>/onnxruntime/capi/libonnxruntime.so.1.31.1";

/// How to get the GPU build, for error messages.
pub const HOW_TO_INSTALL_GPU: &str = "run `bash scripts/setup.sh --gpu` (installs the PyPI onnxruntime-gpu==1.31.1 wheel, \
     the CUDA 13 build, into ~/.cache/nerf-rs/venv-gpu), or set ORT_DYLIB_PATH to onnxruntime-gpu's \
     <site-packages>/onnxruntime/capi/libonnxruntime.so.1.31.1";

/// Where a graph runs: `cpu`, or `cuda` / `cuda:N` (onnxruntime's CUDA execution provider on
/// GPU N, default 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Device {
    /// onnxruntime's default (CPU) provider.
    #[default]
    Cpu,
    /// onnxruntime's CUDA provider on this GPU index.
    Cuda(u32),
}

impl std::str::FromStr for Device {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let bad = || format!("unknown device {s:?}: expected cpu, cuda or cuda:N (N a GPU index: 0, 1, …)");
        match s {
            "cpu" => Ok(Device::Cpu),
            "cuda" => Ok(Device::Cuda(0)),
            _ => {
                let n = s.strip_prefix("cuda:").ok_or_else(bad)?;
                // Digits only: u32's parser would take "+1".
                if n.is_empty() || !n.bytes().all(|b| b.is_ascii_digit()) {
                    return Err(bad());
                }
                n.parse().map(Device::Cuda).map_err(|_| bad())
            }
        }
    }
}

impl std::fmt::Display for Device {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Device::Cpu => write!(f, "cpu"),
            Device::Cuda(n) => write!(f, "cuda:{n}"),
        }
    }
}

/// Where to look for the library: `$ORT_DYLIB_PATH`, else the wheels installed by
/// `scripts/setup.sh` under `$NERF_HOME` (default `~/.cache/nerf-rs`): for [`Device::Cuda`]
/// first `venv-gpu` (`setup.sh --gpu`), then `venv`; `lib/python3*/site-packages/onnxruntime/
/// capi/libonnxruntime.so*`.
pub fn library_path(device: Device) -> Result<PathBuf> {
    library_path_in(device, std::env::var_os(DYLIB_ENV).filter(|p| !p.is_empty()).map(PathBuf::from), nerf_home().as_deref())
}

/// Where `scripts/setup.sh` installs what the project uses at run time: `$NERF_HOME`, default
/// `~/.cache/nerf-rs` (`None` without either variable).
pub fn nerf_home() -> Option<PathBuf> {
    std::env::var_os("NERF_HOME")
        .filter(|h| !h.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| Path::new(&h).join(".cache/nerf-rs")))
}

/// [`library_path`] given `$ORT_DYLIB_PATH` and the `$NERF_HOME` directory.
pub fn library_path_in(device: Device, dylib: Option<PathBuf>, home: Option<&Path>) -> Result<PathBuf> {
    if let Some(path) = dylib {
        if !path.is_file() {
            return Err(RuntimeError::Library(format!("{DYLIB_ENV}={} does not name a file: {HOW_TO_INSTALL}", path.display())));
        }
        return Ok(path);
    }
    let venvs: &[&str] = if device == Device::Cpu { &["venv"] } else { &["venv-gpu", "venv"] };
    let libs: Vec<PathBuf> = home.map(|h| venvs.iter().map(|v| h.join(v).join("lib")).collect()).unwrap_or_default();
    if let Some(found) = libs.iter().find_map(|lib| find_in_venv(lib)) {
        return Ok(found);
    }
    let looked: String = libs.iter().map(|p| format!(" and {}/python3*/site-packages/onnxruntime/capi", p.display())).collect();
    let how = if device == Device::Cpu { HOW_TO_INSTALL } else { HOW_TO_INSTALL_GPU };
    Err(RuntimeError::Library(format!("onnxruntime library not found (looked at ${DYLIB_ENV}{looked}): {how}")))
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

static ENVIRONMENT: OnceLock<std::result::Result<(Environment, PathBuf), String>> = OnceLock::new();

/// The process's onnxruntime environment, created on first use from the library for `device`
/// ([`library_path`]; the first call's device picks it: ort allows one per process).
pub fn environment_for(device: Device) -> Result<&'static Environment> {
    init(device).map(|(environment, _)| environment)
}

/// The process's onnxruntime environment for the CPU ([`environment_for`]).
pub fn environment() -> Result<&'static Environment> {
    environment_for(Device::Cpu)
}

fn init(device: Device) -> Result<&'static (Environment, PathBuf)> {
    ENVIRONMENT
        .get_or_init(|| {
            let path = library_path(device).map_err(|e| e.to_string())?;
            let builder = ort::init_from(&path).map_err(|e| format!("{}: cannot load onnxruntime: {e}; {HOW_TO_INSTALL}", path.display()))?;
            let environment = builder.with_name("nerf-render").build().map_err(|e| format!("{}: cannot create the onnxruntime environment: {e}", path.display()))?;
            Ok((environment, path))
        })
        .as_ref()
        .map_err(|e| RuntimeError::Library(e.clone()))
}

/// Put a session on `device`: nothing for the CPU; for CUDA, onnxruntime's CUDA provider on
/// that GPU with TF32 off (with it on, the field differs from the CPU's by up to 6e-3 in rgb;
/// off, by 2e-7), and an error where it cannot be had (ort would fall back to the CPU
/// silently).
pub fn place(builder: SessionBuilder, device: Device) -> Result<SessionBuilder> {
    let Device::Cuda(id) = device else { return Ok(builder) };
    let (_, path) = init(device)?;
    let available = ort::ep::CUDA::is_available().map_err(|e| RuntimeError::Library(format!("{}: cannot list onnxruntime's providers: {e}", path.display())))?;
    if !available {
        return Err(RuntimeError::Library(format!(
            "--device {device}: the onnxruntime library {} is not a CUDA build (its providers lack CUDAExecutionProvider): {HOW_TO_INSTALL_GPU}",
            path.display()
        )));
    }
    let index = i32::try_from(id).map_err(|_| RuntimeError::Library(format!("--device {device}: no such GPU index")))?;
    let cuda = ort::ep::CUDA::default().with_device_id(index).with_tf32(false).build().error_on_failure();
    builder.with_execution_providers([cuda]).map_err(|e| {
        RuntimeError::Library(format!(
            "--device {device}: onnxruntime's CUDA provider ({}) cannot run on GPU {id}: {e} (it needs an NVIDIA GPU with that index, its driver, \
             and CUDA 13's runtime, cuBLAS and cuDNN 9 where the dynamic loader finds them (LD_LIBRARY_PATH), e.g. from PyTorch's cu130 wheels; --device cpu runs without)",
            path.display()
        ))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn device_strings() {
        assert_eq!("cpu".parse(), Ok(Device::Cpu));
        assert_eq!("cuda".parse(), Ok(Device::Cuda(0)));
        assert_eq!("cuda:3".parse(), Ok(Device::Cuda(3)));
        for bad in ["gpu", "cuda:x", "cuda:-1", "cuda:+1", "cuda:", "CUDA", "cuda:99999999999"] {
            let e = bad.parse::<Device>().unwrap_err();
            assert!(e.contains("expected cpu, cuda or cuda:N"), "{bad}: {e}");
        }
    }

    /// `venv-gpu` before `venv` for CUDA only; `$ORT_DYLIB_PATH` before both.
    #[test]
    fn the_gpu_wheel_is_looked_for_first() {
        let home = tempfile::tempdir().unwrap();
        let lib = |venv: &str| {
            let dir = home.path().join(venv).join("lib/python3.12/site-packages/onnxruntime/capi");
            std::fs::create_dir_all(&dir).unwrap();
            let file = dir.join("libonnxruntime.so.1.31.1");
            std::fs::write(&file, b"").unwrap();
            file
        };
        let cpu = lib("venv");
        assert_eq!(library_path_in(Device::Cuda(0), None, Some(home.path())).unwrap(), cpu, "no GPU wheel: the CPU one (and its clear error later)");
        let gpu = lib("venv-gpu");
        assert_eq!(library_path_in(Device::Cpu, None, Some(home.path())).unwrap(), cpu);
        assert_eq!(library_path_in(Device::Cuda(1), None, Some(home.path())).unwrap(), gpu);
        assert_eq!(library_path_in(Device::Cuda(0), Some(cpu.clone()), Some(home.path())).unwrap(), cpu);
        let empty = tempfile::tempdir().unwrap();
        let e = library_path_in(Device::Cuda(0), None, Some(empty.path())).unwrap_err().to_string();
        assert!(e.contains("venv-gpu") && e.contains("setup.sh --gpu"), "{e}");
    }
}
