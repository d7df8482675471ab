//! `nerf eval` and `nerf render`: test-time rendering of a trained run through the shared
//! renderer and frame writer (`nerf_core::frames`), the same ones `nerf-render` uses.

use crate::error::{Error, Result};
use crate::field::TrainedField;
use crate::run_dir::RunDir;
use crate::train::TrainConfig;
use nerf_core::PinholeCamera;
use nerf_core::camera::Pose;
use nerf_core::dataset::{Split, load_split};
use nerf_core::frames::{FrameOutput, FrameSpec, FramesReport, render_frames};
use nerf_core::metrics::EvalReport;
use nerf_core::occupancy::OccupancyGrid;
use nerf_core::render::RenderedImage;
use std::path::{Path, PathBuf};

/// A trained run loaded for rendering.
pub struct LoadedRun {
    /// Its configuration.
    pub config: TrainConfig,
    /// Its networks (no autodiff).
    pub model: TrainedField,
    /// The training camera.
    pub camera: PinholeCamera,
    /// Steps it was trained for.
    pub step: usize,
    /// Where the scene is, for runs trained with empty-space skipping.
    pub occupancy: Option<OccupancyGrid>,
}

impl LoadedRun {
    /// Load the latest checkpoint of `run`.
    pub fn open(run: &Path) -> Result<Self> {
        let run = RunDir::open(run)?;
        let latest = run.load_latest(&crate::backend::cpu())?;
        let camera = run.read_camera()?;
        Ok(LoadedRun { config: latest.config, model: latest.model, camera, step: latest.state.step, occupancy: latest.occupancy })
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

/// Render a split's views, compare with its images, write PNGs and `<out>/metrics.json`.
pub fn eval(run: &Path, data: &Path, split: Split, downscale: u32, limit: Option<usize>, out: &Path, progress: bool) -> Result<EvalReport> {
    let loaded = LoadedRun::open(run)?;
    let mut scene = load_split(data, split, downscale, true)?;
    scene.views.truncate(limit.unwrap_or(usize::MAX));
    let report = loaded.render_frames(FrameSpec::from_split(scene), out, false, false, progress)?;
    report.metrics.ok_or_else(|| Error::invalid(data, format!("the {} split has no views", split.name())))
}

/// Render a split's poses (no ground truth needed) to PNGs and depth maps (and `.npy` with `raw`).
pub fn render_split(run: &Path, data: &Path, split: Split, downscale: u32, out: &Path, raw: bool, progress: bool) -> Result<usize> {
    let loaded = LoadedRun::open(run)?;
    let scene = load_split(data, split, downscale, false)?;
    Ok(loaded.render_frames(FrameSpec::from_split(scene), out, false, raw, progress)?.frames)
}

/// Render the reference 360° orbit: `frame_NNN.png`, depth maps (`.npy` with `raw`) and `orbit.gif`.
pub fn render_orbit(run: &Path, frames: usize, out: &Path, raw: bool, progress: bool) -> Result<PathBuf> {
    nerf_core::limits::check_count(frames, nerf_core::limits::MAX_FRAMES, "frames", nerf_core::limits::Origin::Option("--frames"))?;
    let loaded = LoadedRun::open(run)?;
    let specs = FrameSpec::orbit(&loaded.camera, &Pose::orbit(frames));
    let report = loaded.render_frames(specs, out, true, raw, progress)?;
    report.gif.ok_or_else(|| Error::Config("an orbit needs at least one frame".into()))
}
