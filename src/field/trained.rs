//! A trained field of either kind, as the run directory, `nerf eval`/`render` and the exporter
//! see it.

use super::{NerfModel, NgpField};
use crate::inference::{BurnField, BurnNgpField};
use burn::tensor::Device;
use nerf_core::PinholeCamera;
use nerf_core::camera::Pose;
use nerf_core::field::FieldKind;
use nerf_core::sample::occupancy::OccupancyGrid;
use nerf_core::render::{RenderOptions, RenderedImage, render_image};

/// The networks of a run, by [`FieldKind`].
#[derive(Debug)]
pub enum TrainedField {
    /// Coarse and fine NeRF MLPs.
    Mlp(NerfModel),
    /// Hash grid and tiny MLPs.
    Ngp(NgpField),
}

impl TrainedField {
    /// Its kind.
    pub fn kind(&self) -> FieldKind {
        match self {
            TrainedField::Mlp(_) => FieldKind::Mlp,
            TrainedField::Ngp(_) => FieldKind::Ngp,
        }
    }

    /// The NeRF MLPs, if that is the kind.
    pub fn as_mlp(&self) -> Option<&NerfModel> {
        match self {
            TrainedField::Mlp(model) => Some(model),
            TrainedField::Ngp(_) => None,
        }
    }

    /// Render one view deterministically through the shared renderer (`device` runs the MLPs).
    pub fn render(
        &self,
        device: &Device,
        occupancy: Option<&OccupancyGrid>,
        camera: &PinholeCamera,
        pose: &Pose,
        options: &RenderOptions,
        progress: &mut dyn FnMut(usize, usize),
    ) -> RenderedImage {
        let device = device.clone();
        let Ok(image) = match self {
            TrainedField::Mlp(model) => render_image(&mut BurnField { model, device }, occupancy, camera, pose, options, progress),
            TrainedField::Ngp(field) => {
                // The field is only defined inside its box: without a grid, march the whole box.
                let whole_box = field.whole_box();
                let grid = occupancy.unwrap_or(&whole_box);
                render_image(&mut BurnNgpField { field, device }, Some(grid), camera, pose, options, progress)
            }
        };
        image
    }
}
