//! The seam every field kind plugs into: what the run loop, `nerf eval`/`render`, the exporter
//! and the bench ask of a field on burn, whatever its kind ([`TrainedField`] once trained,
//! [`FieldTrainer`] while training). Each kind implements both in its folder; the dispatch from
//! a configuration's [`nerf_core::field::FieldKind`] to a kind is in [`super`] alone. A field
//! that is never trained from a config (an analytic one, say) needs only [`TrainedField`], the
//! renderer's [`Field`] and the compiler's [`CompileField`].

use crate::config::TrainConfig;
use crate::error::Result;
use crate::run_dir::{Checkpoint, RunDir};
use burn::tensor::Device;
use nerf_core::PinholeCamera;
use nerf_core::camera::Pose;
use nerf_core::dataset::SplitData;
use nerf_core::field::Field;
use nerf_bundle::scene::FixedAppearance;
use nerf_export::CompileField;
use nerf_core::render::{RenderOptions, RenderedImage, render_image};
use nerf_core::sample::occupancy::{OccupancyGrid, marching_grid};
use std::borrow::Cow;
use std::convert::Infallible;

/// A trained field on burn (no autodiff).
pub trait TrainedField: std::fmt::Debug + Send + Sync {
    /// The field as the ONNX compiler lowers it (its kind's name, its graphs by role).
    fn lowering(&self) -> Box<dyn CompileField + '_>;
    /// Half the side of the origin-centred cube the field is defined in, for a field defined
    /// there only (always marched); `None` for a field defined everywhere.
    fn bounded(&self) -> Option<f32>;
    /// How points are contracted before the field reads them (`None`: they are not).
    fn contraction(&self) -> Option<nerf_core::sample::Contraction> {
        None
    }
    /// Which per-image appearance code the field renders with (`None`: it has no codes).
    fn appearance(&self) -> Option<&FixedAppearance> {
        None
    }
    /// Render with `fixed` instead (`nerf export --appearance`); an error for a field without
    /// codes, or naming an image that is not one of its training images.
    fn fix_appearance(&mut self, fixed: &FixedAppearance) -> std::result::Result<(), String> {
        Err(no_appearance_codes(fixed))
    }
    /// The field as the shared renderer evaluates it, its networks running on `device`.
    fn evaluator<'a>(&'a self, device: &Device) -> Box<dyn Field<Error = Infallible> + 'a>;
    /// The concrete field, for tools and tests that need its modules.
    fn as_any(&self) -> &dyn std::any::Any;
}

/// [`TrainedField::fix_appearance`]'s error for a field without codes.
pub fn no_appearance_codes(fixed: &FixedAppearance) -> String {
    format!("{fixed}: the field has no appearance codes (it was trained without --appearance)")
}

impl<'f> dyn TrainedField + 'f {
    /// The grid the field is marched through (see [`marching_grid`]): `occupancy`, or for a
    /// bounded field its whole box.
    pub fn marching_grid(&self, occupancy: Option<OccupancyGrid>) -> Option<OccupancyGrid> {
        marching_grid(occupancy, self.bounded(), self.contraction())
    }

    /// Render one view deterministically through the shared renderer (`device` runs the networks).
    pub fn render(
        &self,
        device: &Device,
        occupancy: Option<&OccupancyGrid>,
        camera: &PinholeCamera,
        pose: &Pose,
        options: &RenderOptions,
        progress: &mut dyn FnMut(usize, usize),
    ) -> RenderedImage {
        let grid = match occupancy {
            Some(grid) => Some(Cow::Borrowed(grid)),
            None => self.marching_grid(None).map(Cow::Owned),
        };
        let mut evaluator = self.evaluator(device);
        let Ok(image) = render_image(&mut evaluator.as_mut(), grid.as_deref(), camera, pose, options, progress);
        image
    }
}

/// What the run loop needs of a field's trainer.
pub trait FieldTrainer {
    /// The configuration in force.
    fn config(&self) -> &TrainConfig;
    /// Steps completed.
    fn steps_done(&self) -> usize;
    /// One optimisation step on a fresh random batch, at learning rate `lr` (the run's
    /// schedule, [`TrainConfig::learning_rate`]).
    fn step(&mut self, lr: f64) -> StepStats;
    /// Save a checkpoint of the current state into `run`.
    fn save(&self, run: &RunDir, elapsed_s: f64) -> Result<Checkpoint>;
    /// Restore weights, optimizer, step and RNG from a checkpoint; returns the seconds trained.
    fn resume(&mut self, checkpoint: &Checkpoint) -> Result<f64>;
    /// The field as trained so far, without autodiff.
    fn snapshot(&self) -> Box<dyn TrainedField>;
    /// The occupancy grid, when there is one.
    fn occupancy(&self) -> Option<&OccupancyGrid>;
}

impl<'t> dyn FieldTrainer + 't {
    /// PSNR of the current field on view `index` of `data`, rendered deterministically as
    /// `nerf eval` renders it.
    pub fn view_psnr(&self, data: &SplitData, index: usize) -> f32 {
        let view = &data.views[index];
        let Some(target) = &view.image else { return f32::NAN };
        let field = self.snapshot();
        let image = field.render(&crate::backend::cpu(), self.occupancy(), &view.camera, &view.pose, &self.config().render_options(), &mut |_, _| {});
        nerf_core::render::metrics::psnr(&image.rays.rgb, target)
    }
}

/// Loss and PSNR of one step.
#[derive(Debug, Clone, Copy)]
pub struct StepStats {
    /// The loss (MSE; coarse + fine for hierarchical sampling).
    pub loss: f32,
    /// PSNR of the final output on the batch.
    pub psnr: f32,
    /// Samples the field was evaluated on (forward and backward), all passes together.
    pub samples: usize,
    /// Where the step's time went.
    pub timing: StepTiming,
}

/// Seconds spent in each phase of a step.
#[derive(Debug, Clone, Copy, Default)]
pub struct StepTiming {
    /// Occupancy update (when due), batch, rays, sampling and the forward passes (with the
    /// loss read back).
    pub forward_s: f64,
    /// Backpropagation.
    pub backward_s: f64,
    /// The Adam update.
    pub update_s: f64,
    /// Of all three, the hash grid's share: its forward pass, the scatter of its gradient and
    /// its sparse Adam update (0 for fields without one).
    pub grid_s: f64,
}
