//! Importing models trained elsewhere into scene bundles. nerf-pytorch
//! (yenchenlin/nerf-pytorch): its checkpoint (`NNNNNN.tar`) and its run's `args.txt` or
//! `config.txt` become a [`Bundle`] that renders as nerf-pytorch renders at test time
//! (perturb 0, raw_noise_std 0), read without Python or PyTorch.
//!
//! The conventions already agree (rays without a half-pixel offset, OpenGL camera-to-world,
//! `[x, sin(2ᵏx), cos(2ᵏx)]` encodings, skips as `[input, h]`, ReLU density, `sample_pdf` on
//! `weights[1:-1]` with `det = True`, white background as `rgb + 1 − acc`), so importing is a
//! mapping of names and layouts ([`checkpoint`]) plus the run's sampling and camera (LLFF runs:
//! its poses, bounds and NDC rays, through the same LLFF parser and NDC warp as `nerf train`).

pub mod args;
pub mod checkpoint;

use crate::ExportError;
use crate::bundle::Bundle;
use nerf_bundle::scene::{NamedPose, SceneDescription, pose_matrix};
use nerf_core::field::PlainField;
use nerf_core::field::mlp::PlainMlp;
use args::NerfPytorchArgs;
use checkpoint::{ExpectedNetwork, MappingError, read_checkpoint, to_plain_network};
use nerf_core::PinholeCamera;
use nerf_core::camera::{ORBIT_FRAMES, Pose};
use nerf_core::dataset::{CameraPath, CaptureFormat, ScenePlacement, Split, SpiralPath, load_llff_images, load_split};
use nerf_core::camera::ndc::Ndc;
use nerf_core::field::mlp::EncodingSpec;
use nerf_core::sample::stratified::SamplingConfig;
use std::path::{Path, PathBuf};

/// nerf-pytorch's near and far bounds for Blender scenes.
pub const BLENDER_NEAR_FAR: (f32, f32) = (2.0, 6.0);

