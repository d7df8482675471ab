//! `nerf eval` and `nerf render`: test-time rendering of a trained run through the shared
//! renderer and frame writer (`nerf_core::frames::write`), the same ones `nerf-render` uses.

use crate::error::{Error, Result};
use crate::field::TrainedField;
use crate::run_dir::{RunDir, RunSource};
use crate::config::TrainConfig;
use crate::lpips::{Availability, Lpips};
use nerf_core::PinholeCamera;
use nerf_core::camera::Pose;
use nerf_core::dataset::{Background, CaptureSplit, ScenePlacement};
use crate::train::cameras::CameraCorrections;
use nerf_core::frames::camera_path::CameraPathFile;
use nerf_core::frames::spec::{FrameSpec, FramesReport};
use nerf_core::frames::views::{Images, SplitChoice, split_views};
use nerf_core::frames::write::{FrameOutput, FramePlan, render_frames, render_frames_with};
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
    /// The training cameras' corrections, for runs that refined them.
    pub cameras: Option<CameraCorrections>,
}

impl LoadedRun {
    /// Load the latest checkpoint of `run`.
    pub fn open(run: &Path) -> Result<Self> {
        let run = RunDir::open(run)?;
        let latest = crate::field::load_latest(&run, &crate::backend::cpu())?;
        let camera = run.read_camera()?;
        let source = run.read_source()?;
        Ok(LoadedRun { config: latest.config, model: latest.model, camera, step: latest.state.step, occupancy: latest.occupancy, source, cameras: latest.cameras })
    }

    /// Where the run placed its scene in the field (`None` for older runs: Blender as it is).
    pub fn placement(&self) -> Option<&ScenePlacement> {
        self.source.as_ref().and_then(|s| s.placement.as_ref())
    }

    /// The views of `choice`, poses mapped into the field by the run's recorded transform
    /// (never refitted to this data), images on the run's background as `images` says. A run
    /// that refined its cameras renders its training views from their refined poses.
    pub fn split_views(&self, choice: &SplitChoice, images: Images) -> Result<Vec<FrameSpec>> {
        let mut views = split_views(choice, RunSource::transform_of(self.source.as_ref()), Background::from_white(self.config.white_background), images)?;
        if let (Some(cameras), CaptureSplit::Train) = (&self.cameras, choice.split) {
            for v in &mut views {
                if let Some(pose) = cameras.corrected_by_name(&v.name, &v.pose) {
                    v.pose = pose;
                }
            }
        }
        Ok(views)
    }

