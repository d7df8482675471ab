//! `nerf eval` and `nerf render`: test-time rendering of a trained run through the shared
//! renderer, writing PNGs, depth maps, GIFs and metrics.

use crate::field::NerfModel;
use crate::inference::BurnField;
use crate::train::{TrainConfig, load_model};
use indicatif::{ProgressBar, ProgressStyle};
use nerf_core::camera::{Intrinsics, Pose};
use nerf_core::dataset::{Split, load_split};
use nerf_core::imageio::{depth_to_rgb, save_gif, save_png};
use nerf_core::metrics::{EvalReport, ImageMetrics, psnr, ssim};
use nerf_core::occupancy::{OccupancyGrid, render_image_with};
use nerf_core::render::RenderedImage;
use std::path::{Path, PathBuf};

/// `<run>/camera.json`: the training camera, so orbits render at the training resolution.
pub fn camera_path(run: &Path) -> PathBuf {
    run.join("camera.json")
}

/// A trained run loaded for rendering.
pub struct LoadedRun {
    /// Its configuration.
    pub config: TrainConfig,
    /// Its networks (no autodiff).
    pub model: NerfModel,
    /// The training camera.
    pub camera: Intrinsics,
    /// Steps it was trained for.
    pub step: usize,
    /// Where the scene is, for runs trained with empty-space skipping.
    pub occupancy: Option<OccupancyGrid>,
}

impl LoadedRun {
    /// Load the latest checkpoint of `run`.
    pub fn open(run: &Path) -> Result<Self, String> {
        let device = crate::backend::cpu();
        let (config, model, state, occupancy) = load_model(run, &device)?;
        let path = camera_path(run);
        let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        let camera = serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(LoadedRun { config, model, camera, step: state.step, occupancy })
    }

    /// Render one view deterministically, with a progress bar when `bar` is given.
    pub fn render(&self, intrinsics: &Intrinsics, pose: &Pose, bar: &ProgressBar) -> RenderedImage {
        let field = BurnField { model: &self.model, device: crate::backend::cpu() };
        let options = crate::train::render_options(&self.config);
        bar.set_length(intrinsics.num_pixels() as u64);
        bar.set_position(0);
        let Ok(image) = render_image_with(field, self.occupancy.as_ref(), intrinsics, pose, &options, &mut |done, _| {
            bar.set_position(done as u64)
        });
        image
    }

    /// Write `<out>/<name>.png` and `<out>/<name>_depth.png`.
    pub fn save(&self, image: &RenderedImage, out: &Path, name: &str) -> Result<(), String> {
        let (w, h) = (image.width, image.height);
        save_png(&out.join(format!("{name}.png")), w, h, &image.rays.rgb).map_err(|e| e.to_string())?;
        let s = &self.config.sampling;
        let depth = depth_to_rgb(&image.rays.depth, &image.rays.acc, s.near, s.far);
        save_png(&out.join(format!("{name}_depth.png")), w, h, &depth).map_err(|e| e.to_string())
    }
}

/// A progress bar for `what` (hidden when `show` is false).
pub fn frame_bar(show: bool, what: &str) -> ProgressBar {
    let bar = if show { ProgressBar::new(0) } else { ProgressBar::hidden() };
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{elapsed_precise}<{eta_precise}] {wide_bar} {percent}% {msg}").expect("valid template"),
    );
    bar.set_prefix(what.to_string());
    bar
}

fn create_dir(out: &Path) -> Result<(), String> {
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))
}

/// Render a split's views, compare with its images, write PNGs and `<out>/metrics.json`.
pub fn eval(run: &Path, data: &Path, split: Split, downscale: u32, limit: Option<usize>, out: &Path, progress: bool) -> Result<EvalReport, String> {
    let loaded = LoadedRun::open(run)?;
    let mut scene = load_split(data, split, downscale, true).map_err(|e| e.to_string())?;
    scene.views.truncate(limit.unwrap_or(usize::MAX));
    create_dir(out)?;
    let mut per_image = Vec::new();
    for (k, view) in scene.views.iter().enumerate() {
        let bar = frame_bar(progress, &format!("{} {}/{}", view.name, k + 1, scene.views.len()));
        let image = loaded.render(&scene.intrinsics, &view.pose, &bar);
        let target = view.image.as_ref().expect("images were loaded");
        let m = ImageMetrics {
            name: view.name.clone(),
            psnr: psnr(&image.rays.rgb, target),
            ssim: ssim(&image.rays.rgb, target, image.width as usize, image.height as usize),
        };
        bar.finish_with_message(format!("PSNR {:.2} dB, SSIM {:.3}", m.psnr, m.ssim));
        loaded.save(&image, out, &view.name)?;
        per_image.push(m);
    }
    let report = EvalReport::from_images(per_image);
    report.write_json(&out.join("metrics.json")).map_err(|e| e.to_string())?;
    Ok(report)
}

/// Render a split's poses (no ground truth needed) to PNGs and depth maps.
pub fn render_split(run: &Path, data: &Path, split: Split, downscale: u32, out: &Path, progress: bool) -> Result<usize, String> {
    let loaded = LoadedRun::open(run)?;
    let scene = load_split(data, split, downscale, false).map_err(|e| e.to_string())?;
    create_dir(out)?;
    for (k, view) in scene.views.iter().enumerate() {
        let bar = frame_bar(progress, &format!("{} {}/{}", view.name, k + 1, scene.views.len()));
        let image = loaded.render(&scene.intrinsics, &view.pose, &bar);
        bar.finish();
        loaded.save(&image, out, &view.name)?;
    }
    Ok(scene.views.len())
}

/// Render the reference 360° orbit: `frame_NNN.png`, depth maps and `orbit.gif`.
pub fn render_orbit(run: &Path, frames: usize, out: &Path, progress: bool) -> Result<PathBuf, String> {
    let loaded = LoadedRun::open(run)?;
    create_dir(out)?;
    let mut colour = Vec::with_capacity(frames);
    for (k, pose) in Pose::orbit(frames).iter().enumerate() {
        let bar = frame_bar(progress, &format!("orbit {}/{frames}", k + 1));
        let image = loaded.render(&loaded.camera, pose, &bar);
        bar.finish();
        loaded.save(&image, out, &format!("frame_{k:03}"))?;
        colour.push(image.rays.rgb);
    }
    let gif = out.join("orbit.gif");
    save_gif(&gif, loaded.camera.width, loaded.camera.height, &colour, 100).map_err(|e| e.to_string())?;
    Ok(gif)
}
