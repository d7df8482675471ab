//! `nerf`: train, evaluate and render neural radiance fields on the CPU.

mod bench;
mod device_bench;
mod ngp_bench;
mod view;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use nerf::evaluate::{RenderViews, eval, render_orbit, render_views};
use nerf_core::frames::spec::Shard;
use nerf_core::frames::views::SplitChoice;
use nerf_core::frames::write::FramePlan;
use nerf::config::{Preset, TrainConfig};
use nerf::train::{TrainOptions, train, train_live};
use nerf_core::dataset::{CaptureFormat, CaptureSplit, SyntheticSceneConfig, generate_scene};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Parser)]
#[command(name = "nerf", version, about = "Train, evaluate and render NeRFs (burn, CPU by default)")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Train a NeRF on a dataset: Blender, instant-ngp/nerfstudio transforms.json or LLFF
    /// (resumes if <out> holds a checkpoint).
    Train {
        /// Dataset directory: transforms_{train,val,test}.json (Blender), transforms.json
        /// (instant-ngp/nerfstudio) or poses_bounds.npy + images/ (LLFF).
        #[arg(long)]
        data: PathBuf,
        /// The dataset's format: blender, instant-ngp or llff (default: detected from the files).
        #[arg(long)]
        format: Option<CaptureFormat>,
        /// Normalised device coordinates for the rays (nerf-pytorch's LLFF default): `true` or
        /// `false`; default: on for LLFF captures whose cameras all face one way.
        #[arg(long)]
        ndc: Option<bool>,
        /// Contract the unbounded world around a capture (mip-NeRF 360's scene contraction,
        /// L∞ norm): the cameras inside the cube ±1, everything beyond drawn into ±2, marching
        /// steps that grow with distance (docs/captures.md). `--contract` or `--contract true`
        /// to contract, `--contract false` for the cube; default: contracted for ngp runs on
        /// captures that neither face one way nor give an aabb_scale under 8. Not with NDC.
        #[arg(long, num_args = 0..=1, default_missing_value = "true")]
        contract: Option<bool>,
        /// Learn a code per training image for its exposure and white balance (nerfacto's
        /// appearance embedding); renders and bundles use the codes' mean (`nerf export
        /// --appearance` picks another). For the ngp field.
        #[arg(long)]
        appearance: bool,
        /// Refine each training image's pose with the field (nerfstudio's camera optimiser):
        /// for captures whose poses are good but not perfect. For the ngp field, not with NDC.
        #[arg(long)]
        refine_cameras: bool,
        /// TOML file overriding the preset's settings (any subset of the keys of config.toml).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Starting configuration (default: ngp, the hash-grid field).
        #[arg(long, value_enum)]
        preset: Option<Preset>,
        /// Shrink images by this integer factor (area averaging); focal scales to match.
        #[arg(long, default_value_t = 1)]
        downscale: u32,
        /// Number of training steps (overrides the preset).
        #[arg(long)]
        iters: Option<usize>,
        /// Stop after this many minutes of training (counted across resumes).
        #[arg(long)]
        time_budget_min: Option<f64>,
        /// Seed for initialisation, batches and jitter (overrides the preset).
        #[arg(long)]
        seed: Option<u64>,
        /// Run directory: config.toml, camera.json, checkpoints/, curve.csv.
        #[arg(long)]
        out: PathBuf,
        /// Serve the browser viewer on the run as it trains (live snapshots of the field in
        /// <out>/live/, the progress and the PSNR curve); keeps serving once training ends,
        /// until interrupted.
        #[arg(long)]
        serve: bool,
        /// Address to serve the viewer on (default 127.0.0.1: this machine only).
        #[arg(long, requires = "serve", default_value = "127.0.0.1")]
        host: std::net::IpAddr,
        /// Port to serve the viewer on (0: any free port).
        #[arg(long, requires = "serve", default_value_t = 8000)]
        port: u16,
        /// The built viewer's directory (default: $NERF_VIEWER, else ~/.cache/nerf-rs/viewer).
        #[arg(long, requires = "serve")]
        viewer: Option<PathBuf>,
        /// The longest interval, in seconds of training, between two live snapshots: the first
        /// comes 5 s in, the next ones at intervals that double up to this (besides one at each
        /// validation and one at the end).
        #[arg(long, requires = "serve", default_value_t = nerf::live::SnapshotOptions::default().every_s)]
        snapshot_every: f64,
    },
    /// Serve the browser viewer on a run trained by another process (or done): its latest live
    /// snapshot, else one exported from its latest checkpoint (again at each newer one), with
    /// its progress and PSNR curve; runs until interrupted.
    View {
        /// Run directory written by `nerf train`.
        run: PathBuf,
        #[command(flatten)]
        serve: view::ServeArgs,
    },
    /// Render a split's views and compare with its images: PNGs and metrics.json.
    Eval {
        /// Run directory written by `nerf train`.
        #[arg(long)]
        run: PathBuf,
        /// Dataset directory (its poses go through the run's recorded placement).
        #[arg(long)]
        data: PathBuf,
        /// The dataset's format: blender, instant-ngp or llff (default: detected).
        #[arg(long)]
        format: Option<CaptureFormat>,
        /// Which views: train, val, test or all (captures: test = every 8th frame, val = test).
        #[arg(long, default_value = "val")]
        split: CaptureSplit,
        /// Image downscale factor (use the one you trained with).
        #[arg(long, default_value_t = 1)]
        downscale: u32,
        /// Only the first K views.
        #[arg(long)]
        limit: Option<usize>,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
    },
    /// Overlay runs' PSNR curves (their curve.csv) in one PNG: val solid, train dashed,
    /// against minutes of training, one colour per run.
    Plot {
        /// Run directories written by `nerf train` (1 to 9), labelled by their directory names.
        #[arg(required = true)]
        runs: Vec<PathBuf>,
        /// The PNG to write (written whole or not at all).
        #[arg(long)]
        out: PathBuf,
    },
    /// Render a split's poses, a 360° orbit or a nerfstudio camera path: PNG frames, depth maps,
    /// a GIF; or one shard of them (--shard), or assemble the shards (--merge).
    Render {
        /// Run directory written by `nerf train`.
        #[arg(long, required_unless_present = "merge")]
        run: Option<PathBuf>,
        /// Render the run's orbit at the training resolution: the reference one (radius 4,
        /// elevation −30°) for Blender scenes, around the cameras at their height for captures,
        /// nerf-pytorch's spiral for forward-facing ones.
        #[arg(long)]
        orbit: bool,
        /// Frames in the orbit.
        #[arg(long, default_value_t = 40)]
        frames: usize,
        /// Render this split's poses (train, val, test or all; needs --data).
        #[arg(long)]
        split: Option<CaptureSplit>,
        /// Dataset directory (with --split).
        #[arg(long)]
        data: Option<PathBuf>,
        /// The dataset's format: blender, instant-ngp or llff (default: detected).
        #[arg(long)]
        format: Option<CaptureFormat>,
        /// Image downscale factor (with --split: the dataset's images; with --orbit: the
        /// training camera; with --camera-path: the path's render size).
        #[arg(long, default_value_t = 1)]
        downscale: u32,
        /// Render a nerfstudio camera path (camera_path.json: render_width, render_height,
        /// seconds, camera_path[] of camera_to_world and fov; perspective cameras; poses in the
        /// coordinates of the capture the run trained on): frame_00000.png, … and camera_path.gif.
        #[arg(long, conflicts_with_all = ["orbit", "split"])]
        camera_path: Option<PathBuf>,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Also write <name>.npy per frame: float32 [H, W, 5] = r, g, b, depth, acc.
        #[arg(long)]
        npy: bool,
        /// Render only shard I of N (0-based): the I-th of N contiguous ranges of the frames, into
        /// --out shared by all shards; assemble them with --merge once every shard is done.
        #[arg(long, value_name = "I/N")]
        shard: Option<Shard>,
        /// Keep the frames --out already holds (PNG and depth map, and .npy with --npy; with
        /// ground truth, also their recorded metrics) instead of rendering them again.
        #[arg(long)]
        skip_existing: bool,
        /// Assemble a render made in shards once all are done: the GIF, metrics.json and the
        /// contact sheet in --out (checks every shard and frame is there; writes nothing if not).
        #[arg(long, conflicts_with_all = ["run", "orbit", "split", "camera_path", "shard", "skip_existing"])]
        merge: bool,
    },
    /// Turn photos, a video or a COLMAP model into a capture `nerf train` reads: transforms.json
    /// (OpenGL camera-to-world poses, the camera's intrinsics and distortion), images/, and
    /// colmap/ (COLMAP's logs and model). Runs COLMAP (headless, CPU) and ffmpeg when needed.
    #[command(group(clap::ArgGroup::new("input").required(true).args(["images", "video"])))]
    ProcessData {
        /// A folder of photos (.jpg/.png); with --colmap-model, the folder COLMAP read.
        #[arg(long)]
        images: Option<PathBuf>,
        /// A video: about --frames frames are taken evenly over it (ffmpeg).
        #[arg(long, conflicts_with = "colmap_model")]
        video: Option<PathBuf>,
        /// Frames to take from --video.
        #[arg(long, default_value_t = 120, requires = "video")]
        frames: usize,
        /// Each frame of --video is the sharpest (least blurred) of this many candidates around
        /// its time; 1 takes frames at even times only.
        #[arg(long, default_value_t = 3, requires = "video")]
        sharpest_of: usize,
        /// An existing COLMAP model of --images, converted without running COLMAP: a sparse
        /// model folder (cameras.bin/images.bin or .txt) or a project holding sparse/0, … (the
        /// largest model is used).
        #[arg(long, requires = "images")]
        colmap_model: Option<PathBuf>,
        /// The camera model COLMAP estimates (one camera shared by all images).
        #[arg(long, value_enum, default_value = "opencv")]
        camera_model: nerf::process_data::tools::ColmapCamera,
        /// COLMAP's matcher (default: exhaustive for photos, sequential for a video).
        #[arg(long, value_enum)]
        matcher: Option<nerf::process_data::tools::Matcher>,
        /// COLMAP's vocabulary tree file, for --matcher vocab-tree.
        #[arg(long)]
        vocab_tree: Option<PathBuf>,
        /// The scene box's side in instant-ngp's units (the cameras are placed as colmap2nerf.py
        /// places them: mean up along +z, centred where their axes meet, 4 from the centre on
        /// average): 4 holds what lies up to 1.5 times the cameras' distance from the centre;
        /// raise it (8, 16) when the background far behind the object matters.
        #[arg(long, default_value_t = 4, conflicts_with = "keep_colmap_coords")]
        aabb_scale: u32,
        /// Keep COLMAP's coordinates (no aabb_scale: `nerf train` fits the cameras itself).
        #[arg(long)]
        keep_colmap_coords: bool,
        /// Also write shrunk copies of the images: images_2/, images_4/, … up to 2^N, as
        /// nerfstudio does (`nerf train --downscale 4` reads images_4/). 0: none.
        #[arg(long, default_value_t = 3)]
        downscales: u32,
        /// Output capture directory (written whole or not at all).
        #[arg(long)]
        out: PathBuf,
    },
    /// Compile a trained run into an ONNX scene bundle: field.onnx (or coarse.onnx + fine.onnx), scene.json, occupancy.bin.
    #[command(group(clap::ArgGroup::new("field").required(true).args(["run", "bundle"])))]
    Export {
        /// Run directory written by `nerf train`.
        #[arg(long)]
        run: Option<PathBuf>,
        /// A hash-grid bundle to compile again (its field read back from field.onnx): another
        /// lowering (`--portable`) or table precision of the same field, the same pixels.
        #[arg(long)]
        bundle: Option<PathBuf>,
        /// Bundle directory to write (replaced only once the new bundle is complete).
        #[arg(long)]
        out: PathBuf,
        /// ONNX opset (17–23). Default: 17 for the NeRF MLPs, 18 for the hash-grid field (its
        /// hash uses BitwiseXor; at 17 it takes the portable lowering).
        #[arg(long)]
        opset: Option<i64>,
        /// Portable operators only: no bitwise operator and no int64 data, for onnxruntime's
        /// CUDA provider and onnxruntime-web's WebGPU, which have no Bitwise kernels (the hash
        /// grid's portable lowering takes about 1.5× the CPU time of the default one).
        #[arg(long)]
        portable: bool,
        /// Store the hash grid's table in float16: half the bundle, a PSNR cost well under
        /// 0.05 dB (measured in docs/hash-grid.md). Default: f32 from a run, the bundle's own
        /// from --bundle.
        #[arg(long, value_enum)]
        tables: Option<Tables>,
        /// For a run trained with --appearance: the code the bundle renders with, `mean` (the
        /// default) or a training image's name (its file stem), recorded in scene.json.
        #[arg(long)]
        appearance: Option<String>,
    },
    /// Mesh a trained run or a scene bundle: the surface where the density crosses --threshold,
    /// by marching cubes over the field's box, as a binary PLY (positions, normals, colours) in
    /// the scene's own coordinates, carved by the training views (docs/mesh.md).
    #[command(group(clap::ArgGroup::new("field").required(true).args(["run", "bundle"])))]
    Mesh {
        /// Run directory written by `nerf train` (its latest checkpoint, through burn).
        #[arg(long)]
        run: Option<PathBuf>,
        /// Scene bundle (`nerf export`, `nerf import`), through onnxruntime.
        #[arg(long)]
        bundle: Option<PathBuf>,
        /// The PLY file to write (written whole or not at all).
        #[arg(long)]
        out: PathBuf,
        /// Lattice cells per axis over the box.
        #[arg(long, default_value_t = nerf_core::mesh::DEFAULT_RESOLUTION)]
        resolution: usize,
        /// Density σ at the surface (default: 2.5 for hash-grid fields, instant-ngp's; 50 for the
        /// NeRF MLPs, the original NeRF's).
        #[arg(long)]
        threshold: Option<f32>,
        /// Half the side of the cube to mesh, in the field's frame (default: the field's box,
        /// else its occupancy grid's cube, else 1.5).
        #[arg(long)]
        bound: Option<f32>,
        /// Keep the inner walls of hollows inside solids (by default the empty space the
        /// outside cannot reach counts as inside, so only the outer surface is left: one pass
        /// over the densities instead of two, and no carving).
        #[arg(long)]
        keep_cavities: bool,
        /// Carve with this dataset's train views (poses through the field's placement): the
        /// empty space none of them sees empty counts as inside. Default: a run's own dataset
        /// (recorded in its source.json) when it is still there; a bundle carves only with --data.
        #[arg(long, conflicts_with_all = ["no_carve", "keep_cavities"])]
        data: Option<PathBuf>,
        /// No visibility carving: only the cavity fill (the space the outside cannot reach).
        #[arg(long)]
        no_carve: bool,
    },
    /// Import a model trained elsewhere into a scene bundle (coarse.onnx, fine.onnx, scene.json).
    Import {
        #[command(subcommand)]
        source: ImportSource,
    },
    /// Measure speed, all figures from one run: training steps, network throughput (burn and
    /// onnxruntime) and frame times (burn and onnxruntime, paper network, 64 + 128 samples).
    Bench(bench::BenchOptions),
    /// Generate a small scene, train on it, evaluate and render an orbit (no data needed).
    Demo {
        /// Output directory.
        #[arg(long, default_value = "demo-out")]
        out: PathBuf,
        /// Training minutes.
        #[arg(long, default_value_t = 4.0)]
        minutes: f64,
    },
}

