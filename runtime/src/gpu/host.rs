//! The GPU loop's kernels compiled for the CPU (the system's C++ compiler, no fused
//! multiply-adds, as NVRTC is told) and launched thread by thread, with host memory as the
//! device's: [`GpuMarch`](super::GpuMarch) then runs where there is no GPU, onnxruntime's CPU
//! session evaluating the field in place. What this cannot test is CUDA's own calls
//! (`cuda.rs`); the Python package's tests compile the same file the same way.

use super::{Arg, Backend, Buffer, DevicePtr, kernel_source, parameters};
use libloading::Library;
use std::alloc::Layout;
use std::ffi::c_void;
use std::process::Command;

/// CUDA's names for the thread index and qualifiers, for one "thread" per call.
const PRELUDE: &str = "#include <math.h>\n#define __device__\n#define __global__\n#define __forceinline__ inline\nstruct Dim { int x; };\nstatic Dim blockIdx = {0}, blockDim = {1}, threadIdx = {0};\n";

/// `launch_<name>(threads, params)` for each `extern "C" __global__ void <name>(...)` of
/// `source`: its parameters read from `params` as `cuLaunchKernel` passes them.
fn launchers(source: &str) -> String {
    let mut out = String::new();
    const KERNEL: &str = "__global__ void ";
    for (at, _) in source.match_indices(KERNEL) {
        let rest = &source[at + KERNEL.len()..];
        let name = &rest[..rest.find('(').expect("a kernel's parameter list")];
        let list = &rest[name.len() + 1..rest.find(')').expect("a closed parameter list")];
        let args: Vec<String> = list
            .split(',')
            .enumerate()
            .map(|(k, param)| {
                let param = param.trim();
                let ty = &param[..param.rfind(|c: char| !(c.is_alphanumeric() || c == '_')).map_or(0, |i| i + 1)];
                format!("*({}*)p[{k}]", ty.trim())
            })
            .collect();
        out += &format!("extern \"C\" void launch_{name}(int threads, void** p) {{ for (int i = 0; i < threads; ++i) {{ threadIdx.x = i; {name}({}); }} }}\n", args.join(", "));
    }
    out
}

/// The kernels in a shared library of the CPU.
pub struct HostKernels {
    library: Library,
    _dir: tempfile::TempDir,
}

impl HostKernels {
    /// Compile `march.cu` with `c++` (why not, where there is no compiler).
    pub fn compile() -> Result<Self, String> {
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        let source = kernel_source();
        let cpp = dir.path().join("march.cpp");
        let lib = dir.path().join("march.so");
        std::fs::write(&cpp, format!("{PRELUDE}{source}\n{}", launchers(&source))).map_err(|e| e.to_string())?;
        let status = Command::new("c++")
            .args(["-O1", "-ffp-contract=off", "-shared", "-fPIC", "-o"])
            .arg(&lib)
            .arg(&cpp)
            .status()
            .map_err(|e| format!("c++: {e}"))?;
        if !status.success() {
            return Err(format!("c++ could not compile {}", cpp.display()));
        }
        // SAFETY: our own library, no initialisers.
        let library = unsafe { Library::new(&lib) }.map_err(|e| e.to_string())?;
        Ok(HostKernels { library, _dir: dir })
    }
}

/// Host memory standing in for a device's (8-byte aligned, zeroed).
pub struct HostBuffer {
    ptr: *mut u8,
    layout: Layout,
}

impl Buffer for HostBuffer {
    fn ptr(&self) -> DevicePtr {
        self.ptr as DevicePtr
    }
    fn write<T: Copy>(&self, data: &[T]) -> Result<(), String> {
        let bytes = std::mem::size_of_val(data);
        assert!(bytes <= self.layout.size());
        // SAFETY: both hold `bytes`.
        unsafe { std::ptr::copy_nonoverlapping(data.as_ptr().cast::<u8>(), self.ptr, bytes) };
        Ok(())
    }
    fn read<T: Copy>(&self, out: &mut [T]) -> Result<(), String> {
        let bytes = std::mem::size_of_val(out);
        assert!(bytes <= self.layout.size());
        // SAFETY: both hold `bytes`; the types read are plain numbers.
        unsafe { std::ptr::copy_nonoverlapping(self.ptr, out.as_mut_ptr().cast::<u8>(), bytes) };
        Ok(())
    }
}

impl Drop for HostBuffer {
    fn drop(&mut self) {
        // SAFETY: allocated with this layout.
        unsafe { std::alloc::dealloc(self.ptr, self.layout) };
    }
}

impl Backend for HostKernels {
    type Buffer = HostBuffer;
    fn alloc(&self, bytes: usize) -> Result<HostBuffer, String> {
        let layout = Layout::from_size_align(bytes.max(8), 8).map_err(|e| e.to_string())?;
        // SAFETY: a non-zero size.
        let ptr = unsafe { std::alloc::alloc_zeroed(layout) };
        Ok(HostBuffer { ptr, layout })
    }
    fn launch(&self, name: &str, threads: usize, args: &[Arg]) -> Result<(), String> {
        let mut values = args.to_vec();
        let mut params = parameters(&mut values);
        // SAFETY: launch_<name> takes (int, void**) and reads one value per kernel parameter.
        unsafe {
            let launch: libloading::Symbol<unsafe extern "C" fn(i32, *mut *mut c_void)> =
                self.library.get(format!("launch_{name}\0").as_bytes()).map_err(|e| e.to_string())?;
            launch(threads as i32, params.as_mut_ptr());
        }
        Ok(())
    }
    fn synchronize(&self) -> Result<(), String> {
        Ok(())
    }
    fn bind(&self) -> Result<(), String> {
        Ok(())
    }
}
