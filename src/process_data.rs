//! `nerf process-data`: a capture from a COLMAP sparse model into the `transforms.json` layout
//! `nerf train` reads (instant-ngp/nerfstudio): `transforms.json` beside an `images/` folder
//! holding the registered images. The conventions are in [`nerf_core::dataset::colmap`].

use crate::error::Result;
use nerf_core::dataset::colmap::{ColmapModel, model_dirs, read_model, transforms_json};
use nerf_core::io::atomic::write_dir_atomic;
use nerf_core::Error as CoreError;
use std::path::{Path, PathBuf};

/// Fewer registered images than this share of the folder's gets a warning.
pub const WARN_REGISTERED: f64 = 0.9;
/// Fewer registered images than this is an error: nothing to train on.
pub const MIN_REGISTERED: usize = 3;

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
}

/// Image files in `dir` (by extension), sorted by name.
fn image_files(dir: &Path) -> Result<Vec<String>> {
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

/// Convert the COLMAP model at `model` (a model folder, or a project with `sparse/N`) of the
/// images in `images` into `out` (written whole or not at all).
pub fn convert_colmap(model: &Path, images: &Path, out: &Path) -> Result<Processed> {
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
    let json = transforms_json(&model_dir, &colmap, "images")?;
    write_dir_atomic(out, |tmp| {
        let dst = tmp.join("images");
        for image in &colmap.images {
            let to = dst.join(&image.name);
            if let Some(parent) = to.parent() {
                std::fs::create_dir_all(parent).map_err(|e| CoreError::io(parent, e))?;
            }
            std::fs::copy(images.join(&image.name), &to).map_err(|e| CoreError::io(&to, e))?;
        }
        let text = serde_json::to_string_pretty(&json).expect("JSON serialises");
        std::fs::write(tmp.join("transforms.json"), text).map_err(|e| CoreError::io(tmp.join("transforms.json"), e))
    })?;
    let registered: std::collections::HashSet<&str> = colmap.images.iter().map(|i| i.name.as_str()).collect();
    let dropped = in_folder.iter().filter(|n| !registered.contains(n.as_str())).cloned().collect();
    Ok(Processed { model: model_dir, images: in_folder.len(), registered: colmap.images.len(), dropped })
}
