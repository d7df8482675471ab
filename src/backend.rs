//! Which burn device runs the work.

use burn::tensor::Device;

/// The CPU device (burn's `flex` backend: gemm + rayon + SIMD).
pub fn cpu() -> Device {
    Device::flex()
}

/// The CPU device with autodiff, for training.
pub fn cpu_autodiff() -> Device {
    Device::flex().autodiff()
}

/// Keep freed tensor buffers in the process instead of returning them to the kernel.
///
/// glibc serves allocations above 32 MiB with a fresh `mmap` and unmaps them on free, so every
/// large activation of every step page-faults its memory in again. Turning `mmap` off for the
/// heap and never trimming it lets those buffers be reused. Call once, early in `main`.
pub fn tune_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator parameters; called before other threads start.
    unsafe {
        libc::mallopt(libc::M_MMAP_MAX, 0);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}
