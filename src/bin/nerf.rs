//! `nerf`: train, evaluate and render neural radiance fields on the CPU.

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use nerf::evaluate::{eval, render_orbit, render_split};
use nerf::train::{Preset, TrainConfig, TrainOptions, train};
use nerf_core::dataset::{Split, SyntheticSceneConfig, generate_scene};
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
    /// Train a NeRF on a Blender-format scene (resumes if <out> holds a checkpoint).
    Train {
        /// Scene directory holding transforms_{train,val,test}.json.
        #[arg(long)]
        data: PathBuf,
        /// TOML file overriding the preset's settings (any subset of the keys of config.toml).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Starting configuration (default: cpu-fast).
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
    },
    /// Render a split's views and compare with its images: PNGs and metrics.json.
    Eval {
        /// Run directory written by `nerf train`.
        #[arg(long)]
        run: PathBuf,
        /// Scene directory.
        #[arg(long)]
        data: PathBuf,
        /// Which views.
        #[arg(long, value_enum, default_value = "val")]
        split: SplitArg,
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
    /// Render a split's poses or a 360° orbit: PNG frames, depth maps, orbit.gif.
    Render {
        /// Run directory written by `nerf train`.
        #[arg(long)]
        run: PathBuf,
        /// Render the reference orbit (radius 4, elevation −30°) at the training resolution.
        #[arg(long)]
        orbit: bool,
        /// Frames in the orbit.
        #[arg(long, default_value_t = 40)]
        frames: usize,
        /// Render this split's poses (needs --data).
        #[arg(long, value_enum)]
        split: Option<SplitArg>,
        /// Scene directory (with --split).
        #[arg(long)]
        data: Option<PathBuf>,
        /// Image downscale factor (with --split).
        #[arg(long, default_value_t = 1)]
        downscale: u32,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Also write <name>.npy per frame: float32 [H, W, 5] = r, g, b, depth, acc.
        #[arg(long)]
        npy: bool,
    },
    /// Compile a trained run into an ONNX scene bundle: coarse.onnx, fine.onnx, scene.json.
    Export {
        /// Run directory written by `nerf train`.
        #[arg(long)]
        run: PathBuf,
        /// Bundle directory to write (replaced only once the new bundle is complete).
        #[arg(long)]
        out: PathBuf,
        /// ONNX opset (17–23).
        #[arg(long, default_value_t = nerf_export::DEFAULT_OPSET)]
        opset: i64,
    },
    /// Measure training-step speed (all figures from one run).
    Bench {
        /// Presets to time (default: cpu-fast and paper).
        #[arg(long, value_enum)]
        preset: Vec<Preset>,
        /// Scene to draw training rays from (default: a generated scene).
        #[arg(long)]
        data: Option<PathBuf>,
        /// Image downscale factor for --data.
        #[arg(long, default_value_t = 4)]
        downscale: u32,
        /// Timed steps per preset (after 2 warm-up steps).
        #[arg(long, default_value_t = 5)]
        steps: usize,
        /// Also write the results as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
    },
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

#[derive(Clone, Copy, clap::ValueEnum)]
enum SplitArg {
    Train,
    Val,
    Test,
}

impl From<SplitArg> for Split {
    fn from(s: SplitArg) -> Split {
        match s {
            SplitArg::Train => Split::Train,
            SplitArg::Val => Split::Val,
            SplitArg::Test => Split::Test,
        }
    }
}

fn err(s: String) -> anyhow::Error {
    anyhow::anyhow!(s)
}

fn main() -> Result<()> {
    nerf::backend::tune_allocator();
    let cli = Cli::parse();
    let progress = std::io::stderr().is_terminal();
    match cli.command {
        Command::Train { data, config, preset, downscale, iters, time_budget_min, seed, out } => {
            let mut cfg = match &config {
                Some(path) => TrainConfig::from_toml_file(path, preset).map_err(err)?,
                None => preset.unwrap_or(Preset::CpuFast).config(),
            };
            if let Some(seed) = seed {
                cfg.seed = seed;
            }
            let opts = TrainOptions { data, run: out.clone(), config: cfg, downscale, time_budget_min, iters, progress };
            let s = train(&opts).map_err(err)?;
            println!(
                "trained {} steps in {:.1} min: train PSNR {:.2} dB{}; run in {}",
                s.steps,
                s.minutes,
                s.train_psnr,
                s.val_psnr.map(|p| format!(", first val view {p:.2} dB")).unwrap_or_default(),
                out.display()
            );
        }
        Command::Eval { run, data, split, downscale, limit, out } => {
            let r = eval(&run, &data, split.into(), downscale, limit, &out, progress).map_err(err)?;
            println!("{} views: PSNR {:.2} dB, SSIM {:.4}; {}", r.per_image.len(), r.psnr_mean, r.ssim_mean, out.join("metrics.json").display());
        }
        Command::Render { run, orbit, frames, split, data, downscale, out, npy } => match (orbit, split, data) {
            (true, None, _) => {
                let gif = render_orbit(&run, frames, &out, npy, progress).map_err(err)?;
                println!("{frames} frames and depth maps in {}; {}", out.display(), gif.display());
            }
            (false, Some(split), Some(data)) => {
                let n = render_split(&run, &data, split.into(), downscale, &out, npy, progress).map_err(err)?;
                println!("{n} views and depth maps in {}", out.display());
            }
            (false, Some(_), None) => bail!("--split needs --data <scene dir>"),
            _ => bail!("say what to render: --orbit, or --split <val|test> --data <scene dir>"),
        },
        Command::Export { run, out, opset } => {
            let files = nerf::export::export_run(&run, &out, opset).map_err(err)?;
            for f in &files {
                println!("{:>10} bytes  {}", f.bytes, f.path.display());
            }
        }
        Command::Bench { preset, data, downscale, steps, json } => {
            let presets = if preset.is_empty() { vec![Preset::CpuFast, Preset::Paper] } else { preset };
            let mut results = Vec::new();
            println!("{:<10} {:>6} {:>9} {:>9} {:>9} {:>9}", "preset", "rays", "step s", "forward", "backward", "update");
            for p in presets {
                let b = nerf::bench::bench_train_step(p, data.as_deref(), downscale, 2, steps).map_err(err)?;
                println!("{:<10} {:>6} {:>9.3} {:>9.3} {:>9.3} {:>9.3}", b.preset, b.batch_rays, b.step_s, b.forward_s, b.backward_s, b.update_s);
                results.push(b);
            }
            if let Some(path) = json {
                let text = serde_json::to_string_pretty(&serde_json::json!({ "train_steps": results }))?;
                nerf_core::error::write_atomic(&path, text.as_bytes()).map_err(|e| err(e.to_string()))?;
            }
        }
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
    let opts = TrainOptions { data: scene.clone(), run: run.clone(), config, downscale: 1, time_budget_min: Some(minutes), iters: None, progress };
    let s = train(&opts).map_err(err)?;
    println!("trained {} steps, train PSNR {:.2} dB", s.steps, s.train_psnr);
    let eval_dir = out.join("eval");
    let r = eval(&run, &scene, Split::Val, 1, None, &eval_dir, progress).map_err(err)?;
    let orbit_dir = out.join("orbit");
    let gif = render_orbit(&run, 40, &orbit_dir, false, progress).map_err(err)?;
    println!("\ndemo done in {:.1} min", start.elapsed().as_secs_f64() / 60.0);
    println!("  val PSNR {:.2} dB, SSIM {:.4} over {} views: {}", r.psnr_mean, r.ssim_mean, r.per_image.len(), eval_dir.join("metrics.json").display());
    println!("  renders and depth maps: {}", eval_dir.display());
    println!("  orbit: {}", gif.display());
    Ok(())
}
