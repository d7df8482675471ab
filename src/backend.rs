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
