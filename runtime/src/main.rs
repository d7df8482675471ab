//! `nerf-render`: render an exported scene bundle through onnxruntime (no burn).

use anyhow::{Result, bail};
use clap::Parser;
use nerf_core::PinholeCamera;
use nerf_core::camera::Pose;
use nerf_core::SceneTransform;
use nerf_core::dataset::{Background, CaptureFormat, CaptureSplit};
use nerf_core::frames::camera_path::CameraPathFile;
use nerf_core::frames::spec::{FrameSpec, Shard};
use nerf_core::frames::views::{Images, SplitChoice, named_views, orbit_poses, split_views};
use nerf_core::frames::write::{FrameOutput, FramePlan, render_frames_with};
use nerf_core::io::limits::{self, Origin};
use nerf_runtime::{OpenOptions, OrtScene, network::POINTS_PER_RUN};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Parser)]
#[command(group(clap::ArgGroup::new("viewer_use").args(["serve", "export_site"])))]
#[command(
    name = "nerf-render",
    version,
    about = "Render a NeRF scene bundle (nerf export) through onnxruntime",
    after_help = "onnxruntime is loaded from $ORT_DYLIB_PATH, else from the wheel that scripts/setup.sh installs \
                  under ~/.cache/nerf-rs/venv (override the root with $NERF_HOME); with --device cuda, first from \
                  ~/.cache/nerf-rs/venv-gpu (scripts/setup.sh --gpu)."
)]
struct Cli {
    /// Bundle directory: scene.json, coarse.onnx and fine.onnx (NeRF MLPs) or field.onnx (a
    /// hash-grid field), [occupancy.bin].
    #[arg(long, required_unless_present = "merge")]
    bundle: Option<PathBuf>,
    /// Render the bundle's 360° orbit (scene.json poses.orbit) and orbit.gif.
    #[arg(long, conflicts_with = "split")]
    orbit: bool,
    /// Serve the browser viewer and the bundle over HTTP (onnxruntime-web in the page) and
    /// print the URL to open; runs until interrupted.
    #[arg(long, conflicts_with_all = ["orbit", "split"])]
    serve: bool,
    /// Address to serve on (default 127.0.0.1: this machine only).
    #[arg(long, requires = "serve", default_value = "127.0.0.1")]
    host: std::net::IpAddr,
    /// Port to serve on (0: any free port).
    #[arg(long, requires = "serve", default_value_t = 8000)]
    port: u16,
    /// When the bundle does not load, serve the viewer anyway with nothing of the bundle but
    /// its scene.json, so that the page shows why (without it, --serve refuses such a folder).
    #[arg(long, requires = "serve")]
    show_bundle_error: bool,
    /// The built viewer's directory (default: $NERF_VIEWER, else ~/.cache/nerf-rs/viewer, where
    /// scripts/setup.sh installs it).
    #[arg(long, requires = "viewer_use")]
    viewer: Option<PathBuf>,
    /// Write the viewer and the bundle into DIR (new or empty), a folder any static host serves
    /// (its service worker supplies the isolation headers for onnxruntime's threads).
    #[arg(long, value_name = "DIR", conflicts_with_all = ["orbit", "split", "serve", "camera_path", "shard", "skip_existing", "out"])]
    export_site: Option<PathBuf>,
    /// Orbit frames (default: the bundle's orbit; another count renders the same path with
    /// that many frames: around a capture's cameras, else the reference orbit, radius 4,
    /// elevation −30°).
    #[arg(long, requires = "orbit")]
    frames: Option<usize>,
    /// Render this split's views (train, val, test or all): from --data (with metrics.json
    /// when its images exist), or the bundle's own test poses when --data is not given (test
    /// only).
    #[arg(long)]
    split: Option<CaptureSplit>,
    /// Dataset directory (Blender, instant-ngp/nerfstudio or LLFF; a capture's poses go
    /// through the bundle's recorded placement).
    #[arg(long, requires = "split")]
    data: Option<PathBuf>,
    /// The dataset's format: blender, instant-ngp or llff (default: detected).
    #[arg(long, requires = "data")]
    format: Option<CaptureFormat>,
    /// Image downscale factor for --data (use the one the scene was trained at).
    #[arg(long, default_value_t = 1)]
    downscale: u32,
    /// Only the first K views.
    #[arg(long)]
    limit: Option<usize>,
    /// Output directory.
    #[arg(long, required_unless_present_any = ["serve", "export_site"])]
    out: Option<PathBuf>,
    /// Threads (onnxruntime sessions side by side, and the compositing; default: one per core).
    #[arg(long)]
    threads: Option<usize>,
    /// The most points one onnxruntime call evaluates (small pieces keep a hash grid's
    /// intermediates in cache; measured fastest near the default).
    #[arg(long, default_value_t = POINTS_PER_RUN)]
    points_per_run: usize,
    /// Rays marched together, their samples evaluated in one field call per round (16 per ray
    /// when marching, all of them on the dense path): memory is bounded by this, not by the
    /// image size (default: 4096 on the CPU, 262,144 on a GPU; fewer where a call would pass
    /// 4,194,304 points).
    #[arg(long)]
    chunk: Option<usize>,
    /// Render at this width (focal scales with it; height keeps the aspect unless given).
    #[arg(long)]
    width: Option<u32>,
    /// Render at this height (needs --width).
    #[arg(long, requires = "width")]
    height: Option<u32>,
    /// Ignore the bundle's occupancy grid: evaluate every sample (the dense 64 + 128 path; a
    /// hash-grid field marches every interval of its box).
    #[arg(long)]
    dense: bool,
    /// Run a hash-grid bundle's whole graph in onnxruntime, as other consumers do (default: the
    /// hash encoding in Rust, only the MLPs in onnxruntime; same pixels, faster on a CPU).
    #[arg(long)]
    whole_graph: bool,
    /// Where onnxruntime runs the graphs: cpu, or cuda / cuda:N (GPU N; needs the onnxruntime-gpu
    /// library: `bash scripts/setup.sh --gpu`). On a GPU the whole graph runs there.
    #[arg(long, default_value = "cpu", conflicts_with = "serve")]
    device: nerf_runtime::environment::Device,
    /// With --device cuda and an occupancy grid: march and composite on the GPU too (kernels
    /// compiled by NVRTC from the CUDA 13 libraries, the field evaluated where its inputs lie).
    /// Not yet measured on a GPU, so not the default.
    #[arg(long)]
    gpu_loop: bool,
    /// Also write <name>.npy per frame: float32 [H, W, 5] = r, g, b, depth, acc.
    #[arg(long)]
    npy: bool,
    /// Render a nerfstudio camera path (camera_path.json: render_width, render_height, seconds,
    /// camera_path[] of camera_to_world and fov; perspective cameras; poses in the coordinates
    /// of the capture, mapped through the bundle's placement): frame_00000.png, … and
    /// camera_path.gif (--width/--height resize it).
    #[arg(long, conflicts_with_all = ["orbit", "split", "serve"])]
    camera_path: Option<PathBuf>,
    /// Render only shard I of N (0-based): the I-th of N contiguous ranges of the frames, into
    /// --out shared by all shards; assemble them with --merge once every shard is done.
    #[arg(long, value_name = "I/N", conflicts_with = "serve")]
    shard: Option<Shard>,
    /// Keep the frames --out already holds (PNG and depth map, and .npy with --npy; with ground
    /// truth, also their recorded metrics) instead of rendering them again.
    #[arg(long, conflicts_with = "serve")]
    skip_existing: bool,
    /// Assemble a render made in shards once all are done: the GIF, metrics.json and the
    /// contact sheet in --out (checks every shard and frame is there; writes nothing if not).
    #[arg(long, conflicts_with_all = ["bundle", "orbit", "split", "serve", "camera_path", "shard", "skip_existing"])]
    merge: bool,
}

