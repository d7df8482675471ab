//! Which burn device runs the work.

use burn::tensor::Device;

/// The CPU device (burn's `flex` backend: gemm + rayon + SIMD).
pub fn cpu() -> Device {
    Device::flex()
}

/// The CPU device with autodiff, for training.
///
/// Gradient checkpointing is on: burn's ReLU keeps its *input* for the backward pass while the
/// next layer's matmul keeps the ReLU's *output*, two activations per layer. With checkpointing only the matmul outputs are kept, and the bias add and ReLU
/// are recomputed in the backward pass (two cheap elementwise passes per layer).
pub fn cpu_autodiff() -> Device {
    Device::flex().autodiff().gradient_checkpointing()
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
        // -1 is SIZE_MAX once glibc widens it: never trim (i32::MAX still trims a top chunk
        // above 2 GiB, which the paper step's activations exceed).
        libc::mallopt(libc::M_TRIM_THRESHOLD, -1);
    }
}
