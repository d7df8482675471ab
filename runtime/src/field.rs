//! A bundle's graphs as a [`Field`] for the shared renderer (`nerf_core::render`): each stage
//! goes to the graph whose role serves it.

use crate::error::{Result, RuntimeError};
use crate::network::OrtNetwork;
use nerf_core::field::{Field, FieldOutput, Role, Stage};

/// A scene's graphs in onnxruntime, by role.
pub struct OrtField {
    /// The graphs, in the bundle's role order.
    pub graphs: Vec<(Role, OrtNetwork)>,
}

impl OrtField {
    /// The graph that answers for `stage`.
    pub fn graph(&mut self, stage: Stage) -> Option<&mut OrtNetwork> {
        self.graphs.iter_mut().find(|(role, _)| role.serves(stage)).map(|(_, net)| net)
    }
}

impl Field for OrtField {
    type Error = RuntimeError;

    fn evaluate(&mut self, stage: Stage, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> Result<FieldOutput> {
        let net = self.graph(stage).ok_or_else(|| RuntimeError::Other(format!("the renderer asked for {stage:?} samples but no graph of the bundle serves them")))?;
        net.run(points, viewdirs)
    }
}
