//! One harness per file a user hands us. Each builds its seeds with the project's own writers
//! (a generated scene, a real training run, `nerf export`) and calls the public parser the
//! commands call, on the mutated file written where that parser reads it.

use super::{Format, Harness, HarnessDef};
use nerf::evaluate::LoadedRun;
use nerf::run_dir::RunDir;
use nerf::run_dir::Checkpoint;
use nerf::config::{Preset, TrainConfig};
use nerf::train::{TrainOptions, train};
use nerf::field::mlp::Trainer;
use nerf_core::dataset::{
    Background, CaptureSplit, LoadOptions, SceneFrame, Split, SyntheticSceneConfig, generate_scene, load_dataset, load_split,
};
use nerf_core::io::image::{load_rgba, save_gif};
use nerf_core::sample::occupancy::FILE_NAME as OCCUPANCY_FILE;
use nerf_bundle::{read_model, read_scene};
use nerf_bundle::graph::check_initializers;
use nerf_bundle::{check_contract, read_occupancy};
use std::path::{Path, PathBuf};

/// Every harness, in the order they run.
pub const ALL: [HarnessDef; 15] = [
    HarnessDef { name: "transforms", file: "transforms_train.json", setup: transforms },
    HarnessDef { name: "ngp-transforms", file: "capture/transforms.json (instant-ngp, nerfstudio)", setup: ngp_transforms },
    HarnessDef { name: "llff", file: "llff/poses_bounds.npy", setup: llff },
    HarnessDef { name: "colmap-cameras", file: "sparse/0/cameras.bin (COLMAP)", setup: colmap_cameras },
    HarnessDef { name: "colmap-images", file: "sparse/0/images.bin (COLMAP)", setup: colmap_images },
    HarnessDef { name: "source", file: "run/source.json", setup: source },
    HarnessDef { name: "image", file: "train/r_0.png (PNG/GIF)", setup: image },
    HarnessDef { name: "config", file: "run/config.toml", setup: config },
    HarnessDef { name: "camera", file: "run/camera.json", setup: camera },
    HarnessDef { name: "checkpoint-state", file: "checkpoints/step-*/state.json", setup: checkpoint_state },
    HarnessDef { name: "checkpoint-model", file: "checkpoints/step-*/model.bpk", setup: checkpoint_model },
    HarnessDef { name: "checkpoint-optim", file: "checkpoints/step-*/optim.bpk", setup: checkpoint_optim },
    HarnessDef { name: "scene", file: "bundle/scene.json", setup: scene },
    HarnessDef { name: "occupancy", file: "bundle/occupancy.bin", setup: occupancy },
    HarnessDef { name: "onnx", file: "bundle/coarse.onnx", setup: onnx },
];

/// A harness that writes the input to `target` and calls `parse`.
struct FileHarness<F> {
    target: PathBuf,
    seeds: Vec<Vec<u8>>,
    format: Format,
    parse: F,
}

impl<F: FnMut() -> Result<(), String>> Harness for FileHarness<F> {
    fn seeds(&self) -> &[Vec<u8>] {
        &self.seeds
    }

    fn format(&self) -> Format {
        self.format
    }

    fn execute(&mut self, input: &[u8]) -> Result<(), String> {
        std::fs::write(&self.target, input).map_err(|e| format!("harness: writing {}: {e}", self.target.display()))?;
        (self.parse)()
    }
}

fn boxed<F: FnMut() -> Result<(), String> + 'static>(target: PathBuf, seeds: Vec<Vec<u8>>, format: Format, parse: F) -> Box<dyn Harness> {
    Box::new(FileHarness { target, seeds, format, parse })
}

fn read(path: &Path) -> Result<Vec<u8>, String> {
    std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))
}

/// An 8×8 generated Blender scene (3 train, 1 val, 1 test views) in `work/scene`.
fn small_scene(work: &Path) -> Result<PathBuf, String> {
    let dir = work.join("scene");
    let cfg = SyntheticSceneConfig { width: 8, height: 8, n_train: 3, n_val: 1, n_test: 1, seed: 1 };
    generate_scene(&dir, &cfg).map_err(|e| e.to_string())?;
    Ok(dir)
}

