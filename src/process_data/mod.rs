//! `nerf process-data`: photos, a video or a COLMAP sparse model into the `transforms.json`
//! layout `nerf train` reads (instant-ngp/nerfstudio): `transforms.json` beside an `images/`
//! folder holding the registered images, and `colmap/` with COLMAP's logs and model when it ran.
//! The conventions are in [`nerf_core::dataset::colmap`]; the tools in [`tools`].

pub mod frames;
pub mod tools;

use crate::error::Result;
use nerf_core::dataset::colmap::{ColmapModel, Coordinates, model_dirs, read_model, transforms_json};
use nerf_core::dataset::write_prescaled;
use nerf_core::io::atomic::write_dir_atomic;
use nerf_core::Error as CoreError;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Fewer registered images than this share of the folder's gets a warning.
pub const WARN_REGISTERED: f64 = 0.9;
/// Fewer registered images than this is an error: nothing to train on.
pub const MIN_REGISTERED: usize = 3;

/// What is written besides `transforms.json` and `images/`.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputOptions {
    /// Where the cameras go: instant-ngp's placement with an `aabb_scale` (the default, as
    /// `colmap2nerf.py` writes it), or COLMAP's own coordinates.
    pub coordinates: Coordinates,
    /// Shrunk copies of the images, as nerfstudio writes them: `images_2/`, `images_4/`, … up
    /// to `2^downscales` (a factor that does not divide the images' sides is skipped). `nerf
    /// train --downscale N` reads `images_N/` when it is there.
    pub downscales: u32,
    /// Progress on stderr.
    pub progress: bool,
}

/// What a conversion did.
#[derive(Debug, Clone, PartialEq)]
pub struct Processed {
    /// The model converted (the one with the most images when COLMAP made several).
    pub model: PathBuf,
    /// Images in the image folder.
    pub images: usize,
    /// Images the model registered (and the output holds).
    pub registered: usize,
    /// Images of the folder the model did not register, by name.
    pub dropped: Vec<String>,
    /// The factors of the shrunk copies written (`images_2/`, …).
    pub downscaled: Vec<u32>,
}

/// Image files in `dir` (by extension), sorted by name.
pub(crate) fn image_files(dir: &Path) -> Result<Vec<String>> {
    let entries = std::fs::read_dir(dir).map_err(|e| CoreError::io(dir, e))?;
    let mut names: Vec<String> = entries
        .flatten()
        .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| matches!(n.rsplit_once('.').map(|(_, x)| x.to_ascii_lowercase()).as_deref(), Some("png" | "jpg" | "jpeg")))
        .collect();
    names.sort();
    Ok(names)
}

/// Run COLMAP on the photos in `images` and convert its model into `out`.
pub fn process_images(images: &Path, out: &Path, colmap: &tools::ColmapOptions, output: &OutputOptions) -> Result<Processed> {
    let n = image_files(images)?.len();
    if n < MIN_REGISTERED {
        return Err(CoreError::invalid(images, format!("{n} .png/.jpg images: at least {MIN_REGISTERED} are needed to reconstruct anything")).into());
    }
    let work = tempfile::tempdir().map_err(|e| CoreError::io(std::env::temp_dir(), e))?;
    let sparse = tools::run_colmap(images, work.path(), colmap, output.progress)?;
    convert(&sparse, images, out, Some(work.path()), output)
}

/// Which frames of a video to take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameOptions {
    /// About this many frames, evenly over the video.
    pub count: usize,
    /// Each frame is the sharpest of this many candidates around its time (1: no choice).
    pub sharpest_of: usize,
}

/// Pick frames of `video` with ffmpeg, run COLMAP on them (sequential matching suits a
/// video) and convert its model into `out`.
pub fn process_video(video: &Path, frames: FrameOptions, out: &Path, colmap: &tools::ColmapOptions, output: &OutputOptions) -> Result<Processed> {
    let work = tempfile::tempdir().map_err(|e| CoreError::io(std::env::temp_dir(), e))?;
    let candidates = work.path().join("candidates");
    tools::extract_frames(video, frames.count * frames.sharpest_of.max(1), &candidates, work.path(), output.progress)?;
    let images = work.path().join("frames");
    let n = frames::keep_sharpest(&candidates, frames.sharpest_of, &images)?;
    if n < MIN_REGISTERED {
        return Err(CoreError::invalid(video, format!("ffmpeg gave {n} frames: too short a video, or ask for more with --frames")).into());
    }
    let sparse = tools::run_colmap(&images, work.path(), colmap, output.progress)?;
    convert(&sparse, &images, out, Some(work.path()), output)
}

/// Convert the COLMAP model at `model` (a model folder, or a project with `sparse/N`) of the
/// images in `images` into `out` (written whole or not at all).
pub fn convert_colmap(model: &Path, images: &Path, out: &Path, output: &OutputOptions) -> Result<Processed> {
    convert(model, images, out, None, output)
}

