//! Scene bundles: `coarse.onnx` and `fine.onnx` (NeRF MLPs) or `field.onnx` (a hash-grid
//! field), `occupancy.bin` and `scene.json` in one directory, written whole
//! or not at all ([`nerf_core::io::atomic::write_dir_atomic`]): a failed or killed export leaves
//! the previous bundle as it was.

use crate::ExportError;
use crate::graph::{compile, read_network};
use crate::proto::ModelProto;
use nerf_core::PinholeCamera;
use nerf_core::dataset::ScenePlacement;
use nerf_core::camera::Pose;
use nerf_core::io::limits::{self, MAX_FRAMES, Origin};
use crate::hash_grid::HashOps;
use crate::ngp::compile_ngp;
use nerf_core::field::mlp::{EncodingSpec, PlainNetwork};
use nerf_core::field::FieldKind;
use nerf_core::field::ngp::PlainNgp;
use nerf_core::sample::occupancy::{self, OccupancyGrid};
use nerf_core::sample::stratified::SamplingConfig;
use prost::Message;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The `format` of the `scene.json` this version writes.
pub const SCENE_FORMAT: &str = "nerf-rs-scene-1";
/// The scene description's file name.
pub const SCENE_FILE: &str = "scene.json";
/// The camera convention, spelled out for readers of `scene.json`.
pub const CAMERA_CONVENTION: &str = "OpenGL camera-to-world (Blender/NeRF): +x right, +y up, the camera looks along -z; \
     ray through pixel (i, j): o = 0.5 if pixel_center is half_pixel else 0, (xd, yd) = ((i + o - cx)/fx, (j + o - cy)/fy), \
     (x, y) = (xd, yd) with OpenCV distortion (k1, k2, p1, p2) undone (Newton's method), \
     d = c2w[:3,:3] @ (x, -y, -1), not normalised; origin c2w[:3,3]; samples at t in [near, far] along d; viewdirs = d/|d|; \
     with sampling.ndc {width, height, fx, fy, near} the rays are first warped as nerf-pytorch's ndc_rays \
     (t0 = -(near + o_z)/d_z, o += t0·d, o' = (-2fx/W·o_x/o_z, -2fy/H·o_y/o_z, 1 + 2near/o_z), \
     d' = (-2fx/W·(d_x/d_z - o_x/o_z), -2fy/H·(d_y/d_z - o_y/o_z), -2near/o_z)) and samples lie along (o', d'), \
     while viewdirs stay the world d/|d|";

/// The graph file of a hash-grid bundle.
pub const NGP_FILE: &str = "field.onnx";

/// Everything a renderer needs besides the networks (`scene.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneDescription {
    /// [`SCENE_FORMAT`].
    pub format: String,
    /// The training camera.
    pub camera: CameraDescription,
    /// Near/far, samples per ray, lindisp.
    pub sampling: SamplingConfig,
    /// Composite over white: `rgb + (1 − acc)`.
    pub white_background: bool,
    /// What the graphs hold: `mlp` (coarse/fine NeRF networks, sampled densely or marched)
    /// or `ngp` (one hash-grid field graph in `networks.coarse`, only ever marched through the
    /// occupancy grid: the field is defined inside the grid's box alone). Absent: `mlp`.
    #[serde(default)]
    pub field: FieldKind,
    /// Positional encoding of points (inside the graphs; stated for other implementations;
    /// absent for `ngp`, whose encoding is the hash grid in the graph's metadata `nerf.ngp`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_encoding: Option<EncodingDescription>,
    /// Positional encoding of view directions (absent for `ngp`: spherical harmonics of
    /// degree 4 inside the graph).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub direction_encoding: Option<EncodingDescription>,
    /// Marching: equal intervals over [near, far], a sample at each middle where the occupancy
    /// grid is occupied. Absent: 256.
    #[serde(default = "default_march_steps")]
    pub march_steps: usize,
    /// Graph files, relative to the bundle.
    pub networks: NetworkFiles,
    /// Camera-to-world poses to render.
    pub poses: ScenePoses,
    /// The occupancy grid for empty-space skipping (format in [`nerf_core::sample::occupancy`]);
    /// renderers without it sample densely.
    #[serde(default)]
    pub occupancy: Option<OccupancyDescription>,
    /// For a captured scene: its format, the transform from the capture's world into the
    /// field's frame that every pose here already went through (apply it to poses of the
    /// capture's own files: `x' = scale · (rotation · x + translation)`), near/far and the
    /// orbit path. Absent for Blender scenes, which are used as they are.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub placement: Option<ScenePlacement>,
}

