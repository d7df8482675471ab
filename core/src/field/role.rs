//! The roles graphs play in a bundle, whatever the field's kind.

use serde::{Deserialize, Serialize};

use super::eval::Stage;

/// What one graph of a bundle evaluates: the whole field, or one stage of the hierarchical
/// sampler. Bundle files are named after it (`field.onnx`, `coarse.onnx`, `fine.onnx`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Role {
    /// The whole field, whatever the stage.
    Field,
    /// The coarse network, on the stratified samples.
    Coarse,
    /// The fine network, on coarse ∪ importance samples.
    Fine,
}

impl Role {
    /// The role as written in `scene.json` and in file names.
    pub fn name(self) -> &'static str {
        match self {
            Role::Field => "field",
            Role::Coarse => "coarse",
            Role::Fine => "fine",
        }
    }

    /// Whether this graph answers for `stage`.
    pub fn serves(self, stage: Stage) -> bool {
        match self {
            Role::Field => true,
            Role::Coarse => stage == Stage::Coarse,
            Role::Fine => stage == Stage::Fine,
        }
    }
}