/// Why a model could not be imported. Nothing is written when any of these is returned.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// The checkpoint cannot be read, or is not a nerf-pytorch checkpoint.
    #[error("{}: {message}", path.display())]
    Checkpoint {
        /// The checkpoint.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The run's settings file cannot be read or parsed.
    #[error("{}: {message}", path.display())]
    Args {
        /// `args.txt` / `config.txt`.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A setting the bundle format cannot express.
    #[error("{}: {setting} = {value} is not supported: {why}", path.display())]
    Unsupported {
        /// The settings file.
        path: PathBuf,
        /// The setting's name in nerf-pytorch.
        setting: &'static str,
        /// Its value.
        value: String,
        /// Why.
        why: String,
    },
    /// The checkpoint disagrees with the settings (or lacks a layer).
    #[error("{} does not match {}: {message}", checkpoint.display(), args.display())]
    Mismatch {
        /// The checkpoint.
        checkpoint: PathBuf,
        /// The settings file.
        args: PathBuf,
        /// The disagreeing setting, when one does.
        setting: Option<&'static str>,
        /// What is wrong.
        message: String,
    },
    /// The dataset (camera and test poses) is missing or unreadable.
    #[error("{0}")]
    Data(String),
    /// The bundle could not be compiled or written.
    #[error(transparent)]
    Export(#[from] ExportError),
}

impl ImportError {
    pub(crate) fn args(path: &Path, message: String) -> Self {
        ImportError::Args { path: path.to_path_buf(), message }
    }
}

/// What to import.
#[derive(Debug, Clone, PartialEq)]
pub struct NerfPytorchImport {
    /// The checkpoint, `<run>/NNNNNN.tar`.
    pub checkpoint: PathBuf,
    /// `args.txt` or `config.txt`; default: `args.txt` beside the checkpoint, else `config.txt`.
    pub args: Option<PathBuf>,
    /// The scene the run was trained on, Blender or LLFF (camera, test poses); default: the run's
    /// `datadir` when it exists here.
    pub data: Option<PathBuf>,
}

/// An imported model, ready for [`crate::write_bundle`].
#[derive(Debug, Clone)]
pub struct Imported {
    /// The networks, sampling, camera and poses.
    pub bundle: Bundle,
    /// The settings file that was read.
    pub args_file: PathBuf,
    /// The scene the camera and test poses came from.
    pub data: PathBuf,
    /// The settings read from it.
    pub args: NerfPytorchArgs,
}

/// The settings file of a run: `explicit`, else `args.txt`, else `config.txt` beside the checkpoint.
fn find_args(checkpoint: &Path, explicit: Option<&Path>) -> Result<PathBuf, ImportError> {
    if let Some(p) = explicit {
        return Ok(p.to_path_buf());
    }
    let dir = checkpoint.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    ["args.txt", "config.txt"].iter().map(|f| dir.join(f)).find(|p| p.is_file()).ok_or_else(|| {
        ImportError::args(&dir.join("args.txt"), "not found (nor config.txt): give the run's settings with --args <run>/args.txt".into())
    })
}

/// The scene directory: `explicit`, else the run's `datadir` when it holds the run's kind of
/// scene here (Blender `transforms_test.json`, LLFF `poses_bounds.npy`).
fn find_data(explicit: Option<&Path>, args: &NerfPytorchArgs) -> Result<PathBuf, ImportError> {
    if let Some(p) = explicit {
        return Ok(p.to_path_buf());
    }
    let (marker, kind) = if args.dataset_type == "llff" { ("poses_bounds.npy", "LLFF capture") } else { ("transforms_test.json", "Blender scene") };
    match &args.datadir {
        Some(d) if Path::new(d).join(marker).is_file() => Ok(PathBuf::from(d)),
        other => Err(ImportError::Data(format!(
            "the camera (image size, focal) and the test poses come from the dataset: give --data <scene dir>, the {kind} \
             the model was trained on{}",
            other.as_ref().map(|d| format!(" (the run's datadir {d} is not a {kind} here)")).unwrap_or_default()
        ))),
    }
}

/// The scene of a Blender run: nerf-pytorch's near/far 2, 6, the test split's camera (halved
/// with `half_res`) and poses, the reference orbit.
fn blender_scene(data: &Path, args: &NerfPytorchArgs) -> Result<SceneDescription, ImportError> {
    // nerf-pytorch halves the images (and the focal) with half_res.
    let downscale = if args.half_res { 2 } else { 1 };
    let test = load_split(data, Split::Test, downscale, false).map_err(|e| ImportError::Data(e.to_string()))?;
    let camera: PinholeCamera = test.camera().ok_or_else(|| ImportError::Data(format!("{}: the test split has no views", data.display())))?;
    let (near, far) = BLENDER_NEAR_FAR;
    let sampling = SamplingConfig { near, far, n_coarse: args.n_samples, n_fine: args.n_importance, lindisp: args.lindisp, ndc: None };
    let mut scene = SceneDescription::new(&camera, &sampling, args.white_bkgd, nerf_core::render::DEFAULT_MARCH_STEPS);
    scene.poses.orbit = Pose::orbit(ORBIT_FRAMES).iter().map(pose_matrix).collect();
    scene.poses.test = test.views.iter().map(|v| NamedPose { name: v.name.clone(), transform_matrix: pose_matrix(&v.pose) }).collect();
    Ok(scene)
}

/// The scene of an LLFF run, as nerf-pytorch's `load_llff_data(factor, recenter=True,
/// bd_factor=.75, spherify=False)` and `train()` set it up: the images of `images_<factor>`
/// (else `images/`), poses recentred and scaled, NDC rays with near plane 1 over t in [0, 1]
/// (lindisp ignored, as nerf-pytorch ignores it there) or, with `no_ndc`, near/far = 0.9 · the
/// smallest bound and the largest; test views every `llffhold`-th image; the spiral path.
fn llff_scene(data: &Path, args: &NerfPytorchArgs) -> Result<SceneDescription, ImportError> {
    let factored = format!("images_{}", args.factor);
    let images = if args.factor > 1 && data.join(&factored).is_dir() { factored.as_str() } else { "images" };
    let capture = load_llff_images(data, images).map_err(|e| ImportError::Data(e.to_string()))?;
    let camera = capture.views[0].camera;
    let bounds = capture.near_far.ok_or_else(|| ImportError::Data(format!("{}: no depth bounds", capture.source.display())))?;
    let (near, far, ndc, lindisp) = if args.no_ndc { (bounds.0, bounds.1, None, args.lindisp) } else { (0.0, 1.0, Some(Ndc::for_camera(&camera, 1.0)), false) };
    let sampling = SamplingConfig { near, far, n_coarse: args.n_samples, n_fine: args.n_importance, lindisp, ndc };
    let mut scene = SceneDescription::new(&camera, &sampling, args.white_bkgd, nerf_core::render::DEFAULT_MARCH_STEPS);
    let spiral = SpiralPath::around(&capture.poses(), bounds.0, bounds.1).map(CameraPath::Spiral);
    scene.poses.orbit = spiral.map(|p| p.poses(ORBIT_FRAMES)).unwrap_or_default().iter().map(pose_matrix).collect();
    // nerf-pytorch's i_test = np.arange(N)[::llffhold].
    scene.poses.test = (0..capture.views.len())
        .step_by(args.llffhold)
        .map(|k| NamedPose { name: capture.views[k].name.clone(), transform_matrix: pose_matrix(&capture.views[k].pose) })
        .collect();
    scene.placement = Some(ScenePlacement { format: CaptureFormat::Llff, transform: capture.transform, near_far: Some((near, far)), orbit: spiral, ndc });
    Ok(scene)
}

/// Read a nerf-pytorch run and build its bundle (nothing is written).
pub fn import_nerf_pytorch(opts: &NerfPytorchImport) -> Result<Imported, ImportError> {
    let args_file = find_args(&opts.checkpoint, opts.args.as_deref())?;
    let args = NerfPytorchArgs::read(&args_file)?;
    args.check_supported()
        .map_err(|(setting, value, why)| ImportError::Unsupported { path: args_file.clone(), setting, value, why })?;
    let nets = read_checkpoint(&opts.checkpoint)
        .map_err(|message| ImportError::Checkpoint { path: opts.checkpoint.clone(), message })?;

    let mismatch = |e: MappingError| ImportError::Mismatch {
        checkpoint: opts.checkpoint.clone(),
        args: args_file.clone(),
        setting: e.setting,
        message: e.message,
    };
    let encoding = |l: usize| EncodingSpec { n_frequencies: l, include_input: true };
    let expected = |depth, width| ExpectedNetwork {
        depth,
        width,
        position: encoding(args.multires),
        direction: encoding(args.multires_views),
        use_viewdirs: args.use_viewdirs,
    };
    let coarse = to_plain_network(&nets.coarse, &expected(args.netdepth, args.netwidth), false)
        .map_err(|e| mismatch(MappingError { message: format!("{}: {}", checkpoint::COARSE_KEY, e.message), ..e }))?;
    let fine = match (args.n_importance, nets.fine.is_empty()) {
        (0, _) => None,
        (n, true) => {
            return Err(mismatch(MappingError {
                setting: Some("N_importance"),
                message: format!("N_importance = {n} but the checkpoint has no {}", checkpoint::FINE_KEY),
            }));
        }
        (_, false) => Some(
            to_plain_network(&nets.fine, &expected(args.netdepth_fine, args.netwidth_fine), true)
                .map_err(|e| mismatch(MappingError { message: format!("{}: {}", checkpoint::FINE_KEY, e.message), ..e }))?,
        ),
    };

    let data = find_data(opts.data.as_deref(), &args)?;
    let scene = match args.dataset_type.as_str() {
        "llff" => llff_scene(&data, &args)?,
        _ => blender_scene(&data, &args)?,
    };
    Ok(Imported { bundle: Bundle { field: PlainField::Mlp(PlainMlp { coarse, fine }), scene, occupancy: None }, args_file, data, args })
}