fn default_march_steps() -> usize {
    nerf_core::render::DEFAULT_MARCH_STEPS
}

/// Where the occupancy grid is and what it covers (also in the file's header).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OccupancyDescription {
    /// The grid file, relative to the bundle (`occupancy.bin`).
    pub file: String,
    /// Cells per axis.
    pub resolution: usize,
    /// The grid covers [−bound, bound]³.
    pub bound: f32,
}

/// The training camera (the full pinhole model; bundles written before it carry `focal`
/// alone, read as the Blender camera) and the convention rays follow.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraDescription {
    /// Size, focal lengths, principal point, pixel centres, distortion.
    #[serde(flatten)]
    pub camera: PinholeCamera,
    /// [`CAMERA_CONVENTION`].
    pub convention: String,
}

impl CameraDescription {
    /// `camera` with today's convention.
    pub fn new(camera: &PinholeCamera) -> Self {
        CameraDescription { camera: *camera, convention: CAMERA_CONVENTION.into() }
    }
}

/// An encoding `[x, sin(f x), cos(f x) for f in frequencies]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EncodingDescription {
    /// Number of frequencies L.
    pub n_frequencies: usize,
    /// Whether x itself comes first.
    pub include_input: bool,
    /// The frequencies 2ᵏ, k < L.
    pub frequencies: Vec<f32>,
    /// Values per 3-vector.
    pub output_dim: usize,
}

impl From<&EncodingSpec> for EncodingDescription {
    fn from(e: &EncodingSpec) -> Self {
        EncodingDescription {
            n_frequencies: e.n_frequencies,
            include_input: e.include_input,
            frequencies: e.frequencies(),
            output_dim: e.output_dim(),
        }
    }
}

/// Which files hold the networks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NetworkFiles {
    /// The coarse network (stratified samples).
    pub coarse: String,
    /// The fine network (all samples); absent when the scene has none.
    pub fine: Option<String>,
}

/// Poses as row-major 4×4 camera-to-world matrices (the Blender `transform_matrix`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ScenePoses {
    /// The dataset's test views, when the export knew the dataset.
    pub test: Vec<NamedPose>,
    /// The reference 360° orbit (radius 4, elevation −30°).
    pub orbit: Vec<[[f32; 4]; 4]>,
}

/// A dataset view's pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NamedPose {
    /// Image name (`r_0`).
    pub name: String,
    /// Camera-to-world, row-major 4×4.
    pub transform_matrix: [[f32; 4]; 4],
}

/// A pose as a 4×4 row-major matrix.
pub fn pose_matrix(p: &Pose) -> [[f32; 4]; 4] {
    [p.0[0], p.0[1], p.0[2], [0.0, 0.0, 0.0, 1.0]]
}

impl SceneDescription {
    /// A description for networks trained with `sampling` on images from `camera`.
    pub fn new(camera: &PinholeCamera, sampling: &SamplingConfig, white_background: bool, coarse: &PlainNetwork, has_fine: bool) -> Self {
        SceneDescription {
            format: SCENE_FORMAT.into(),
            camera: CameraDescription::new(camera),
            sampling: sampling.clone(),
            white_background,
            field: FieldKind::Mlp,
            position_encoding: Some((&coarse.spec.position_encoding).into()),
            direction_encoding: Some((&coarse.spec.direction_encoding).into()),
            march_steps: default_march_steps(),
            networks: NetworkFiles { coarse: "coarse.onnx".into(), fine: has_fine.then(|| "fine.onnx".into()) },
            poses: ScenePoses::default(),
            occupancy: None,
            placement: None,
        }
    }