#[derive(Subcommand)]
enum ImportSource {
    /// A nerf-pytorch run: its checkpoint and args.txt (read without Python or PyTorch).
    NerfPytorch {
        /// The checkpoint, <run>/NNNNNN.tar (torch.save's zip or legacy format).
        #[arg(long)]
        checkpoint: PathBuf,
        /// The run's args.txt or config.txt (default: beside the checkpoint).
        #[arg(long)]
        args: Option<PathBuf>,
        /// The scene it was trained on, Blender or LLFF: camera and test poses (default: the run's
        /// datadir, when it exists here).
        #[arg(long)]
        data: Option<PathBuf>,
        /// Bundle directory to write (replaced only once the new bundle is complete).
        #[arg(long)]
        out: PathBuf,
        /// ONNX opset (17–23).
        #[arg(long, default_value_t = nerf_export::DEFAULT_OPSET)]
        opset: i64,
    },
}

/// `nerf export --tables`.
#[derive(Debug, Clone, Copy, PartialEq, clap::ValueEnum)]
enum Tables {
    /// float32: the trained values exactly.
    F32,
    /// float16: half the size.
    F16,
}

#[derive(Debug, Clone, Copy, PartialEq, clap::ValueEnum)]
enum BenchPart {
    /// Training steps.
    Train,
    /// Network forward throughput.
    Mlp,
    /// Frame times: the paper network in burn and onnxruntime, and a hash-grid bundle on each
    /// `--device`, both lowerings, split into the field's and the loop's shares.
    Render,
    /// Empty-space skipping and early termination against the dense path (onnxruntime).
    Skip,
    /// The hash-grid encoding: forward, backward and sparse Adam update (no MLPs).
    Grid,
    /// A full-resolution lego val view of a hash-grid bundle through onnxruntime.
    NgpRender,
}

