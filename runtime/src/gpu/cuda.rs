//! The few CUDA driver and NVRTC calls the GPU loop needs, loaded at run time: `libcuda.so.1`
//! (the driver) and NVRTC (`libnvrtc.so.13`, one of the CUDA 13 libraries onnxruntime-gpu
//! needs beside it). Nothing is linked: without them, `--device cuda` marches on the CPU.

use libloading::Library;
use std::ffi::{CStr, CString, c_char, c_int, c_uint, c_void};
use super::Arg;
use std::sync::Arc;

/// A device address.
pub type DevicePtr = u64;
type CuResult = c_int;
type Handle = *mut c_void;

/// The driver and NVRTC entry points (copied out of the libraries, which are kept alive).
struct Api {
    init: unsafe extern "C" fn(c_uint) -> CuResult,
    device_get: unsafe extern "C" fn(*mut c_int, c_int) -> CuResult,
    primary_ctx_retain: unsafe extern "C" fn(*mut Handle, c_int) -> CuResult,
    ctx_set_current: unsafe extern "C" fn(Handle) -> CuResult,
    ctx_synchronize: unsafe extern "C" fn() -> CuResult,
    module_load_data: unsafe extern "C" fn(*mut Handle, *const c_void) -> CuResult,
    module_get_function: unsafe extern "C" fn(*mut Handle, Handle, *const c_char) -> CuResult,
    #[allow(clippy::type_complexity)]
    launch_kernel: unsafe extern "C" fn(Handle, c_uint, c_uint, c_uint, c_uint, c_uint, c_uint, c_uint, Handle, *mut *mut c_void, *mut *mut c_void) -> CuResult,
    mem_alloc: unsafe extern "C" fn(*mut DevicePtr, usize) -> CuResult,
    mem_free: unsafe extern "C" fn(DevicePtr) -> CuResult,
    memcpy_htod: unsafe extern "C" fn(DevicePtr, *const c_void, usize) -> CuResult,
    memcpy_dtoh: unsafe extern "C" fn(*mut c_void, DevicePtr, usize) -> CuResult,
    error_string: unsafe extern "C" fn(CuResult, *mut *const c_char) -> CuResult,
    nvrtc_create: unsafe extern "C" fn(*mut Handle, *const c_char, *const c_char, c_int, *const *const c_char, *const *const c_char) -> c_int,
    nvrtc_compile: unsafe extern "C" fn(Handle, c_int, *const *const c_char) -> c_int,
    nvrtc_log_size: unsafe extern "C" fn(Handle, *mut usize) -> c_int,
    nvrtc_log: unsafe extern "C" fn(Handle, *mut c_char) -> c_int,
    nvrtc_ptx_size: unsafe extern "C" fn(Handle, *mut usize) -> c_int,
    nvrtc_ptx: unsafe extern "C" fn(Handle, *mut c_char) -> c_int,
    nvrtc_destroy: unsafe extern "C" fn(*mut Handle) -> c_int,
    _libraries: (Library, Library),
}

/// The first of `names` the dynamic loader finds.
fn open(names: &[&str]) -> Result<Library, String> {
    let mut errors = Vec::new();
    for name in names {
        // SAFETY: loading a system library runs its initialisers; the CUDA ones are plain.
        match unsafe { Library::new(name) } {
            Ok(lib) => return Ok(lib),
            Err(e) => errors.push(e.to_string()),
        }
    }
    Err(errors.join("; "))
}