    /// A description for a hash-grid field marched with `march_steps` intervals over
    /// `sampling`'s [near, far] (`networks.coarse` = `field.onnx`, no fine network).
    pub fn ngp(camera: &PinholeCamera, sampling: &SamplingConfig, white_background: bool, march_steps: usize) -> Self {
        SceneDescription {
            format: SCENE_FORMAT.into(),
            camera: CameraDescription::new(camera),
            sampling: SamplingConfig { n_fine: 0, ..sampling.clone() },
            white_background,
            field: FieldKind::Ngp,
            position_encoding: None,
            direction_encoding: None,
            march_steps,
            networks: NetworkFiles { coarse: NGP_FILE.into(), fine: None },
            poses: ScenePoses::default(),
            occupancy: None,
            placement: None,
        }
    }
}

/// The networks and description of one scene.
#[derive(Debug, Clone)]
pub struct Bundle {
    /// The coarse network.
    pub coarse: PlainNetwork,
    /// The fine network, if any (must be present exactly when `scene.networks.fine` is).
    pub fine: Option<PlainNetwork>,
    /// `scene.json` (its `occupancy` field is filled in from `occupancy` when writing).
    pub scene: SceneDescription,
    /// The occupancy grid, if the scene was trained with one.
    pub occupancy: Option<OccupancyGrid>,
}



/// A hash-grid field and its description: one graph, the occupancy grid it is marched through.
#[derive(Debug, Clone)]
pub struct NgpBundle {
    /// The field.
    pub field: PlainNgp,
    /// `scene.json` (made by [`SceneDescription::ngp`]; `occupancy` filled in when writing).
    pub scene: SceneDescription,
    /// The grid (required: the field is only marched).
    pub occupancy: OccupancyGrid,
}

/// A file written into a bundle and its size.
#[derive(Debug, Clone, PartialEq)]
pub struct WrittenFile {
    /// Path of the file in its final place.
    pub path: PathBuf,
    /// Size in bytes.
    pub bytes: usize,
}

/// The contract metadata every graph of a scene carries.
fn scene_metadata(scene: &SceneDescription, stage: &str) -> Vec<(String, String)> {
    let s = &scene.sampling;
    let mut metadata = vec![
        ("nerf.stage".into(), stage.into()),
        ("nerf.near".into(), s.near.to_string()),
        ("nerf.far".into(), s.far.to_string()),
        ("nerf.n_coarse".into(), s.n_coarse.to_string()),
        ("nerf.n_fine".into(), s.n_fine.to_string()),
        ("nerf.lindisp".into(), s.lindisp.to_string()),
        ("nerf.white_background".into(), scene.white_background.to_string()),
        ("nerf.camera".into(), CAMERA_CONVENTION.into()),
    ];
    if let Some(n) = &s.ndc {
        let ndc = format!("width {} height {} fx {} fy {} near {}", n.width, n.height, n.fx, n.fy, n.near);
        metadata.push(("nerf.ndc".into(), ndc));
    }
    metadata
}

