//! The scene bundle format, apart from the compiler: a directory holding `scene.json`
//! ([`scene::SceneDescription`]), one ONNX graph per role (`field.onnx`, or `coarse.onnx` and
//! `fine.onnx`) that follows the graph contract ([`graph`]) and, for marched fields,
//! `occupancy.bin`. Renderers read and check bundles here; the compiler (`nerf-export`) writes
//! them through [`write_bundle`]. Bundles written by earlier versions (`nerf-rs-scene-1`)
//! still read.
#![warn(missing_docs)]

pub mod graph;
pub mod ngp;
pub mod proto;
pub mod scene;

pub use graph::{check_contract, read_model};
pub use scene::{SCENE_FILE, SceneDescription, pose_matrix};

use nerf_core::field::Role;
use nerf_core::io::limits::{self, Origin};
use nerf_core::sample::occupancy::{self, OccupancyGrid};
use scene::OccupancyDescription;
use std::path::{Path, PathBuf};

/// A file written into a bundle and its size.
#[derive(Debug, Clone, PartialEq)]
pub struct WrittenFile {
    /// Path of the file in its final place.
    pub path: PathBuf,
    /// Size in bytes.
    pub bytes: usize,
}

/// Write a bundle to `dir`, whole or not at all ([`nerf_core::io::atomic::write_dir_atomic`]: a
/// failed or killed write leaves the previous bundle as it was): each graph (role, encoded
/// model) as `<role>.onnx`, the grid as `occupancy.bin`, and `scene` with both named.
pub fn write_bundle(dir: &Path, scene: &SceneDescription, graphs: Vec<(Role, Vec<u8>)>, occupancy: Option<&OccupancyGrid>) -> nerf_core::Result<Vec<WrittenFile>> {
    let mut scene = scene.clone();
    // Today's format (a contracted field's own), whatever the description was read as.
    scene.set_contraction(scene.contraction);
    scene.networks = None;
    let mut files: Vec<(String, Vec<u8>)> = Vec::with_capacity(graphs.len() + 2);
    scene.graphs.clear();
    for (role, bytes) in graphs {
        let file = format!("{}.onnx", role.name());
        scene.graphs.insert(role, file.clone());
        files.push((file, bytes));
    }
    scene.occupancy = occupancy.map(|g| OccupancyDescription { file: occupancy::FILE_NAME.into(), resolution: g.resolution(), bound: g.bound() });
    if let Some(p) = &mut scene.placement {
        p.ndc = None; // stated once, in sampling.ndc
    }
    files.extend(occupancy.map(|g| (occupancy::FILE_NAME.to_string(), g.to_bytes())));
    files.push((SCENE_FILE.into(), serde_json::to_vec_pretty(&scene).expect("a scene serialises")));
    nerf_core::io::atomic::write_dir_atomic(dir, |tmp| {
        for (file, bytes) in &files {
            let p = tmp.join(file);
            std::fs::write(&p, bytes).map_err(|e| nerf_core::Error::io(&p, e))?;
        }
        Ok(())
    })?;
    Ok(files.into_iter().map(|(file, bytes)| WrittenFile { path: dir.join(file), bytes: bytes.len() }).collect())
}

/// The path of the bundle file `name` that `scene.json`'s `key` names: a plain file name
/// inside `dir` (no absolute path, no `..`, no separator; a symbolic link must stay inside).
pub fn bundle_file(dir: &Path, name: &str, key: &str) -> nerf_core::Result<PathBuf> {
    let scene = dir.join(SCENE_FILE);
    limits::file_in_dir(dir, name, Origin::Field(&scene, key))
}

/// Read and check a bundle's `scene.json` (see [`SceneDescription::check`]).
pub fn read_scene(dir: &Path) -> nerf_core::Result<SceneDescription> {
    let path = dir.join(SCENE_FILE);
    let text = limits::read_json_text(&path)?;
    let scene: SceneDescription = serde_json::from_str(&text).map_err(|e| nerf_core::Error::invalid(&path, e.to_string()))?;
    scene.check(&path)?;
    Ok(scene)
}

/// The bundle's occupancy grid, if `scene.json` names one.
pub fn read_occupancy(dir: &Path, scene: &SceneDescription) -> nerf_core::Result<Option<OccupancyGrid>> {
    let Some(o) = &scene.occupancy else { return Ok(None) };
    let grid = OccupancyGrid::load(&bundle_file(dir, &o.file, "occupancy.file")?)?;
    if grid.resolution() != o.resolution || grid.bound() != o.bound {
        let problem = format!("occupancy: the grid file is {}³ over ±{}, scene.json says {}³ over ±{}", grid.resolution(), grid.bound(), o.resolution, o.bound);
        return Err(nerf_core::Error::invalid(dir.join(SCENE_FILE), problem));
    }
    if grid.contraction() != scene.contraction {
        let problem = format!("occupancy: the grid file's contraction is {:?}, scene.json's {:?}", grid.contraction(), scene.contraction);
        return Err(nerf_core::Error::invalid(dir.join(SCENE_FILE), problem));
    }
    Ok(Some(grid))
}