/// [`convert_colmap`], keeping COLMAP's logs and models from `work` in `out/colmap/`.
fn convert(model: &Path, images: &Path, out: &Path, work: Option<&Path>, output: &OutputOptions) -> Result<Processed> {
    let candidates = model_dirs(model);
    if candidates.is_empty() {
        return Err(CoreError::invalid(model, "not a COLMAP sparse model or project: no cameras.bin/cameras.txt here or in sparse/*").into());
    }
    // COLMAP splits a capture it cannot connect into several models: take the largest.
    let mut best: Option<(PathBuf, ColmapModel)> = None;
    for dir in candidates {
        let m = read_model(&dir)?;
        if best.as_ref().is_none_or(|(_, b)| m.images.len() > b.images.len()) {
            best = Some((dir, m));
        }
    }
    let (model_dir, colmap) = best.expect("at least one candidate");
    let in_folder = image_files(images)?;
    if in_folder.is_empty() {
        return Err(CoreError::invalid(images, "no .png/.jpg images in this folder").into());
    }
    if colmap.images.len() < MIN_REGISTERED {
        return Err(CoreError::invalid(&model_dir, format!("only {} images registered (at least {MIN_REGISTERED} are needed): too little overlap between the photos, or too little texture", colmap.images.len())).into());
    }
    for image in &colmap.images {
        if !images.join(&image.name).is_file() {
            return Err(CoreError::invalid(images, format!("the model registers {:?}, which is not in this folder: is it the folder COLMAP read?", image.name)).into());
        }
    }
    let json = transforms_json(&model_dir, &colmap, "images", output.coordinates)?;
    let downscaled = downscale_factors(images, &colmap, output.downscales)?;
    write_dir_atomic(out, |tmp| {
        let dst = tmp.join("images");
        for image in &colmap.images {
            let to = dst.join(&image.name);
            if let Some(parent) = to.parent() {
                std::fs::create_dir_all(parent).map_err(|e| CoreError::io(parent, e))?;
            }
            std::fs::copy(images.join(&image.name), &to).map_err(|e| CoreError::io(&to, e))?;
        }
        write_downscaled(&dst, &colmap, &downscaled, output.progress)?;
        if let Some(work) = work {
            copy_logs(work, &tmp.join("colmap"))?;
        }
        let text = serde_json::to_string_pretty(&json).expect("JSON serialises");
        std::fs::write(tmp.join("transforms.json"), text).map_err(|e| CoreError::io(tmp.join("transforms.json"), e))
    })?;
    let registered: std::collections::HashSet<&str> = colmap.images.iter().map(|i| i.name.as_str()).collect();
    let dropped = in_folder.iter().filter(|n| !registered.contains(n.as_str())).cloned().collect();
    // A model COLMAP made here is kept in out/colmap/.
    let model = match work.and_then(|w| model_dir.strip_prefix(w).ok()) {
        Some(rel) => out.join("colmap").join(rel),
        None => model_dir,
    };
    Ok(Processed { model, images: in_folder.len(), registered: colmap.images.len(), dropped, downscaled })
}

/// The factors 2, 4, … 2^`count` that divide the sides of every registered image.
fn downscale_factors(images: &Path, colmap: &ColmapModel, count: u32) -> Result<Vec<u32>> {
    let mut sizes = Vec::new();
    for image in &colmap.images {
        let path = images.join(&image.name);
        let size = image::image_dimensions(&path).map_err(|source| CoreError::Image { path: path.clone(), source })?;
        if !sizes.contains(&size) {
            sizes.push(size);
        }
    }
    let divides = |f: u32| sizes.iter().all(|&(w, h)| w.is_multiple_of(f) && h.is_multiple_of(f));
    Ok((1..=count.min(8)).map(|k| 1u32 << k).filter(|&f| divides(f)).collect())
}

/// Shrunk copies (`images_2/`, …) of the registered images in `images`.
fn write_downscaled(images: &Path, colmap: &ColmapModel, factors: &[u32], progress: bool) -> nerf_core::Result<()> {
    if factors.is_empty() {
        return Ok(());
    }
    let bar = if progress { indicatif::ProgressBar::new(colmap.images.len() as u64) } else { indicatif::ProgressBar::hidden() };
    bar.set_style(indicatif::ProgressStyle::with_template("{msg} {bar:30} {pos}/{len} {elapsed}").expect("a valid template"));
    bar.set_message(format!("shrunk copies (÷{})", factors.iter().map(u32::to_string).collect::<Vec<_>>().join(", ÷")));
    colmap.images.par_iter().try_for_each(|image| {
        write_prescaled(&images.join(&image.name), factors)?;
        bar.inc(1);
        Ok(())
    })?;
    bar.finish_and_clear();
    Ok(())
}

/// COLMAP's stage logs and sparse models from `work` into `to`.
fn copy_logs(work: &Path, to: &Path) -> nerf_core::Result<()> {
    let copy_tree = |from: &Path, to: &Path| -> nerf_core::Result<()> {
        for entry in walk(from)? {
            let rel = entry.strip_prefix(from).expect("below");
            let dst = to.join(rel);
            std::fs::create_dir_all(dst.parent().expect("a file has a parent")).map_err(|e| CoreError::io(&dst, e))?;
            std::fs::copy(&entry, &dst).map_err(|e| CoreError::io(&dst, e))?;
        }
        Ok(())
    };
    std::fs::create_dir_all(to).map_err(|e| CoreError::io(to, e))?;
    for entry in std::fs::read_dir(work).map_err(|e| CoreError::io(work, e))?.flatten() {
        let path = entry.path();
        if path.extension().is_some_and(|x| x == "log") {
            std::fs::copy(&path, to.join(entry.file_name())).map_err(|e| CoreError::io(&path, e))?;
        }
    }
    copy_tree(&work.join("sparse"), &to.join("sparse"))
}

/// Regular files below `dir`, recursively.
fn walk(dir: &Path) -> nerf_core::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    if !dir.is_dir() {
        return Ok(files);
    }
    for entry in std::fs::read_dir(dir).map_err(|e| CoreError::io(dir, e))?.flatten() {
        let path = entry.path();
        if path.is_dir() {
            files.extend(walk(&path)?);
        } else {
            files.push(path);
        }
    }
    Ok(files)
}
