//! The NeRF MLPs on burn (nerf-pytorch's `NeRF`): coarse and fine networks with positional
//! encoding, their differentiable volume rendering and trainer, checkpoint parts, and their
//! place at the field seam ([`crate::field::seam`]).

pub mod bench;
mod encoding;
mod model;
mod network;
mod trainer;
mod volume;

pub use encoding::encode;
pub use model::NerfModel;
pub use network::NerfMlp;
pub use trainer::Trainer;
pub use volume::{VolumeOutput, composite, deltas_tensor};

use crate::config::TrainConfig;
use crate::error::Result;
use crate::field::seam::{FieldTrainer, TrainedField};
use crate::inference::tensor_vec3;
use crate::run_dir::Checkpoint;
use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::dataset::SplitData;
use nerf_core::field::mlp::EncodingSpec;
use nerf_core::field::mlp::PlainMlp;
use nerf_core::field::{Field, FieldOutput, Stage};
use nerf_export::CompileField;

/// `[n]` 3-vectors, encoded as `spec` says, as an `[n, spec.output_dim()]` tensor.
pub fn encoded_tensor(spec: &EncodingSpec, v: &[[f32; 3]], device: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(spec.encode_all(v), [v.len(), spec.output_dim()]), device)
}

impl TrainedField for NerfModel {
    fn lowering(&self) -> Box<dyn CompileField + '_> {
        Box::new(PlainMlp { coarse: self.coarse.to_plain(), fine: self.fine.as_ref().map(|f| f.to_plain()) })
    }

    fn bounded(&self) -> Option<f32> {
        None
    }

    fn evaluator<'a>(&'a self, device: &Device) -> Box<dyn Field<Error = std::convert::Infallible> + 'a> {
        Box::new(MlpEvaluator { model: self, device: device.clone() })
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

/// The networks of `config`, weights from `checkpoint`, on `device`.
pub fn load(config: &TrainConfig, checkpoint: &Checkpoint, device: &Device) -> Result<Box<dyn TrainedField>> {
    let mut model = NerfModel::new(&config.shapes.network, config.sampling.n_fine > 0, device);
    checkpoint.load_model(&mut model)?;
    Ok(Box::new(model))
}

/// A fresh trainer of `config`'s networks on `train`.
pub fn trainer(config: TrainConfig, train: SplitData) -> Result<Box<dyn FieldTrainer>> {
    Ok(Box::new(Trainer::new(config, train, crate::backend::cpu_autodiff())?))
}

/// A burn model as a [`Field`] (no autodiff).
pub struct MlpEvaluator<'a> {
    /// The networks.
    pub model: &'a NerfModel,
    /// Where to run them.
    pub device: Device,
}

impl MlpEvaluator<'_> {
    fn network(&self, stage: Stage) -> &NerfMlp {
        match stage {
            Stage::Coarse => &self.model.coarse,
            Stage::Fine => self.model.last(),
        }
    }
}

impl Field for MlpEvaluator<'_> {
    type Error = std::convert::Infallible;

    fn evaluate(&mut self, stage: Stage, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> std::result::Result<FieldOutput, Self::Error> {
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
