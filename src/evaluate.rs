//! `nerf eval` and `nerf render`: test-time rendering of a trained run through the shared
//! renderer and frame writer (`nerf_core::io::frames`), the same ones `nerf-render` uses.

use crate::error::{Error, Result};
use crate::field::TrainedField;
use crate::run_dir::{RunDir, RunSource};
use crate::config::TrainConfig;
use nerf_core::PinholeCamera;
use nerf_core::camera::Pose;
use nerf_core::dataset::{Background, ScenePlacement};
use nerf_core::io::frames::{FrameOutput, FrameSpec, FramesReport, render_frames};
use nerf_core::io::views::{Images, SplitChoice, orbit_poses, split_views};
use nerf_core::render::metrics::EvalReport;
use nerf_core::sample::occupancy::OccupancyGrid;
use nerf_core::render::RenderedImage;
use std::path::{Path, PathBuf};

/// A trained run loaded for rendering.
pub struct LoadedRun {
    /// Its configuration.
    pub config: TrainConfig,
    /// Its networks (no autodiff).
    pub model: Box<dyn TrainedField>,
    /// The training camera.
    pub camera: PinholeCamera,
    /// Steps it was trained for.
    pub step: usize,
    /// Where the scene is, for runs trained with empty-space skipping.
    pub occupancy: Option<OccupancyGrid>,
    /// Where its data came from and how the scene is placed in the field (`None` for older
    /// runs: Blender as it is).
    pub source: Option<RunSource>,
}

impl LoadedRun {
    /// Load the latest checkpoint of `run`.
    pub fn open(run: &Path) -> Result<Self> {
        let run = RunDir::open(run)?;
        let latest = crate::field::load_latest(&run, &crate::backend::cpu())?;
        let camera = run.read_camera()?;
        let source = run.read_source()?;
        Ok(LoadedRun { config: latest.config, model: latest.model, camera, step: latest.state.step, occupancy: latest.occupancy, source })
    }

    /// Where the run placed its scene in the field (`None` for older runs: Blender as it is).
    pub fn placement(&self) -> Option<&ScenePlacement> {
        self.source.as_ref().and_then(|s| s.placement.as_ref())
    }

    /// The views of `choice`, poses mapped into the field by the run's recorded transform
    /// (never refitted to this data), images on the run's background as `images` says.
    pub fn split_views(&self, choice: &SplitChoice, images: Images) -> Result<Vec<FrameSpec>> {
        let transform = self.placement().map_or_else(nerf_core::SceneTransform::identity, |p| p.transform);
        Ok(split_views(choice, transform, Background::from_white(self.config.white_background), images)?)
    }

    /// The run's orbit: around a capture's cameras, else the reference orbit.
    pub fn orbit(&self, frames: usize) -> Vec<Pose> {
        orbit_poses(self.placement().and_then(|p| p.orbit.as_ref()), frames)
    }

    /// Render one view deterministically (test-time sampling, skipping empty space when the
    /// run has a grid), reporting `progress(done, total)` pixels.
    pub fn render(&self, camera: &PinholeCamera, pose: &Pose, progress: &mut dyn FnMut(usize, usize)) -> RenderedImage {
        self.model.render(&crate::backend::cpu(), self.occupancy.as_ref(), camera, pose, &self.config.render_options(), progress)
    }

    /// Render `frames` into `out` (PNG + depth map each, `.npy` with `raw`; metrics when they
    /// have ground truth).
    pub fn render_frames(&self, frames: Vec<FrameSpec>, out: &Path, gif: bool, raw: bool, progress: bool) -> Result<FramesReport> {
        let s = &self.config.sampling;
        let output = FrameOutput { dir: out.to_path_buf(), depth_range: (s.near, s.far), gif, raw, progress };
        render_frames(frames, &output, |f, p| Ok::<_, Error>(self.render(&f.camera, &f.pose, p)))
    }
}

/// Render a split's views, compare with its images, write PNGs, `<out>/metrics.json` and the
/// per-view PSNR plot (`<out>/psnr_per_view.png`, when a view has a finite PSNR).
pub fn eval(run: &Path, data: &SplitChoice, limit: Option<usize>, out: &Path, progress: bool) -> Result<EvalReport> {
    let loaded = LoadedRun::open(run)?;
    let mut views = loaded.split_views(data, Images::Required)?;
    views.truncate(limit.unwrap_or(usize::MAX));
    let report = loaded.render_frames(views, out, false, false, progress)?;
    let metrics = report.metrics.ok_or_else(|| Error::invalid(&data.dir, format!("the {} split has no views", data.split)))?;
    if metrics.per_image.iter().any(|m| m.psnr.is_finite()) {
        let title = format!("{} ({} split)", crate::plot::run_label(run), data.split);
        crate::plot::write_view_psnr(&title, &metrics.per_image, &out.join(crate::plot::VIEWS_FILE))?;
    }
    Ok(metrics)
}

/// Render a split's poses (no ground truth needed) to PNGs and depth maps (and `.npy` with `raw`).
pub fn render_split(run: &Path, data: &SplitChoice, out: &Path, raw: bool, progress: bool) -> Result<usize> {
    let loaded = LoadedRun::open(run)?;
    let views = loaded.split_views(data, Images::Skip)?;
    Ok(loaded.render_frames(views, out, false, raw, progress)?.frames)
}

/// Render the run's orbit (around a capture's cameras, a spiral in front of forward-facing
/// ones, else the reference orbit) at the training resolution divided by `downscale`:
/// `frame_NNN.png`, depth maps (`.npy` with `raw`) and `orbit.gif`.
pub fn render_orbit(run: &Path, frames: usize, downscale: u32, out: &Path, raw: bool, progress: bool) -> Result<PathBuf> {
    nerf_core::io::limits::check_count(frames, nerf_core::io::limits::MAX_FRAMES, "frames", nerf_core::io::limits::Origin::Option("--frames"))?;
    let loaded = LoadedRun::open(run)?;
    let k = loaded.camera;
    let (width, height) = (k.width.checked_div(downscale).unwrap_or(0), k.height.checked_div(downscale).unwrap_or(0));
    if width == 0 || height == 0 {
        return Err(Error::Config(format!("--downscale {downscale} leaves nothing of the {}×{} training camera", k.width, k.height)));
    }
    let specs = FrameSpec::orbit(&k.resized(width, height), &loaded.orbit(frames));
    let report = loaded.render_frames(specs, out, true, raw, progress)?;
    report.gif.ok_or_else(|| Error::Config("an orbit needs at least one frame".into()))
}
