//! A trained field of either kind, as the run directory, `nerf eval`/`render` and the exporter
//! see it.

use super::{NerfModel, NgpField};
use crate::inference::{BurnField, BurnNgpField};
use burn::tensor::Device;
use nerf_core::PinholeCamera;
use nerf_core::camera::Pose;
use nerf_core::field::{FieldKind, PlainField};
use nerf_core::render::{RenderOptions, RenderedImage, render_image};
use nerf_core::sample::occupancy::{OccupancyGrid, marching_grid};

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

    /// The field as plain data, for the ONNX compiler.
    pub fn to_plain(&self) -> PlainField {
        match self {
            TrainedField::Mlp(model) => PlainField::Mlp { coarse: model.coarse.to_plain(), fine: model.fine.as_ref().map(|f| f.to_plain()) },
            TrainedField::Ngp(field) => PlainField::Ngp(field.to_plain()),
        }
    }

    /// The grid the field is marched through (see [`marching_grid`]): `occupancy`, or for a
    /// bounded kind its whole box.
    pub fn marching_grid(&self, occupancy: Option<OccupancyGrid>) -> Option<OccupancyGrid> {
        let bounded = match self {
            TrainedField::Mlp(_) => None,
            TrainedField::Ngp(field) => Some(field.box_half_size()),
        };
        marching_grid(occupancy, bounded)
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
        let grid = match occupancy {
            Some(grid) => Some(std::borrow::Cow::Borrowed(grid)),
            None => self.marching_grid(None).map(std::borrow::Cow::Owned),
        };
        let grid = grid.as_deref();
        let Ok(image) = match self {
            TrainedField::Mlp(model) => render_image(&mut BurnField { model, device }, grid, camera, pose, options, progress),
            TrainedField::Ngp(field) => render_image(&mut BurnNgpField { field, device }, grid, camera, pose, options, progress),
        };
        image
    }
}