/// A tiny network trained for two steps on the small scene, with an occupancy grid.
fn tiny_config() -> TrainConfig {
    let mut c = Preset::CpuFast.config();
    c.shapes.network.depth = 2;
    c.shapes.network.width = 16;
    c.shapes.network.skips = vec![0];
    c.sampling.n_coarse = 8;
    c.sampling.n_fine = 8;
    c.batch_rays = 32;
    c.iters = 2;
    c.precrop_iters = 0;
    c.eval_every_min = 0.0;
    c.occupancy.resolution = 8;
    c.occupancy.warmup_steps = 0;
    c.occupancy.update_every = 1;
    c
}

/// `work/run`: a real run (config.toml, camera.json, a checkpoint) written by `nerf train`'s code.
fn trained_run(work: &Path) -> Result<(PathBuf, PathBuf), String> {
    let data = small_scene(work)?;
    let run = work.join("run");
    let options =
        TrainOptions { format: None, data: data.clone(), run: run.clone(), config: tiny_config(), ndc: None, contract: None, downscale: 1, time_budget_min: None, iters: None, progress: false };
    train(&options).map_err(|e| e.to_string())?;
    Ok((data, run))
}

/// `work/bundle`: the trained run exported by `nerf export`'s code (graphs, scene.json, grid).
fn exported_bundle(work: &Path) -> Result<PathBuf, String> {
    let (_, run) = trained_run(work)?;
    let bundle = work.join("bundle");
    nerf::export::export_run(&run, &bundle, &Default::default(), None).map_err(|e| e.to_string())?;
    Ok(bundle)
}

fn transforms(work: &Path) -> Result<Box<dyn Harness>, String> {
    let dir = small_scene(work)?;
    let target = nerf_core::dataset::transforms_path(&dir, Split::Train);
    // All three splits' files are valid train files: their images are in the scene too.
    let seeds = Split::ALL.iter().map(|&s| read(&nerf_core::dataset::transforms_path(&dir, s))).collect::<Result<_, _>>()?;
    Ok(boxed(target, seeds, Format::Json, move || {
        // Training reads pixels; `nerf render --split` reads only the sizes (and downscales).
        let with_images = load_split(&dir, Split::Train, 1, true).map(drop).map_err(|e| e.to_string());
        let sizes_only = load_split(&dir, Split::Train, 2, false).map(drop).map_err(|e| e.to_string());
        with_images.and(sizes_only)
    }))
}

/// Loads every view of the dataset in `dir` as training does (fitted, with pixels) and the
/// test split as `nerf render --split` does (poses and sizes, downscaled).
fn load_as_commands_do(dir: &Path) -> Result<(), String> {
    let options = |images, downscale| LoadOptions { format: None, downscale, images, background: Background::White, frame: SceneFrame::Fit { bound: 1.5, ndc: None, contraction: None } };
    let all = load_dataset(dir, CaptureSplit::All, &options(true, 1)).map(drop).map_err(|e| e.to_string());
    all.and(load_dataset(dir, CaptureSplit::Test, &options(false, 2)).map(drop).map_err(|e| e.to_string()))
}

/// A camera-to-world matrix, 4 rows of 4.
type Matrix = [[f32; 4]; 4];

/// The small scene's train views (8×8) copied to `work/<name>/images/<k>.png`, with their
/// OpenGL camera-to-world rows.
fn capture_images(work: &Path, name: &str) -> Result<(PathBuf, Vec<Matrix>), String> {
    let scene = small_scene(work)?;
    let dir = work.join(name);
    std::fs::create_dir_all(dir.join("images")).map_err(|e| e.to_string())?;
    let train = nerf_core::dataset::load_split(&scene, Split::Train, 1, false).map_err(|e| e.to_string())?;
    let mut poses = Vec::new();
    for (k, view) in train.views.iter().enumerate() {
        std::fs::copy(scene.join(format!("train/{}.png", view.name)), dir.join(format!("images/{k}.png"))).map_err(|e| e.to_string())?;
        let r = view.pose.0;
        poses.push([r[0], r[1], r[2], [0.0, 0.0, 0.0, 1.0]]);
    }
    Ok((dir, poses))
}

