//! Evaluating a trained burn model through the shared renderer ([`nerf_core::render`]).

use crate::field::{NerfMlp, NerfModel, NgpField};
use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::field::mlp::EncodingSpec;
use nerf_core::field::{Field, FieldOutput, Stage};

/// `[n]` 3-vectors as an `[n, 3]` tensor.
pub fn vec3_tensor(v: &[[f32; 3]], device: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(v.as_flattened().to_vec(), [v.len(), 3]), device)
}

/// `[n]` 3-vectors, encoded as `spec` says, as an `[n, spec.output_dim()]` tensor.
pub fn encoded_tensor(spec: &EncodingSpec, v: &[[f32; 3]], device: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(spec.encode_all(v), [v.len(), spec.output_dim()]), device)
}

/// An `[n, 3]` tensor as `[n]` 3-vectors.
pub fn tensor_vec3(t: Tensor<2>) -> Vec<[f32; 3]> {
    let flat = t.into_data().try_to_vec::<f32>().expect("f32 tensor");
    flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// A burn model as a [`Field`] (no autodiff).
pub struct BurnField<'a> {
    /// The networks.
    pub model: &'a NerfModel,
    /// Where to run them.
    pub device: Device,
}

impl BurnField<'_> {
    fn network(&self, stage: Stage) -> &NerfMlp {
        match stage {
            Stage::Coarse => &self.model.coarse,
            Stage::Fine => self.model.last(),
        }
    }
}

impl Field for BurnField<'_> {
    type Error = std::convert::Infallible;

    fn evaluate(&mut self, stage: Stage, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> Result<FieldOutput, Self::Error> {
        let net = self.network(stage);
        let spec = net.spec();
        let (rgb, sigma) = net.forward_encoded(
            encoded_tensor(&spec.position_encoding, points, &self.device),
            encoded_tensor(&spec.direction_encoding, viewdirs, &self.device),
            1,
        );
        Ok(FieldOutput { rgb: tensor_vec3(rgb), sigma: sigma.into_data().try_to_vec::<f32>().expect("f32 tensor") })
    }
}

/// A hash-grid field as a [`Field`] (no autodiff; one network, whatever the stage).
pub struct BurnNgpField<'a> {
    /// The field.
    pub field: &'a NgpField,
    /// Where its MLPs run.
    pub device: Device,
}

impl Field for BurnNgpField<'_> {
    type Error = std::convert::Infallible;

    fn evaluate(&mut self, _: Stage, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> Result<FieldOutput, Self::Error> {
        if points.is_empty() {
            return Ok(FieldOutput::default());
        }
        let (rgb, sigma) = self.field.forward(points, viewdirs, &self.device);
        Ok(FieldOutput { rgb: tensor_vec3(rgb), sigma: sigma.into_data().try_to_vec::<f32>().expect("f32 tensor") })
    }
}