/// `--frames` for a video: at least 3, at most the frame limit.
fn limits_frames(frames: usize, sharpest_of: usize) -> Result<()> {
    use nerf_core::io::limits::{check_count, Origin, MAX_FRAMES};
    check_count(frames, MAX_FRAMES, "frames", Origin::Option("--frames"))?;
    if frames < 3 {
        bail!("--frames {frames}: a reconstruction needs at least 3");
    }
    if !(1..=10).contains(&sharpest_of) {
        bail!("--sharpest-of {sharpest_of}: give 1 (no choice) to 10 candidates per frame");
    }
    Ok(())
}

fn main() -> Result<()> {
    nerf::backend::tune_allocator();
    let cli = Cli::parse();
    let progress = std::io::stderr().is_terminal();
    match cli.command {
        Command::Train { data, format, ndc, contract, appearance, refine_cameras, config, preset, downscale, iters, time_budget_min, seed, out, serve, host, port, viewer, snapshot_every } => {
            let mut cfg = match &config {
                Some(path) => TrainConfig::from_toml_file(path, preset)?,
                None => preset.unwrap_or(Preset::DEFAULT).config(),
            };
            cfg.appearance |= appearance;
            cfg.refine_cameras |= refine_cameras;
            if let Some(seed) = seed {
                cfg.seed = seed;
            }
            let opts = TrainOptions { format, data, run: out.clone(), config: cfg, ndc, contract, downscale, time_budget_min, iters, progress };
            let live = if serve {
                if !(snapshot_every.is_finite() && snapshot_every > 0.0) {
                    bail!("--snapshot-every {snapshot_every}: give seconds > 0");
                }
                let url = view::serve_training(&out, &view::ServeArgs { host, port, viewer })?;
                let defaults = nerf::live::SnapshotOptions::default();
                Some((url, nerf::live::SnapshotOptions { every_s: snapshot_every, first_after_s: defaults.first_after_s.min(snapshot_every) }))
            } else {
                None
            };
            let s = train_live(&opts, live.as_ref().map(|l| l.1))?;
            println!(
                "trained {} steps in {:.1} min: train PSNR {:.2} dB{}; run in {}",
                s.steps,
                s.minutes,
                s.train_psnr,
                s.val_psnr.map(|p| format!(", first val view {p:.2} dB")).unwrap_or_default(),
                out.display()
            );
            if let Some((url, _)) = live {
                println!("still serving the viewer at {url} (Ctrl-C to stop)");
                use std::io::Write;
                std::io::stdout().flush().ok();
                view::serve_forever();
            }
        }
        Command::View { run, serve } => view::view(&run, &serve)?,
        Command::Eval { run, data, format, split, downscale, limit, out } => {
            let r = eval(&run, &SplitChoice { dir: data, format, split, downscale }, limit, &out, progress)?;
            println!("{} views: {}; {}", r.per_image.len(), scores(&r), out.join("metrics.json").display());
        }
        Command::Plot { runs, out } => {
            nerf::plot::plot_runs(&runs, &out)?;
            println!("{} run{} plotted: {}", runs.len(), if runs.len() == 1 { "" } else { "s" }, out.display());
        }
        Command::Render { run, orbit, frames, split, data, format, downscale, camera_path, out, npy, shard, skip_existing, merge } => {
            if merge {
                println!("{}", nerf_core::frames::merge::merge_shards(&out)?.summary(&out, Shard::WHOLE));
                return Ok(());
            }
            let views = match (orbit, split, data, camera_path) {
                (true, None, _, None) => RenderViews::Orbit { frames, downscale },
                (false, Some(split), Some(data), None) => RenderViews::Split(SplitChoice { dir: data, format, split, downscale }),
                (false, None, _, Some(file)) => RenderViews::CameraPath { file, downscale },
                (false, Some(_), None, _) => bail!("--split needs --data <scene dir>"),
                _ => bail!("say what to render: --orbit, --camera-path <camera_path.json>, or --split <val|test> --data <scene dir>"),
            };
            let run = run.context("--run <run dir> is needed")?;
            let plan = FramePlan { shard: shard.unwrap_or(Shard::WHOLE), skip_existing, ..FramePlan::default() };
            let report = render_views(&run, &views, &out, npy, &plan, progress)?;
            println!("{}", report.summary(&out, plan.shard));
        }
        Command::ProcessData { images, video, frames, sharpest_of, colmap_model, camera_model, matcher, vocab_tree, aabb_scale, keep_colmap_coords, downscales, out } => {
            use nerf::process_data::{convert_colmap, process_images, process_video, tools::{ColmapOptions, Matcher}, FrameOptions, OutputOptions};
            use nerf_core::dataset::colmap::Coordinates;
            limits_frames(frames, sharpest_of)?;
            if !(1..=128).contains(&aabb_scale) {
                bail!("--aabb-scale {aabb_scale}: give 1 to 128 (instant-ngp uses powers of two)");
            }
            let coordinates = if keep_colmap_coords { Coordinates::Colmap } else { Coordinates::InstantNgp { aabb_scale } };
            let output = OutputOptions { coordinates, downscales, progress };
            let colmap = |default| ColmapOptions { camera: camera_model, matcher: matcher.unwrap_or(default), vocab_tree: vocab_tree.clone() };
            let p = match (images, video, colmap_model) {
                (Some(images), _, Some(model)) => convert_colmap(&model, &images, &out, &output)?,
                (Some(images), _, None) => process_images(&images, &out, &colmap(Matcher::Exhaustive), &output)?,
                (None, Some(video), _) => process_video(&video, FrameOptions { count: frames, sharpest_of }, &out, &colmap(Matcher::Sequential), &output)?,
                (None, None, _) => bail!("say what to process: --images DIR or --video FILE"),
            };
            println!("{} of {} images registered (model {}): {}", p.registered, p.images, p.model.display(), out.join("transforms.json").display());
            if (p.registered as f64) < nerf::process_data::WARN_REGISTERED * p.images as f64 {
                eprintln!("warning: {} images were not registered: {}", p.dropped.len(), p.dropped.join(", "));
            }
            if !p.downscaled.is_empty() {
                let folders: Vec<String> = p.downscaled.iter().map(|f| format!("images_{f}/")).collect();
                println!("shrunk copies: {} (read by nerf train --downscale N)", folders.join(", "));
            }
            println!("train with: nerf train --data {} --out <run-dir>", out.display());
        }
        Command::Export { run, bundle, out, opset, portable, tables, appearance } => {
            if appearance.is_some() && run.is_none() {
                bail!("--appearance picks one of a run's codes: give --run (a bundle holds one code already)");
            }
            let appearance = appearance.as_deref().map(nerf_bundle::scene::FixedAppearance::parse);
            let tables = tables.map(|t| match t {
                Tables::F32 => nerf_export::TablePrecision::F32,
                Tables::F16 => nerf_export::TablePrecision::F16,
            });
            let options = nerf_export::CompileOptions { opset, portable, tables: tables.unwrap_or_default() };
            let files = match (run, bundle) {
                (Some(run), _) => nerf::export::export_run(&run, &out, &options, appearance.as_ref())?,
                (None, Some(bundle)) => nerf::export::export_bundle(&bundle, &out, &options, tables)?,
                (None, None) => unreachable!("clap requires --run or --bundle"),
            };
            for f in &files {
                println!("{:>10} bytes  {}", f.bytes, f.path.display());
            }
        }
        Command::Import { source: ImportSource::NerfPytorch { checkpoint, args, data, out, opset } } => {
            let opts = nerf_export::field::mlp::import::NerfPytorchImport { checkpoint, args, data };
            let imported = nerf_export::field::mlp::import::import_nerf_pytorch(&opts)?;
            let b = &imported.bundle;
            let a = &imported.args;
            let fine = if a.n_importance > 0 { format!("{}×{}", a.netdepth_fine, a.netwidth_fine) } else { "none".into() };
            let (s, k) = (&b.scene.sampling, &b.scene.camera.camera);
            println!(
                "nerf-pytorch run ({}): coarse {}, fine {}, {} + {} samples; camera {}×{}, focal {:.2}, {} test poses from {}",
                imported.args_file.display(),
                format!("{}×{}", a.netdepth, a.netwidth),
                fine,
                s.n_coarse,
                s.n_fine,
                k.width,
                k.height,
                k.fx,
                b.scene.poses.test.len(),
                imported.data.display()
            );
            for f in nerf_export::write_bundle(&out, b, &nerf_export::CompileOptions { opset: Some(opset), ..Default::default() })? {
                println!("{:>10} bytes  {}", f.bytes, f.path.display());
            }
        }
        Command::Mesh { run, bundle, out, resolution, threshold, bound, keep_cavities, data, no_carve } => {
            use nerf_core::mesh::carve::CarveViews;
            let request = nerf_core::mesh::MeshRequest { resolution, threshold, bound, keep_cavities };
            let carve = match (no_carve, data) {
                (true, _) => CarveViews::Off,
                (false, Some(data)) => CarveViews::Data(data),
                (false, None) => CarveViews::Own,
            };
            let m = match (run, bundle) {
                (Some(run), _) => nerf::mesh::mesh_run(&run, &out, &request, &carve, progress)?,
                (None, Some(bundle)) => nerf_runtime::mesh::mesh_bundle(&bundle, &out, &request, &carve, None, progress)?,
                (None, None) => bail!("say what to mesh: --run RUN or --bundle BUNDLE"),
            };
            let (report, options) = (&m.report, &m.options);
            println!("{}", m.carving);
            println!(
                "{} vertices, {} triangles at σ = {} on {}³ cells over ±{} ({:?} box); {} of {} lattice points evaluated, {} empty ones filled, largest σ {:.1}: {}",
                report.vertices,
                report.faces,
                options.threshold,
                options.resolution,
                options.bound,
                m.bound_from,
                report.evaluated,
                report.nodes,
                report.filled,
                report.max_density,
                out.display()
            );
        }
        Command::Bench(options) => bench::run(&options, progress)?,
        Command::Demo { out, minutes } => demo(out, minutes, progress)?,
    }
    Ok(())
}