impl Api {
    fn load() -> Result<Self, String> {
        let driver = open(&["libcuda.so.1", "libcuda.so"]).map_err(|e| format!("the CUDA driver (libcuda.so.1): {e}"))?;
        let nvrtc = open(&["libnvrtc.so.13", "libnvrtc.so.12", "libnvrtc.so"])
            .map_err(|e| format!("NVRTC (libnvrtc.so.13, from the CUDA 13 runtime libraries, e.g. the nvidia-cuda-nvrtc wheel, on LD_LIBRARY_PATH): {e}"))?;
        // SAFETY: each symbol is declared with its C signature (cuda.h, nvrtc.h).
        unsafe {
            macro_rules! sym {
                ($lib:expr, $name:literal) => {
                    *$lib.get($name).map_err(|e| format!("{}: {e}", String::from_utf8_lossy(&$name[..$name.len() - 1])))?
                };
            }
            Ok(Api {
                init: sym!(driver, b"cuInit\0"),
                device_get: sym!(driver, b"cuDeviceGet\0"),
                primary_ctx_retain: sym!(driver, b"cuDevicePrimaryCtxRetain\0"),
                ctx_set_current: sym!(driver, b"cuCtxSetCurrent\0"),
                ctx_synchronize: sym!(driver, b"cuCtxSynchronize\0"),
                module_load_data: sym!(driver, b"cuModuleLoadData\0"),
                module_get_function: sym!(driver, b"cuModuleGetFunction\0"),
                launch_kernel: sym!(driver, b"cuLaunchKernel\0"),
                mem_alloc: sym!(driver, b"cuMemAlloc_v2\0"),
                mem_free: sym!(driver, b"cuMemFree_v2\0"),
                memcpy_htod: sym!(driver, b"cuMemcpyHtoD_v2\0"),
                memcpy_dtoh: sym!(driver, b"cuMemcpyDtoH_v2\0"),
                error_string: sym!(driver, b"cuGetErrorString\0"),
                nvrtc_create: sym!(nvrtc, b"nvrtcCreateProgram\0"),
                nvrtc_compile: sym!(nvrtc, b"nvrtcCompileProgram\0"),
                nvrtc_log_size: sym!(nvrtc, b"nvrtcGetProgramLogSize\0"),
                nvrtc_log: sym!(nvrtc, b"nvrtcGetProgramLog\0"),
                nvrtc_ptx_size: sym!(nvrtc, b"nvrtcGetPTXSize\0"),
                nvrtc_ptx: sym!(nvrtc, b"nvrtcGetPTX\0"),
                nvrtc_destroy: sym!(nvrtc, b"nvrtcDestroyProgram\0"),
                _libraries: (driver, nvrtc),
            })
        }
    }

    fn check(&self, what: &str, code: CuResult) -> Result<(), String> {
        if code == 0 {
            return Ok(());
        }
        let mut text: *const c_char = std::ptr::null();
        // SAFETY: cuGetErrorString writes a static string or leaves the pointer null.
        unsafe { (self.error_string)(code, &mut text) };
        let text = if text.is_null() { "unknown error".into() } else { unsafe { CStr::from_ptr(text) }.to_string_lossy() };
        Err(format!("{what}: CUDA error {code} ({text})"))
    }
}

/// A GPU's primary context (the one onnxruntime's CUDA provider uses) and the driver.
#[derive(Clone)]
pub struct Cuda {
    api: Arc<Api>,
    context: Handle,
}

// SAFETY: a context handle may be made current on any thread (`bind` does, before each use).
unsafe impl Send for Cuda {}

impl Cuda {
    /// GPU `ordinal`'s primary context.
    pub fn new(ordinal: u32) -> Result<Self, String> {
        let api = Arc::new(Api::load()?);
        let (mut device, mut context) = (0, std::ptr::null_mut());
        // SAFETY: out-pointers to locals.
        unsafe {
            api.check("cuInit", (api.init)(0))?;
            api.check(&format!("cuDeviceGet({ordinal})"), (api.device_get)(&mut device, ordinal as c_int))?;
            api.check("cuDevicePrimaryCtxRetain", (api.primary_ctx_retain)(&mut context, device))?;
        }
        let cuda = Cuda { api, context };
        cuda.bind()?;
        Ok(cuda)
    }

    /// Make the context current on this thread.
    pub fn bind(&self) -> Result<(), String> {
        // SAFETY: a retained context.
        self.api.check("cuCtxSetCurrent", unsafe { (self.api.ctx_set_current)(self.context) })
    }

    /// Wait for the work queued so far.
    pub fn synchronize(&self) -> Result<(), String> {
        // SAFETY: no arguments.
        self.api.check("cuCtxSynchronize", unsafe { (self.api.ctx_synchronize)() })
    }