fn ngp_transforms(work: &Path) -> Result<Box<dyn Harness>, String> {
    let (dir, poses) = capture_images(work, "capture")?;
    let frames = |ext: &str| -> Vec<serde_json::Value> {
        poses.iter().enumerate().map(|(k, m)| serde_json::json!({"file_path": format!("images/{k}{ext}"), "transform_matrix": m})).collect()
    };
    // instant-ngp: shared intrinsics with distortion and aabb_scale; nerfstudio: per-frame
    // focal lengths, paths without extension, explicit splits.
    let ngp = serde_json::json!({"fl_x": 9.5, "fl_y": 9.0, "cx": 4.2, "cy": 3.9, "w": 8, "h": 8, "k1": 0.05, "k2": -0.01, "p1": 0.001, "p2": 0.002, "aabb_scale": 2, "frames": frames(".png")});
    let mut studio_frames = frames("");
    for (k, f) in studio_frames.iter_mut().enumerate() {
        f["fl_x"] = serde_json::json!(9.0 + k as f64);
        f["camera_model"] = serde_json::json!("OPENCV");
    }
    let studio = serde_json::json!({"camera_angle_x": 0.7, "frames": studio_frames, "train_filenames": ["images/1", "images/2"], "test_filenames": ["images/0"]});
    let seeds = [ngp, studio].iter().map(|v| serde_json::to_vec_pretty(v).expect("JSON serialises")).collect();
    Ok(boxed(dir.join("transforms.json"), seeds, Format::Json, move || load_as_commands_do(&dir)))
}

/// A NumPy `.npy` (format 1.0, little-endian float64, C order) of `rows` × 17.
fn npy_f8(rows: &[[f64; 17]]) -> Vec<u8> {
    let mut header = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({}, 17), }}", rows.len());
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend(rows.iter().flatten().flat_map(|v| v.to_le_bytes()));
    out
}

fn llff(work: &Path) -> Result<Box<dyn Harness>, String> {
    let (dir, poses) = capture_images(work, "llff")?;
    // LLFF columns [down, right, back, centre, (H, W, focal)] from OpenGL [right, up, back].
    let rows: Vec<[f64; 17]> = poses
        .iter()
        .map(|m| {
            let mut row = [0.0; 17];
            for r in 0..3 {
                let cols = [-m[r][1], m[r][0], m[r][2], m[r][3], [8.0, 8.0, 9.5][r]];
                for (c, v) in cols.iter().enumerate() {
                    row[r * 5 + c] = *v as f64;
                }
            }
            (row[15], row[16]) = (2.0, 6.0);
            row
        })
        .collect();
    let seeds = vec![npy_f8(&rows)];
    Ok(boxed(dir.join("poses_bounds.npy"), seeds, Format::Binary, move || load_as_commands_do(&dir)))
}

/// A COLMAP binary model in `work/colmap`: one OPENCV camera, three images with 2-D points
/// (COLMAP's layout: counts as u64, ids as i32, names NUL-terminated).
fn colmap_model(work: &Path) -> Result<PathBuf, String> {
    let dir = work.join("colmap");
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    let mut cameras = 1u64.to_le_bytes().to_vec();
    cameras.extend(1i32.to_le_bytes());
    cameras.extend(4i32.to_le_bytes());
    cameras.extend(64u64.to_le_bytes());
    cameras.extend(48u64.to_le_bytes());
    [60.0f64, 61.0, 32.0, 24.0, 0.01, -0.02, 0.001, 0.0].iter().for_each(|v| cameras.extend(v.to_le_bytes()));
    let mut images = 3u64.to_le_bytes().to_vec();
    for k in 0..3 {
        images.extend((k + 1i32).to_le_bytes());
        [0.9f64, 0.1 * k as f64, -0.2, 0.3, k as f64, 0.5, -2.0].iter().for_each(|v| images.extend(v.to_le_bytes()));
        images.extend(1i32.to_le_bytes());
        images.extend(format!("img_{k}.png\0").as_bytes());
        images.extend(2u64.to_le_bytes());
        for p in 0..2 {
            images.extend((p as f64).to_le_bytes());
            images.extend(1.5f64.to_le_bytes());
            images.extend((p as i64 - 1).to_le_bytes());
        }
    }
    std::fs::write(dir.join("cameras.bin"), cameras).map_err(|e| e.to_string())?;
    std::fs::write(dir.join("images.bin"), images).map_err(|e| e.to_string())?;
    Ok(dir)
}