/// Compile both networks and write the bundle to `dir` (replacing an existing bundle only once
/// the new one is complete).
pub fn write_bundle(dir: &Path, bundle: &Bundle, opset: i64) -> Result<Vec<WrittenFile>, ExportError> {
    let mut scene = bundle.scene.clone();
    scene.occupancy = bundle.occupancy.as_ref().map(|g| OccupancyDescription {
        file: occupancy::FILE_NAME.into(),
        resolution: g.resolution(),
        bound: g.bound(),
    });
    let scene = &scene;
    if scene.networks.fine.is_some() != bundle.fine.is_some() {
        return Err(ExportError::Network("scene.json and the networks disagree about a fine network".into()));
    }
    let mut files: Vec<(String, Vec<u8>)> = vec![(
        scene.networks.coarse.clone(),
        compile(&bundle.coarse, "coarse", opset, &scene_metadata(scene, "coarse"))?.encode_to_vec(),
    )];
    if let (Some(net), Some(name)) = (&bundle.fine, &scene.networks.fine) {
        files.push((name.clone(), compile(net, "fine", opset, &scene_metadata(scene, "fine"))?.encode_to_vec()));
    }
    if let Some(grid) = &bundle.occupancy {
        files.push((occupancy::FILE_NAME.into(), grid.to_bytes()));
    }
    files.push((SCENE_FILE.into(), serde_json::to_vec_pretty(scene).expect("a scene serialises")));
    write_files(dir, files)
}

/// Compile a hash-grid field and write its bundle to `dir` (as [`write_bundle`]): `field.onnx`
/// with BitwiseXor/And at opset ≥ 18, the bitwise-free lowering at opset 17.
pub fn write_ngp_bundle(dir: &Path, bundle: &NgpBundle, opset: i64) -> Result<Vec<WrittenFile>, ExportError> {
    let mut scene = bundle.scene.clone();
    let grid = &bundle.occupancy;
    scene.occupancy = Some(OccupancyDescription { file: occupancy::FILE_NAME.into(), resolution: grid.resolution(), bound: grid.bound() });
    if scene.field != FieldKind::Ngp || scene.networks.fine.is_some() {
        return Err(ExportError::Network("a hash-grid bundle's scene.json must say field \"ngp\" and name no fine network".into()));
    }
    let ops = if opset >= HashOps::Bitwise.min_opset() { HashOps::Bitwise } else { HashOps::Arithmetic };
    let model = compile_ngp(&bundle.field, "field", opset, ops, &scene_metadata(&scene, "field"))?;
    let files = vec![
        (scene.networks.coarse.clone(), model.encode_to_vec()),
        (occupancy::FILE_NAME.into(), grid.to_bytes()),
        (SCENE_FILE.into(), serde_json::to_vec_pretty(&scene).expect("a scene serialises")),
    ];
    write_files(dir, files)
}

/// Write `files` (name, bytes) as the directory `dir`, whole or not at all.
fn write_files(dir: &Path, files: Vec<(String, Vec<u8>)>) -> Result<Vec<WrittenFile>, ExportError> {
    nerf_core::io::atomic::write_dir_atomic(dir, |tmp| {
        for (file, bytes) in &files {
            let p = tmp.join(file);
            std::fs::write(&p, bytes).map_err(|e| nerf_core::Error::io(&p, e))?;
        }
        Ok(())
    })?;
    Ok(files.into_iter().map(|(file, bytes)| WrittenFile { path: dir.join(file), bytes: bytes.len() }).collect())
}

/// Largest graph file read: protobuf messages stop at 2 GiB.
pub const MAX_GRAPH_BYTES: u64 = 2 << 30;

/// Decode an ONNX file (a regular file of at most [`MAX_GRAPH_BYTES`]).
pub fn read_model(path: &Path) -> nerf_core::Result<ModelProto> {
    let bytes = limits::read_bounded(path, MAX_GRAPH_BYTES)?;
    ModelProto::decode(bytes.as_slice()).map_err(|e| nerf_core::Error::invalid(path, format!("not a valid ONNX file (truncated?): {e}")))
}

/// The path of the bundle file `name` that `scene.json`'s `field` names: a plain file name
/// inside `dir` (no absolute path, no `..`, no separator; a symbolic link must stay inside).
pub fn bundle_file(dir: &Path, name: &str, field: &str) -> nerf_core::Result<PathBuf> {
    let scene = dir.join(SCENE_FILE);
    limits::file_in_dir(dir, name, Origin::Field(&scene, field))
}

