//! The instant-ngp field on burn: the hash grid (plain Rust, [`nerf_core::field::ngp`]) and two
//! tiny MLPs, the sparse Adam of its table, its checkpoint parts, its trainer, and its place at
//! the field seam ([`crate::field::seam`]).

pub mod adam;
pub mod appearance;
mod field;
pub mod fused;
pub mod state;
pub mod throughput;
mod trainer;

pub use field::{NgpField, NgpMlps, trunc_exp};
pub use state::GRID_FILE;
pub use trainer::NgpTrainer;

use crate::config::TrainConfig;
use crate::error::{Error, Result};
use crate::field::seam::{FieldTrainer, TrainedField};
use crate::run_dir::Checkpoint;
use burn::tensor::Device;
use nerf_core::dataset::SplitData;
use nerf_core::field::{Field, FieldOutput, Stage};
use nerf_export::CompileField;
use appearance::{Appearance, FixedAppearance, RenderedAppearance};

impl TrainedField for NgpField {
    fn lowering(&self) -> Box<dyn CompileField + '_> {
        Box::new(self.to_plain())
    }

    fn bounded(&self) -> Option<f32> {
        Some(self.spec.bound.enclosing_half_size())
    }

    fn contraction(&self) -> Option<nerf_core::sample::Contraction> {
        self.spec.bound.contraction
    }

    fn appearance(&self) -> Option<&FixedAppearance> {
        self.appearance.as_ref().map(|a| a.fixed())
    }

    fn fix_appearance(&mut self, fixed: &FixedAppearance) -> std::result::Result<(), String> {
        let Some(a) = &self.appearance else { return Err(crate::field::seam::no_appearance_codes(fixed)) };
        self.appearance = Some(a.refixed(fixed.clone())?);
        Ok(())
    }

    fn evaluator<'a>(&'a self, device: &Device) -> Box<dyn Field<Error = std::convert::Infallible> + 'a> {
        Box::new(NgpEvaluator { field: self, device: device.clone() })
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

/// The field of `config`, table and MLPs from `checkpoint`, on `device`.
pub fn load(config: &TrainConfig, checkpoint: &Checkpoint, device: &Device) -> Result<Box<dyn TrainedField>> {
    let mut field = NgpField::new(config.shapes.ngp, config.seed, device).map_err(Error::Config)?;
    checkpoint.load_model(&mut field.mlps)?;
    field.grid = state::load_grid(checkpoint, &config.shapes.ngp.grid, Default::default())?.0;
    if config.appearance {
        let codes = Appearance::read(&checkpoint.dir, config.shapes.ngp.color_hidden)?;
        field.appearance = Some(RenderedAppearance::new(codes, FixedAppearance::Mean).expect("the mean always exists"));
    }
    Ok(Box::new(field))
}

/// A fresh trainer of `config`'s field on `train`.
pub fn trainer(config: TrainConfig, train: SplitData) -> Result<Box<dyn FieldTrainer>> {
    Ok(Box::new(NgpTrainer::new(config, train, burn::tensor::Device::flex().autodiff())?))
}

/// A hash-grid field as a [`Field`] (no autodiff; one network, whatever the stage).
pub struct NgpEvaluator<'a> {
    /// The field.
    pub field: &'a NgpField,
    /// Where its MLPs run.
    pub device: Device,
}

impl Field for NgpEvaluator<'_> {
    type Error = std::convert::Infallible;

    fn evaluate(&mut self, _: Stage, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> std::result::Result<FieldOutput, Self::Error> {
        if points.is_empty() {
            return Ok(FieldOutput::default());
        }
        let (rgb, sigma) = self.field.forward(points, viewdirs);
        Ok(FieldOutput { rgb, sigma })
    }
}