/// Read the model and convert it, as `nerf process-data --colmap-model` does.
fn colmap_harness(work: &Path, file: &str) -> Result<Box<dyn Harness>, String> {
    let dir = colmap_model(work)?;
    let target = dir.join(file);
    let seeds = vec![read(&target)?];
    Ok(boxed(target, seeds, Format::Binary, move || {
        let model = nerf_core::dataset::colmap::read_model(&dir).map_err(|e| e.to_string())?;
        nerf_core::dataset::colmap::transforms_json(&dir, &model, "images", nerf_core::dataset::colmap::Coordinates::InstantNgp { aabb_scale: 4 }).map(drop).map_err(|e| e.to_string())
    }))
}

fn colmap_cameras(work: &Path) -> Result<Box<dyn Harness>, String> {
    colmap_harness(work, "cameras.bin")
}

fn colmap_images(work: &Path) -> Result<Box<dyn Harness>, String> {
    colmap_harness(work, "images.bin")
}

fn source(work: &Path) -> Result<Box<dyn Harness>, String> {
    run_file(work, "source.json", Format::Json)
}

fn image(work: &Path) -> Result<Box<dyn Harness>, String> {
    let dir = small_scene(work)?;
    let target = dir.join("train/r_0.png");
    let rgba = read(&target)?;
    // The same 8×8 picture in the other layouts the loader accepts, as a GIF and as a JPEG.
    let decoded = image::open(&target).map_err(|e| e.to_string())?;
    let mut seeds = vec![rgba];
    let encode = |img: image::DynamicImage| -> Result<Vec<u8>, String> {
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Png).map_err(|e| e.to_string())?;
        Ok(out.into_inner())
    };
    seeds.push(encode(image::DynamicImage::ImageLuma8(decoded.to_luma8()))?);
    seeds.push(encode(image::DynamicImage::ImageLumaA8(decoded.to_luma_alpha8()))?);
    seeds.push(encode(image::DynamicImage::ImageRgb8(decoded.to_rgb8()))?);
    seeds.push(encode(image::DynamicImage::ImageRgba16(decoded.to_rgba16()))?);
    let gif = work.join("r_0.gif");
    let rgb: Vec<[f32; 3]> = decoded.to_rgb32f().pixels().map(|p| p.0).collect();
    save_gif(&gif, 8, 8, &[rgb], 40).map_err(|e| e.to_string())?;
    seeds.push(read(&gif)?);
    // And as a JPEG (real captures are JPEGs; the loader sniffs the format from the bytes).
    let mut jpeg = std::io::Cursor::new(Vec::new());
    image::DynamicImage::ImageRgb8(decoded.to_rgb8()).write_to(&mut jpeg, image::ImageFormat::Jpeg).map_err(|e| e.to_string())?;
    seeds.push(jpeg.into_inner());
    Ok(boxed(target.clone(), seeds, Format::Binary, move || {
        load_rgba(&target).map_err(|e| e.to_string())?;
        load_split(&dir, Split::Train, 2, true).map(drop).map_err(|e| e.to_string())
    }))
}

