//! The coarse and fine networks trained together.

use super::NerfMlp;
use burn::module::Module;
use burn::tensor::Device;
use nerf_core::field::mlp::NetworkSpec;

/// The coarse and fine networks trained together (one optimizer, one checkpoint).
#[derive(Module, Debug)]
pub struct NerfModel {
    /// Evaluated on the stratified samples.
    pub coarse: NerfMlp,
    /// Evaluated on all samples; absent when no fine samples are drawn.
    pub fine: Option<NerfMlp>,
}

impl NerfModel {
    /// Fresh coarse (and, with `fine`, fine) networks of shape `spec`.
    pub fn new(spec: &NetworkSpec, fine: bool, device: &Device) -> Self {
        NerfModel { coarse: NerfMlp::new(spec, device), fine: fine.then(|| NerfMlp::new(spec, device)) }
    }

    /// The network that renders the final image: the fine one if there is one.
    pub fn last(&self) -> &NerfMlp {
        self.fine.as_ref().unwrap_or(&self.coarse)
    }

    /// The device the coarse network's weights live on.
    pub fn coarse_device(&self) -> Device {
        self.coarse.devices().into_iter().next().unwrap_or_else(crate::backend::cpu)
    }
}