    /// The run's orbit: around a capture's cameras, else the reference orbit.
    pub fn orbit(&self, frames: usize) -> Vec<Pose> {
        RunSource::orbit_of(self.source.as_ref(), frames)
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

/// Render a split's views, compare with its images, write PNGs, `<out>/metrics.json` (PSNR,
/// SSIM and LPIPS per view and their means) and the per-view plots (`<out>/psnr_per_view.png`
/// when a view has a finite PSNR, `<out>/lpips_per_view.png` with LPIPS). LPIPS needs its
/// weights (`scripts/setup.sh`) and onnxruntime: without them `metrics.json` says why it was
/// skipped (`lpips_skipped`).
pub fn eval(run: &Path, data: &SplitChoice, limit: Option<usize>, out: &Path, progress: bool) -> Result<EvalReport> {
    let loaded = LoadedRun::open(run)?;
    let mut views = loaded.split_views(data, Images::Required)?;
    views.truncate(limit.unwrap_or(usize::MAX));
    // Before rendering, so that a broken LPIPS install fails at once.
    let mut lpips = match crate::lpips::Lpips::open_default()? {
        Availability::Ready(lpips) => match views.iter().find_map(|v| Lpips::unfit(v.camera.width, v.camera.height)) {
            Some(why) => Err(why),
            None => Ok(lpips),
        },
        Availability::Skipped(why) => Err(why),
    };
    let mut scores = Vec::new();
    let s = &loaded.config.sampling;
    let output = FrameOutput { dir: out.to_path_buf(), depth_range: (s.near, s.far), gif: false, raw: false, progress };
    let report = render_frames(views, &output, |f, p| {
        let image = loaded.render(&f.camera, &f.pose, p);
        if let (Ok(lpips), Some(target)) = (&mut lpips, &f.target) {
            scores.push((f.name.clone(), lpips.distance(&image.rays.rgb, target, image.width, image.height)?));
        }
        Ok::<_, Error>(image)
    })?;
    let mut metrics = report.metrics.ok_or_else(|| Error::invalid(&data.dir, format!("the {} split has no views", data.split)))?;
    match lpips {
        Ok(_) => {
            for m in &mut metrics.per_image {
                m.lpips = scores.iter().find(|(name, _)| *name == m.name).map(|&(_, score)| score);
            }
            metrics = EvalReport::from_images(metrics.per_image);
        }
        Err(why) => {
            eprintln!("note: LPIPS skipped: {why}");
            metrics.lpips_skipped = Some(why);
        }
    }
    metrics.write_json(&out.join(nerf_core::frames::spec::METRICS_FILE))?;
    let title = format!("{} ({} split)", crate::plot::run_label(run), data.split);
    if metrics.per_image.iter().any(|m| m.psnr.is_finite()) {
        crate::plot::write_view_psnr(&title, &metrics.per_image, &out.join(crate::plot::VIEWS_FILE))?;
    }
    if metrics.lpips_mean.is_some() {
        crate::plot::write_view_lpips(&title, &metrics.per_image, &out.join(crate::plot::LPIPS_VIEWS_FILE))?;
    }
    Ok(metrics)
}

/// What `nerf render` renders.
#[derive(Debug, Clone, PartialEq)]
pub enum RenderViews {
    /// The run's orbit (around a capture's cameras, a spiral in front of forward-facing ones,
    /// else the reference orbit): `frames` frames at the training resolution divided by
    /// `downscale`, and `orbit.gif`.
    Orbit {
        /// Frames in the orbit.
        frames: usize,
        /// Divides the training camera's size.
        downscale: u32,
    },
    /// A split's poses (no ground truth needed).
    Split(SplitChoice),
    /// A nerfstudio `camera_path.json` (poses in the capture's coordinates, mapped through the
    /// run's placement): `frame_00000.png`, … and `camera_path.gif`.
    CameraPath {
        /// The file.
        file: PathBuf,
        /// Divides the path's render size.
        downscale: u32,
    },
}

/// Render `views` of `run` into `out`: PNG + depth map per frame (`.npy` with `raw`), the
/// frames of `plan.shard` only, keeping an earlier run's with `plan.skip_existing`; a whole
/// render also writes its GIF (orbits, camera paths).
pub fn render_views(run: &Path, views: &RenderViews, out: &Path, raw: bool, plan: &FramePlan, progress: bool) -> Result<FramesReport> {
    if let RenderViews::Orbit { frames, .. } = views {
        nerf_core::io::limits::check_count(*frames, nerf_core::io::limits::MAX_FRAMES, "frames", nerf_core::io::limits::Origin::Option("--frames"))?;
    }
    let loaded = LoadedRun::open(run)?;
    let (specs, gif) = match views {
        RenderViews::Orbit { frames, downscale } => {
            let k = shrink(loaded.camera, *downscale, "training camera")?;
            (FrameSpec::orbit(&k, &loaded.orbit(*frames)), Some(plan.gif.clone()))
        }
        RenderViews::Split(choice) => (loaded.split_views(choice, Images::Skip)?, None),
        RenderViews::CameraPath { file, downscale } => {
            let path = CameraPathFile::read(file)?;
            let transform = RunSource::transform_of(loaded.source.as_ref());
            let mut specs = path.frames(&transform, loaded.camera.pixel_center);
            for f in &mut specs {
                f.camera = shrink(f.camera, *downscale, "camera path's render size")?;
            }
            (specs, Some(path.gif()))
        }
    };
    let s = &loaded.config.sampling;
    let output = FrameOutput { dir: out.to_path_buf(), depth_range: (s.near, s.far), gif: gif.is_some(), raw, progress };
    let plan = FramePlan { gif: gif.unwrap_or_else(|| plan.gif.clone()), ..plan.clone() };
    render_frames_with(specs, &output, &plan, |f, p| Ok::<_, Error>(loaded.render(&f.camera, &f.pose, p)))
}

/// `k` at its size divided by `downscale` (an error when nothing would be left of `what`).
fn shrink(k: PinholeCamera, downscale: u32, what: &str) -> Result<PinholeCamera> {
    let (width, height) = (k.width.checked_div(downscale).unwrap_or(0), k.height.checked_div(downscale).unwrap_or(0));
    if width == 0 || height == 0 {
        return Err(Error::Config(format!("--downscale {downscale} leaves nothing of the {}×{} {what}", k.width, k.height)));
    }
    Ok(k.resized(width, height))
}

/// Render a split's poses (no ground truth needed) to PNGs and depth maps (and `.npy` with `raw`).
pub fn render_split(run: &Path, data: &SplitChoice, out: &Path, raw: bool, progress: bool) -> Result<usize> {
    Ok(render_views(run, &RenderViews::Split(data.clone()), out, raw, &FramePlan::default(), progress)?.frames)
}

/// Render the run's orbit (around a capture's cameras, a spiral in front of forward-facing
/// ones, else the reference orbit) at the training resolution divided by `downscale`:
/// `frame_NNN.png`, depth maps (`.npy` with `raw`) and `orbit.gif`.
pub fn render_orbit(run: &Path, frames: usize, downscale: u32, out: &Path, raw: bool, progress: bool) -> Result<PathBuf> {
    let report = render_views(run, &RenderViews::Orbit { frames, downscale }, out, raw, &FramePlan::default(), progress)?;
    report.gif.ok_or_else(|| Error::Config("an orbit needs at least one frame".into()))
}