/// A run-directory harness: mutates `file` of a trained run and opens the run as `nerf eval`,
/// `nerf render` and `nerf export` do.
fn run_file(work: &Path, file: &str, format: Format) -> Result<Box<dyn Harness>, String> {
    let (_, run) = trained_run(work)?;
    let target = run.join(file);
    let seeds = vec![read(&target)?];
    Ok(boxed(target, seeds, format, move || LoadedRun::open(&run).map(drop).map_err(|e| e.to_string())))
}

fn config(work: &Path) -> Result<Box<dyn Harness>, String> {
    run_file(work, "config.toml", Format::Toml)
}

fn camera(work: &Path) -> Result<Box<dyn Harness>, String> {
    run_file(work, "camera.json", Format::Json)
}

/// A checkpoint harness: mutates `file` of the run's latest checkpoint and resumes a trainer
/// from it, as `nerf train` does on an existing run.
fn checkpoint_file(work: &Path, file: &str, format: Format) -> Result<Box<dyn Harness>, String> {
    let (data, run) = trained_run(work)?;
    let checkpoint = RunDir::open(&run).and_then(|r| r.latest_checkpoint()).map_err(|e| e.to_string())?.ok_or("the run has no checkpoint")?;
    let train_data = load_split(&data, Split::Train, 1, true).map_err(|e| e.to_string())?;
    let mut trainer = Trainer::new(tiny_config(), train_data, nerf::backend::cpu_autodiff()).map_err(|e| e.to_string())?;
    let target = checkpoint.dir.join(file);
    let seeds = vec![read(&target)?];
    Ok(boxed(target, seeds, format, move || trainer.resume(&Checkpoint { dir: checkpoint.dir.clone() }).map(drop).map_err(|e| e.to_string())))
}

fn checkpoint_state(work: &Path) -> Result<Box<dyn Harness>, String> {
    checkpoint_file(work, "state.json", Format::Json)
}

fn checkpoint_model(work: &Path) -> Result<Box<dyn Harness>, String> {
    checkpoint_file(work, "model.bpk", Format::Binary)
}

fn checkpoint_optim(work: &Path) -> Result<Box<dyn Harness>, String> {
    checkpoint_file(work, "optim.bpk", Format::Binary)
}

/// Reads a bundle as `nerf-render` does before onnxruntime sees it: `scene.json`, the grid,
/// and each graph decoded, contract-checked and its initializers sized as their shapes say.
fn read_bundle(dir: &Path) -> Result<(), String> {
    let read = || -> nerf_core::Result<()> {
        let scene = read_scene(dir)?;
        read_occupancy(dir, &scene)?;
        for g in scene.graph_files() {
            let path = nerf_bundle::bundle_file(dir, g.file, g.key)?;
            let model = read_model(&path)?;
            check_contract(&model).and_then(|()| check_initializers(&model)).map_err(|e| nerf_core::Error::invalid(&path, e))?;
        }
        Ok(())
    };
    read().map_err(|e| e.to_string())
}

fn scene(work: &Path) -> Result<Box<dyn Harness>, String> {
    let bundle = exported_bundle(work)?;
    let target = bundle.join(nerf_bundle::SCENE_FILE);
    let seeds = vec![read(&target)?];
    Ok(boxed(target, seeds, Format::Json, move || read_bundle(&bundle)))
}

fn occupancy(work: &Path) -> Result<Box<dyn Harness>, String> {
    let bundle = exported_bundle(work)?;
    let target = bundle.join(OCCUPANCY_FILE);
    let seeds = vec![read(&target)?];
    Ok(boxed(target, seeds, Format::Binary, move || read_bundle(&bundle)))
}

fn onnx(work: &Path) -> Result<Box<dyn Harness>, String> {
    let bundle = exported_bundle(work)?;
    let target = bundle.join("coarse.onnx");
    // The fine graph is a valid coarse.onnx too (same contract, another stage).
    let seeds = vec![read(&target)?, read(&bundle.join("fine.onnx"))?];
    Ok(boxed(target, seeds, Format::Onnx, move || read_bundle(&bundle)))
}