    /// Compile CUDA C++ `source` with NVRTC (`options`, e.g. `--fmad=false`) and load it.
    pub fn module(&self, source: &str, options: &[&str]) -> Result<Module, String> {
        let api = &self.api;
        let source = CString::new(source).map_err(|e| e.to_string())?;
        let options: Vec<CString> = options.iter().map(|o| CString::new(*o).expect("an option without NUL")).collect();
        let option_ptrs: Vec<*const c_char> = options.iter().map(|o| o.as_ptr()).collect();
        let mut program = std::ptr::null_mut();
        // SAFETY: NUL-terminated strings and out-pointers that live through the calls.
        let ptx = unsafe {
            if (api.nvrtc_create)(&mut program, source.as_ptr(), c"march.cu".as_ptr(), 0, std::ptr::null(), std::ptr::null()) != 0 {
                return Err("nvrtcCreateProgram failed".into());
            }
            let compiled = (api.nvrtc_compile)(program, option_ptrs.len() as c_int, option_ptrs.as_ptr());
            let result = if compiled != 0 {
                let mut size = 0;
                (api.nvrtc_log_size)(program, &mut size);
                let mut log = vec![0u8; size.max(1)];
                (api.nvrtc_log)(program, log.as_mut_ptr().cast());
                Err(format!("NVRTC could not compile the kernels: {}", String::from_utf8_lossy(&log).trim_end_matches('\0')))
            } else {
                let mut size = 0;
                (api.nvrtc_ptx_size)(program, &mut size);
                let mut ptx = vec![0u8; size.max(1)];
                (api.nvrtc_ptx)(program, ptx.as_mut_ptr().cast());
                Ok(ptx)
            };
            (api.nvrtc_destroy)(&mut program);
            result?
        };
        let mut module = std::ptr::null_mut();
        // SAFETY: NUL-terminated PTX.
        api.check("cuModuleLoadData", unsafe { (api.module_load_data)(&mut module, ptx.as_ptr().cast()) })?;
        Ok(Module { cuda: self.clone(), module })
    }

    /// `bytes` of device memory.
    pub fn alloc(&self, bytes: usize) -> Result<DeviceBuffer, String> {
        let mut ptr = 0;
        // SAFETY: an out-pointer to a local.
        self.api.check(&format!("cuMemAlloc({bytes} bytes)"), unsafe { (self.api.mem_alloc)(&mut ptr, bytes.max(1)) })?;
        Ok(DeviceBuffer { cuda: self.clone(), ptr, bytes })
    }

}

/// Device memory, freed on drop.
pub struct DeviceBuffer {
    cuda: Cuda,
    ptr: DevicePtr,
    bytes: usize,
}

impl super::Buffer for DeviceBuffer {
    fn ptr(&self) -> DevicePtr {
        self.ptr
    }

    fn write<T: Copy>(&self, data: &[T]) -> Result<(), String> {
        let bytes = std::mem::size_of_val(data);
        assert!(bytes <= self.bytes, "{bytes} bytes into a buffer of {}", self.bytes);
        // SAFETY: `bytes` fit both the slice and the buffer.
        self.cuda.api.check("cuMemcpyHtoD", unsafe { (self.cuda.api.memcpy_htod)(self.ptr, data.as_ptr().cast(), bytes) })
    }

    fn read<T: Copy>(&self, out: &mut [T]) -> Result<(), String> {
        let bytes = std::mem::size_of_val(out);
        assert!(bytes <= self.bytes, "{bytes} bytes out of a buffer of {}", self.bytes);
        // SAFETY: `bytes` fit both; any bit pattern is a valid value of the plain types read.
        self.cuda.api.check("cuMemcpyDtoH", unsafe { (self.cuda.api.memcpy_dtoh)(out.as_mut_ptr().cast(), self.ptr, bytes) })
    }
}

impl Drop for DeviceBuffer {
    fn drop(&mut self) {
        // SAFETY: allocated by cuMemAlloc and not freed before.
        unsafe { (self.cuda.api.mem_free)(self.ptr) };
    }
}

/// Compiled kernels.
pub struct Module {
    cuda: Cuda,
    module: Handle,
}

impl Module {
    /// Launch kernel `name` over `threads` threads (blocks of 128) with `args`, on the default
    /// stream (asynchronously).
    pub fn launch(&self, name: &str, threads: usize, args: &[Arg]) -> Result<(), String> {
        let api = &self.cuda.api;
        let mut function = std::ptr::null_mut();
        let cname = CString::new(name).map_err(|e| e.to_string())?;
        // SAFETY: a loaded module and a NUL-terminated name.
        api.check(&format!("kernel {name}"), unsafe { (api.module_get_function)(&mut function, self.module, cname.as_ptr()) })?;
        let mut values = args.to_vec();
        let mut params = super::parameters(&mut values);
        let blocks = threads.div_ceil(BLOCK).max(1) as c_uint;
        // SAFETY: `params` points at one value per kernel parameter, alive through the call.
        api.check(&format!("launching {name}"), unsafe {
            (api.launch_kernel)(function, blocks, 1, 1, BLOCK as c_uint, 1, 1, 0, std::ptr::null_mut(), params.as_mut_ptr(), std::ptr::null_mut())
        })
    }
}

/// Threads per block.
const BLOCK: usize = 128;