fn main() {
    if let Err(e) = run(Cli::parse()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn resize(k: PinholeCamera, width: Option<u32>, height: Option<u32>) -> Result<PinholeCamera> {
    let Some(w) = width else { return Ok(k) };
    let h = height.map_or((w as u64 * k.height as u64 + k.width as u64 / 2) / k.width as u64, u64::from);
    limits::check_image_size(w as u64, h, Origin::Option("--width/--height"))?;
    Ok(k.resized(w, h as u32))
}

fn run(cli: Cli) -> Result<()> {
    if cli.merge {
        let out = cli.out.clone().expect("clap requires --out without --serve");
        println!("{}", nerf_core::frames::merge::merge_shards(&out)?.summary(&out, Shard::WHOLE));
        return Ok(());
    }
    let bundle = cli.bundle.clone().expect("clap requires --bundle without --merge");
    let viewer = || cli.viewer.clone().or_else(nerf_runtime::serve::viewer_dir).ok_or_else(|| anyhow::anyhow!("no viewer directory: set --viewer or $NERF_VIEWER"));
    if let Some(dir) = &cli.export_site {
        let files = nerf_runtime::serve::bundle_files(&bundle)?;
        let site = nerf_runtime::serve::Site::new(&viewer()?, files)?;
        let exported = nerf_runtime::site::export_site(&site, dir)?;
        if !exported.service_worker {
            eprintln!("warning: the viewer has no {}: on a static host it runs onnxruntime on one thread (rebuild it: bash scripts/setup.sh)", nerf_runtime::site::SERVICE_WORKER);
        }
        println!("site: {} ({} files, {:.1} MB); serve the folder with any static server, e.g. python3 -m http.server -d {}", dir.display(), exported.files, exported.bytes as f64 / 1e6, dir.display());
        return Ok(());
    }
    if cli.serve {
        let viewer = viewer()?;
        let files = match nerf_runtime::serve::bundle_files(&bundle) {
            Ok(files) => files,
            Err(e) if cli.show_bundle_error && bundle.is_dir() => {
                eprintln!("warning: {e}");
                match nerf_runtime::serve::scene_file(&bundle) {
                    Ok(scene) => {
                        eprintln!("serving nothing of the bundle but its scene.json, so that the page shows why it does not load");
                        vec![(nerf_bundle::SCENE_FILE.to_string(), scene)]
                    }
                    Err(e) => {
                        eprintln!("warning: {e}: serving nothing of the bundle (the page will say that scene.json is not found)");
                        Vec::new()
                    }
                }
            }
            Err(e) if bundle.is_dir() => bail!("{e}\n(nothing is served; --show-bundle-error serves the viewer with this folder's scene.json alone, so that the page shows why)"),
            Err(e) => return Err(e.into()),
        };
        let site = nerf_runtime::serve::Site::new(&viewer, files)?;
        return Ok(nerf_runtime::serve::serve(site, cli.host, cli.port)?);
    }
    let out = cli.out.clone().expect("clap requires --out without --serve or --export-site");
    if let Some(n) = cli.threads {
        limits::check_count(n, limits::MAX_THREADS, "threads", Origin::Option("--threads"))?;
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global()?;
    }
    if cli.gpu_loop && cli.device == nerf_runtime::environment::Device::Cpu {
        bail!("--gpu-loop runs the loop around the field on a GPU: it needs --device cuda (or cuda:N)");
    }
    let options = OpenOptions { threads: cli.threads, points_per_run: cli.points_per_run, chunk: cli.chunk, skip_empty_space: !cli.dense, whole_graph: cli.whole_graph, device: cli.device, gpu_loop: cli.gpu_loop };
    let mut scene = OrtScene::open(&bundle, &options)?;
    let transform = scene.description.placement.as_ref().map_or_else(SceneTransform::identity, |p| p.transform);
    let mut gif = cli.orbit.then(|| FramePlan::default().gif);
    let mut frames = match (cli.orbit, cli.split, &cli.data) {
        _ if cli.camera_path.is_some() => {
            let path = CameraPathFile::read(cli.camera_path.as_deref().expect("matched Some"))?;
            gif = Some(path.gif());
            let mut specs = path.frames(&transform, scene.camera(None).pixel_center);
            for f in &mut specs {
                f.camera = resize(f.camera, cli.width, cli.height)?;
            }
            specs
        }
        (true, _, _) => {
            if let Some(n) = cli.frames {
                limits::check_count(n, limits::MAX_FRAMES, "frames", Origin::Option("--frames"))?;
            }
            // The bundle's own orbit, unless another frame count asks for the same path anew.
            let poses = match cli.frames {
                Some(n) if n != scene.description.poses.orbit.len() => orbit_poses(scene.description.placement.as_ref().and_then(|p| p.orbit.as_ref()), n),
                _ => scene.orbit_poses()?,
            };
            if poses.is_empty() {
                bail!("the orbit has no frames");
            }
            FrameSpec::orbit(&resize(scene.camera(None), cli.width, cli.height)?, &poses)
        }
        (false, Some(split), Some(data)) => {
            let background = Background::from_white(scene.description.white_background);
            let choice = SplitChoice { dir: data.clone(), format: cli.format, split, downscale: cli.downscale };
            let mut specs = split_views(&choice, transform, background, Images::IfPresent)?;
            if cli.width.is_some() {
                for f in &mut specs {
                    f.camera = resize(f.camera, cli.width, cli.height)?;
                    f.target = None; // ground truth is at the dataset's resolution
                }
            }
            specs
        }
        (false, Some(CaptureSplit::Test), None) => {
            let k = resize(scene.camera(None), cli.width, cli.height)?;
            named_views(&k, scene.description.poses.test.iter().map(|p| (p.name.as_str(), Pose::from_rows(p.transform_matrix))))
        }
        (false, Some(_), None) => bail!("--split val/train needs --data <scene dir> (the bundle only stores test poses)"),
        (false, None, _) => bail!("say what to render: --orbit, --camera-path <camera_path.json>, or --split <val|test> [--data <scene dir>]"),
    };
    frames.truncate(cli.limit.unwrap_or(usize::MAX));
    if frames.is_empty() {
        bail!("nothing to render: no poses");
    }
    let s = &scene.options.sampling;
    let output = FrameOutput { dir: out.clone(), depth_range: (s.near, s.far), gif: gif.is_some(), raw: cli.npy, progress: std::io::stderr().is_terminal() };
    let plan = FramePlan { shard: cli.shard.unwrap_or(Shard::WHOLE), skip_existing: cli.skip_existing, gif: gif.unwrap_or_else(|| FramePlan::default().gif) };
    let first = frames[0].camera;
    let start = Instant::now();
    let report = render_frames_with(frames, &output, &plan, |f, progress| scene.render(&f.camera, &f.pose, progress))?;
    let seconds = start.elapsed().as_secs_f64();
    let n = report.frames - report.skipped;
    println!(
        "{n} frames rendered at {}×{} in {seconds:.1} s ({:.2} s per frame, {}{}{})",
        first.width,
        first.height,
        seconds / n.max(1) as f64,
        if scene.occupancy.is_some() { "empty space skipped" } else { "dense sampling" },
        if scene.field.graphs.iter().any(|(_, g)| g.encoding() == nerf_runtime::network::Encoding::Rust) { ", hash encoding in Rust" } else { "" },
        if cli.device == nerf_runtime::environment::Device::Cpu { String::new() } else { format!(", on {}", cli.device) },
    );
    println!("{}", report.summary(&out, plan.shard));
    Ok(())
}
