//! The coarse and fine graphs as a [`Field`] for the shared renderer (`nerf_core::render`).

use crate::error::{Result, RuntimeError};
use crate::network::OrtNetwork;
use nerf_core::field::{Field, FieldOutput, Stage};

/// A scene's networks in onnxruntime.
pub struct OrtField {
    /// The coarse network.
    pub coarse: OrtNetwork,
    /// The fine network (bundles with `n_fine > 0`).
    pub fine: Option<OrtNetwork>,
}

impl Field for OrtField {
    type Error = RuntimeError;

    fn evaluate(&mut self, stage: Stage, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> Result<FieldOutput> {
        let net = match (stage, self.fine.as_mut()) {
            (Stage::Fine, Some(fine)) => fine,
            (Stage::Fine, None) => return Err(RuntimeError::Other("the renderer asked for fine samples but the bundle has no fine network".into())),
            (Stage::Coarse, _) => &mut self.coarse,
        };
        net.run(points, viewdirs)
    }
}