/// The plain network stored in a bundle's graph file `file` (`coarse.onnx`, `fine.onnx`).
pub fn read_bundle_network(dir: &Path, file: &str) -> nerf_core::Result<PlainNetwork> {
    let path = bundle_file(dir, file, "networks")?;
    read_network(&read_model(&path)?).map_err(|e| nerf_core::Error::invalid(&path, e))
}

/// Read and check a bundle's `scene.json` (see [`SceneDescription::check`]).
pub fn read_scene(dir: &Path) -> nerf_core::Result<SceneDescription> {
    let path = dir.join(SCENE_FILE);
    let text = limits::read_json_text(&path)?;
    let scene: SceneDescription = serde_json::from_str(&text).map_err(|e| nerf_core::Error::invalid(&path, e.to_string()))?;
    scene.check(&path)?;
    Ok(scene)
}

impl SceneDescription {
    /// Everything a renderer relies on, checked before it allocates or opens anything:
    /// the format, the camera and sampling within [`nerf_core::io::limits`], file names that are
    /// plain names inside the bundle, at most [`MAX_FRAMES`] poses, pose names that are plain
    /// file names (they name output files), a grid resolution within the limit.
    pub fn check(&self, path: &Path) -> nerf_core::Result<()> {
        let at = |field| Origin::Field(path, field);
        if self.format != SCENE_FORMAT {
            return Err(at("format").error(format!("{:?}, expected {SCENE_FORMAT:?}", self.format)));
        }
        limits::check_camera(&self.camera.camera, at("camera"))?;
        limits::check_sampling(&self.sampling, at("sampling"))?;
        if (self.sampling.n_fine > 0) != self.networks.fine.is_some() {
            return Err(at("networks.fine").error("must be given exactly when sampling.n_fine > 0"));
        }
        if self.field == FieldKind::Ngp && self.occupancy.is_none() {
            return Err(at("occupancy").error("a hash-grid field (field \"ngp\") is marched through its occupancy grid: the bundle needs one"));
        }
        limits::check_count(self.march_steps, limits::MAX_SAMPLES_PER_RAY, "steps", at("march_steps"))?;
        limits::check_plain_file_name(&self.networks.coarse, at("networks.coarse"))?;
        if let Some(fine) = &self.networks.fine {
            limits::check_plain_file_name(fine, at("networks.fine"))?;
        }
        for (field, n) in [("poses.test", self.poses.test.len()), ("poses.orbit", self.poses.orbit.len())] {
            if n > MAX_FRAMES {
                return Err(at(field).error(format!("{n} poses is more than the limit of {MAX_FRAMES}")));
            }
        }
        for (k, pose) in self.poses.test.iter().enumerate() {
            limits::check_plain_file_name(&pose.name, Origin::Field(path, &format!("poses.test[{k}].name")))?;
        }
        if let Some(o) = &self.occupancy {
            limits::check_plain_file_name(&o.file, at("occupancy.file"))?;
            limits::check_grid_resolution(o.resolution, at("occupancy.resolution"))?;
            if !(o.bound.is_finite() && o.bound > 0.0) {
                return Err(at("occupancy.bound").error(format!("{} is not a positive finite bound", o.bound)));
            }
        }
        Ok(())
    }
}

/// The bundle's occupancy grid, if `scene.json` names one.
pub fn read_occupancy(dir: &Path, scene: &SceneDescription) -> nerf_core::Result<Option<OccupancyGrid>> {
    let Some(o) = &scene.occupancy else { return Ok(None) };
    let grid = OccupancyGrid::load(&bundle_file(dir, &o.file, "occupancy.file")?)?;
    if grid.resolution() != o.resolution || grid.bound() != o.bound {
        let problem = format!("occupancy: the grid file is {}³ over ±{}, scene.json says {}³ over ±{}", grid.resolution(), grid.bound(), o.resolution, o.bound);
        return Err(nerf_core::Error::invalid(dir.join(SCENE_FILE), problem));
    }
    Ok(Some(grid))
}