fn demo(out: PathBuf, minutes: f64, progress: bool) -> Result<()> {
    let start = Instant::now();
    let scene = out.join("scene");
    let scene_cfg = SyntheticSceneConfig::default();
    println!("generating a {}×{} scene in {}", scene_cfg.width, scene_cfg.height, scene.display());
    generate_scene(&scene, &scene_cfg).with_context(|| format!("generating {}", scene.display()))?;
    let run = out.join("run");
    let mut config = Preset::CpuFast.config();
    config.iters = 100_000;
    config.eval_every_min = 0.0;
    config.lr_decay_ksteps = 2.0;
    println!("training for {minutes} min (preset cpu-fast) into {}", run.display());
    let opts = TrainOptions { format: None, data: scene.clone(), run: run.clone(), config, ndc: None, contract: None, downscale: 1, time_budget_min: Some(minutes), iters: None, progress };
    let s = train(&opts)?;
    println!("trained {} steps, train PSNR {:.2} dB", s.steps, s.train_psnr);
    let eval_dir = out.join("eval");
    let r = eval(&run, &SplitChoice { dir: scene.clone(), format: None, split: CaptureSplit::Val, downscale: 1 }, None, &eval_dir, progress)?;
    let orbit_dir = out.join("orbit");
    let gif = render_orbit(&run, nerf_core::camera::ORBIT_FRAMES, 1, &orbit_dir, false, progress)?;
    println!("\ndemo done in {:.1} min", start.elapsed().as_secs_f64() / 60.0);
    println!("  val {} over {} views: {}", scores(&r), r.per_image.len(), eval_dir.join("metrics.json").display());
    println!("  renders and depth maps: {}", eval_dir.display());
    println!("  orbit: {}", gif.display());
    Ok(())
}

/// An evaluation's means as `nerf eval` and `nerf demo` print them: "PSNR 24.77 dB, SSIM 0.8641,
/// LPIPS 0.0583" (LPIPS where it was computed).
fn scores(r: &nerf_core::render::metrics::EvalReport) -> String {
    let lpips = r.lpips_mean.map(|l| format!(", LPIPS {l:.4}")).unwrap_or_default();
    format!("PSNR {:.2} dB, SSIM {:.4}{lpips}", r.psnr_mean, r.ssim_mean)
}
