//! `scene.json`: everything a renderer needs besides the graphs, and the checks a reader makes
//! before it allocates or opens anything.

use nerf_core::PinholeCamera;
use nerf_core::camera::Pose;
use nerf_core::dataset::ScenePlacement;
use nerf_core::field::Role;
use nerf_core::io::limits::{self, MAX_FRAMES, Origin};
use nerf_core::sample::{Contraction, SamplingConfig};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// The `format` of the `scene.json` this version writes.
pub const SCENE_FORMAT: &str = "nerf-rs-scene-2";
/// The `format` of a contracted field's `scene.json` (`contraction` set; readers that do not
/// know it refuse the bundle rather than march it wrong).
pub const SCENE_FORMAT_CONTRACTED: &str = "nerf-rs-scene-3";
/// Earlier `scene.json` formats this version still reads: `nerf-rs-scene-1` names the graphs
/// under `networks` (a hash-grid field's as `networks.coarse`) and repeats NDC in the placement.
pub const READ_FORMATS: [&str; 3] = ["nerf-rs-scene-1", SCENE_FORMAT, SCENE_FORMAT_CONTRACTED];
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
    /// The kind of field the graphs hold (`mlp`: coarse/fine NeRF networks; `ngp`: a hash-grid
    /// field), for people and tools; a renderer needs only [`graphs`](Self::graphs) and
    /// [`bounded`](Self::bounded). Absent: `mlp`.
    #[serde(default = "default_kind")]
    pub field: String,
    /// The field is defined inside the occupancy grid's box only: it is always marched, through
    /// its grid or, without one, through the whole box. Absent: false (in `nerf-rs-scene-1`
    /// files: true for `ngp`, the one kind that was bounded then).
    #[serde(default)]
    pub bounded: bool,
    /// Positional encoding of points (inside the graphs; stated for other implementations;
    /// absent for `ngp`, whose encoding is the hash grid in the graph's metadata `nerf.ngp`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_encoding: Option<EncodingDescription>,
    /// Positional encoding of view directions (absent for `ngp`: spherical harmonics of
    /// degree 4 inside the graph).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub direction_encoding: Option<EncodingDescription>,
    /// Marching: equal intervals over [near, far], a sample at each middle where the occupancy
    /// grid is occupied (contracted: segments of `march_steps / 4` intervals growing 4× each,
    /// `nerf_core::render::grid::march_segments`). Absent: 256.
    #[serde(default = "default_march_steps")]
    pub march_steps: usize,
    /// How points are contracted before the field and the occupancy grid see them (the graph
    /// contracts its input itself; marching contracts to find cells). Absent: not contracted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contraction: Option<Contraction>,
    /// [`Contraction::describe`], for other implementations (written with `contraction`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contraction_definition: Option<String>,
    /// For a field trained with per-image appearance codes: the one code it renders with,
    /// already inside the graph (color.0's bias), recorded for people and tools. Absent: the
    /// field has no appearance codes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub appearance: Option<FixedAppearance>,
    /// Graph files by role (`field`, or `coarse` and `fine`), relative to the bundle.
    #[serde(default)]
    pub graphs: BTreeMap<Role, String>,
    /// `nerf-rs-scene-1`'s graph files (`coarse`, `fine`; a hash-grid field's in `coarse`),
    /// read as [`graphs`](Self::graphs) by [`SceneDescription::graph_files`]; never written.
    #[serde(default, skip_serializing)]
    pub networks: Option<NetworkFiles>,
    /// Camera-to-world poses to render.
    pub poses: ScenePoses,
    /// The occupancy grid for empty-space skipping (format in [`nerf_core::sample::occupancy`]);
    /// renderers without it sample densely.
    #[serde(default)]
    pub occupancy: Option<OccupancyDescription>,
    /// For a captured scene: its format, the transform from the capture's world into the
    /// field's frame that every pose here already went through (apply it to poses of the
    /// capture's own files: `x' = scale · (rotation · x + translation)`), near/far and the
    /// orbit path. Absent for Blender scenes, which are used as they are. NDC is stated once,
    /// in `sampling.ndc`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub placement: Option<ScenePlacement>,
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

/// `nerf-rs-scene-1`'s graph files.
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
    /// A description of a field trained with `sampling` on images from `camera`: no graphs yet
    /// (the writer names them, and the field's kind and bounds), no poses.
    pub fn new(camera: &PinholeCamera, sampling: &SamplingConfig, white_background: bool, march_steps: usize) -> Self {
        SceneDescription {
            format: SCENE_FORMAT.into(),
            camera: CameraDescription::new(camera),
            sampling: sampling.clone(),
            white_background,
            field: default_kind(),
            bounded: false,
            position_encoding: None,
            direction_encoding: None,
            march_steps,
            contraction: None,
            contraction_definition: None,
            appearance: None,
            graphs: BTreeMap::new(),
            networks: None,
            poses: ScenePoses::default(),
            occupancy: None,
            placement: None,
        }
    }

    /// Contract (or not), with the format and definition that go with it.
    pub fn set_contraction(&mut self, contraction: Option<Contraction>) {
        self.contraction = contraction;
        self.contraction_definition = contraction.map(|c| c.describe().to_string());
        self.format = if contraction.is_some() { SCENE_FORMAT_CONTRACTED } else { SCENE_FORMAT }.into();
    }

    /// Whether the field is defined inside its box only ([`bounded`](Self::bounded), or a
    /// `nerf-rs-scene-1` hash-grid bundle).
    pub fn is_bounded(&self) -> bool {
        self.bounded || (self.format == READ_FORMATS[0] && self.field == "ngp")
    }

    /// The graph files by role, in role order, with the `scene.json` key that names each
    /// (`graphs.<role>`, or `networks.coarse`/`networks.fine` in a `nerf-rs-scene-1` file).
    pub fn graph_files(&self) -> Vec<GraphFile<'_>> {
        match &self.networks {
            Some(n) if self.graphs.is_empty() => {
                let coarse = if self.is_bounded() { Role::Field } else { Role::Coarse };
                let mut files = vec![GraphFile { role: coarse, file: &n.coarse, key: "networks.coarse" }];
                files.extend(n.fine.as_deref().map(|file| GraphFile { role: Role::Fine, file, key: "networks.fine" }));
                files
            }
            _ => self.graphs.iter().map(|(&role, file)| GraphFile { role, file, key: graph_key(role) }).collect(),
        }
    }

    /// Everything a renderer relies on, checked before it allocates or opens anything:
    /// the format, the camera and sampling within [`nerf_core::io::limits`], file names that are
    /// plain names inside the bundle, at most [`MAX_FRAMES`] poses, pose names that are plain
    /// file names (they name output files), finite poses, a grid resolution within the limit.
    /// (`python/nerf_bundle/_validate.py` makes the same checks.)
    pub fn check(&self, path: &Path) -> nerf_core::Result<()> {
        let at = |field| Origin::Field(path, field);
        if !READ_FORMATS.contains(&self.format.as_str()) {
            return Err(at("format").error(format!("{:?}, expected one of {READ_FORMATS:?}", self.format)));
        }
        if self.contraction.is_some() != (self.format == SCENE_FORMAT_CONTRACTED) {
            return Err(at("contraction").error(format!("{:?} with format {:?}: a contracted field is {SCENE_FORMAT_CONTRACTED:?}, and only it", self.contraction, self.format)));
        }
        limits::check_camera(&self.camera.camera, at("camera"))?;
        limits::check_sampling(&self.sampling, at("sampling"))?;
        let files = self.graph_files();
        let roles: Vec<Role> = files.iter().map(|g| g.role).collect();
        let wanted: &[Role] = match (roles.first(), self.sampling.n_fine > 0) {
            (Some(Role::Field), _) => &[Role::Field],
            (_, true) => &[Role::Coarse, Role::Fine],
            (_, false) => &[Role::Coarse],
        };
        if roles != wanted || (wanted == [Role::Field] && self.sampling.n_fine > 0) {
            let names = |r: &[Role]| r.iter().map(|r| r.name()).collect::<Vec<_>>().join(", ");
            let problem = format!("graphs [{}] with sampling.n_fine {}: need [field] (n_fine 0), [coarse] (n_fine 0) or [coarse, fine] (n_fine > 0)", names(&roles), self.sampling.n_fine);
            return Err(at(if self.networks.is_some() && self.graphs.is_empty() { "networks" } else { "graphs" }).error(problem));
        }
        if self.is_bounded() && self.occupancy.is_none() {
            return Err(at("occupancy").error("a bounded field is defined inside its box only and marched through its occupancy grid: the bundle needs one"));
        }
        limits::check_count(self.march_steps, limits::MAX_SAMPLES_PER_RAY, "steps", at("march_steps"))?;
        for g in &files {
            limits::check_plain_file_name(g.file, at(g.key))?;
        }
        for (field, n) in [("poses.test", self.poses.test.len()), ("poses.orbit", self.poses.orbit.len())] {
            if n > MAX_FRAMES {
                return Err(at(field).error(format!("{n} poses is more than the limit of {MAX_FRAMES}")));
            }
        }
        for (k, pose) in self.poses.test.iter().enumerate() {
            limits::check_plain_file_name(&pose.name, Origin::Field(path, &format!("poses.test[{k}].name")))?;
        }
        // A number past f32's range reads as infinite.
        let finite = |m: &[[f32; 4]; 4]| m.iter().flatten().all(|v| v.is_finite());
        let test = self.poses.test.iter().map(|p| &p.transform_matrix).enumerate().map(|(k, m)| (format!("poses.test[{k}].transform_matrix"), m));
        let orbit = self.poses.orbit.iter().enumerate().map(|(k, m)| (format!("poses.orbit[{k}]"), m));
        if let Some((field, _)) = test.chain(orbit).find(|(_, m)| !finite(m)) {
            return Err(Origin::Field(path, &field).error("has a non-finite entry"));
        }
        if let Some(FixedAppearance::Image { image }) = &self.appearance {
            if image.is_empty() || image.len() > 255 || image.chars().any(char::is_control) {
                return Err(at("appearance.image").error(format!("{image:?} is not an image name")));
            }
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

/// Which per-image appearance code a field renders with ([`SceneDescription::appearance`]):
/// `{"fixed": "mean"}` or `{"fixed": "image", "image": NAME}`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(tag = "fixed", rename_all = "lowercase", deny_unknown_fields)]
pub enum FixedAppearance {
    /// The mean of the training images' codes (nerfacto's choice for novel views).
    #[default]
    Mean,
    /// The code of the training image of that name (its file stem).
    Image {
        /// The image's name.
        image: String,
    },
}

impl FixedAppearance {
    /// `mean`, or a training image's name.
    pub fn parse(text: &str) -> Self {
        if text == "mean" { FixedAppearance::Mean } else { FixedAppearance::Image { image: text.to_string() } }
    }
}

impl std::fmt::Display for FixedAppearance {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FixedAppearance::Mean => write!(f, "the mean of the training images' codes"),
            FixedAppearance::Image { image } => write!(f, "training image {image:?}'s code"),
        }
    }
}

/// One graph file of a bundle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GraphFile<'a> {
    /// What it evaluates.
    pub role: Role,
    /// Its file name, relative to the bundle.
    pub file: &'a str,
    /// The `scene.json` key that names it (for error messages).
    pub key: &'static str,
}

fn graph_key(role: Role) -> &'static str {
    match role {
        Role::Field => "graphs.field",
        Role::Coarse => "graphs.coarse",
        Role::Fine => "graphs.fine",
    }
}

fn default_kind() -> String {
    "mlp".into()
}

fn default_march_steps() -> usize {
    nerf_core::render::DEFAULT_MARCH_STEPS
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::Intrinsics;

    fn scene(kind: &str, n_fine: usize) -> SceneDescription {
        let camera = PinholeCamera::from(Intrinsics { width: 8, height: 8, focal: 8.0 });
        let sampling = SamplingConfig { near: 2.0, far: 6.0, n_coarse: 8, n_fine, lindisp: false, ndc: None };
        SceneDescription { field: kind.into(), ..SceneDescription::new(&camera, &sampling, true, 256) }
    }

    #[test]
    fn graphs_are_named_by_role_and_checked_against_the_kind() {
        let path = Path::new("b/scene.json");
        let mut s = scene("mlp", 4);
        s.graphs = [(Role::Coarse, "coarse.onnx".into()), (Role::Fine, "fine.onnx".into())].into();
        s.check(path).unwrap();
        let files = s.graph_files();
        assert_eq!(files.iter().map(|g| (g.role, g.file, g.key)).collect::<Vec<_>>(), [(Role::Coarse, "coarse.onnx", "graphs.coarse"), (Role::Fine, "fine.onnx", "graphs.fine")]);
        s.graphs.remove(&Role::Fine);
        let err = s.check(path).unwrap_err().to_string();
        assert!(err.contains("graphs [coarse] with sampling.n_fine 4"), "{err}");
        let mut s = scene("ngp", 0);
        s.bounded = true;
        s.graphs = [(Role::Field, "../field.onnx".into())].into();
        s.occupancy = Some(OccupancyDescription { file: "occupancy.bin".into(), resolution: 4, bound: 1.5 });
        let err = s.check(path).unwrap_err().to_string();
        assert!(err.contains("graphs.field") && err.contains("not a plain file name"), "{err}");
        s.occupancy = None;
        s.graphs = [(Role::Field, "field.onnx".into())].into();
        assert!(s.check(path).unwrap_err().to_string().contains("occupancy"));
    }

    #[test]
    fn poses_past_f32_range_are_refused() {
        let path = Path::new("b/scene.json");
        let mut s = scene("mlp", 0);
        s.graphs = [(Role::Coarse, "coarse.onnx".into())].into();
        s.poses.orbit = vec![[[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0], [0.0, 0.0, 0.0, 1.0]]; 2];
        s.poses.test = vec![NamedPose { name: "r_0".into(), transform_matrix: s.poses.orbit[0] }];
        s.check(path).unwrap();
        // As JSON: 1e39 is a finite number there, infinite as f32.
        let mut v = serde_json::to_value(&s).unwrap();
        v["poses"]["orbit"][1][2][3] = serde_json::json!(1e39);
        let far: SceneDescription = serde_json::from_value(v).unwrap();
        assert_eq!(far.check(path).unwrap_err().to_string(), "b/scene.json: poses.orbit[1]: has a non-finite entry");
        s.poses.test[0].transform_matrix[0][0] = f32::NAN;
        assert_eq!(s.check(path).unwrap_err().to_string(), "b/scene.json: poses.test[0].transform_matrix: has a non-finite entry");
    }

    #[test]
    fn a_fixed_appearance_is_spelt_and_checked() {
        let path = Path::new("b/scene.json");
        assert_eq!(serde_json::to_value(FixedAppearance::Mean).unwrap(), serde_json::json!({"fixed": "mean"}));
        assert_eq!(serde_json::to_value(FixedAppearance::parse("r_3")).unwrap(), serde_json::json!({"fixed": "image", "image": "r_3"}));
        assert_eq!(FixedAppearance::parse("mean"), FixedAppearance::Mean);
        let mut s = scene("mlp", 0);
        s.graphs = [(Role::Coarse, "coarse.onnx".into())].into();
        assert!(!serde_json::to_string(&s).unwrap().contains("appearance"), "absent unless the field has codes");
        s.appearance = Some(FixedAppearance::parse("IMG_0001"));
        s.check(path).unwrap();
        let again: SceneDescription = serde_json::from_str(&serde_json::to_string(&s).unwrap()).unwrap();
        assert_eq!(again, s);
        s.appearance = Some(FixedAppearance::parse("a\nb"));
        assert!(s.check(path).unwrap_err().to_string().contains("appearance.image"));
        let mut v = serde_json::to_value(&again).unwrap();
        v["appearance"] = serde_json::json!({"fixed": "median"});
        assert!(serde_json::from_value::<SceneDescription>(v).is_err());
    }

    #[test]
    fn deeply_nested_json_is_an_error_not_a_stack_overflow() {
        let nested = |depth: usize| format!("{}{}", "[".repeat(depth), "]".repeat(depth));
        let text = serde_json::to_string(&scene("mlp", 0)).unwrap();
        // In a field it reads (placement.orbit is buffered as a tree): serde_json's limit.
        let deep = text.replacen('{', &format!("{{\"placement\":{{\"orbit\":{}}},", nested(100_000)), 1);
        assert!(serde_json::from_str::<SceneDescription>(&deep).unwrap_err().to_string().contains("recursion limit exceeded"));
        // In a field it does not know, skipped without recursing (the Python package refuses
        // this past its parser's recursion limit: the one difference).
        let unknown = text.replacen('{', &format!("{{\"x\":{},", nested(100_000)), 1);
        assert_eq!(serde_json::from_str::<SceneDescription>(&unknown).unwrap(), scene("mlp", 0));
    }

    #[test]
    fn first_format_scenes_still_read() {
        // A hash-grid bundle as nerf-rs-scene-1 wrote it: its one graph under networks.coarse,
        // NDC in the placement too.
        let mut v1 = serde_json::to_value(scene("ngp", 0)).unwrap();
        v1["format"] = "nerf-rs-scene-1".into();
        v1.as_object_mut().unwrap().remove("graphs");
        v1.as_object_mut().unwrap().remove("bounded");
        v1["networks"] = serde_json::json!({ "coarse": "field.onnx", "fine": null });
        v1["occupancy"] = serde_json::json!({ "file": "occupancy.bin", "resolution": 4, "bound": 1.5 });
        let s: SceneDescription = serde_json::from_value(v1).unwrap();
        s.check(Path::new("scene.json")).unwrap();
        assert!(s.is_bounded(), "version 1 hash-grid bundles are bounded");
        let files = s.graph_files();
        assert_eq!(files.iter().map(|g| (g.role, g.file, g.key)).collect::<Vec<_>>(), [(Role::Field, "field.onnx", "networks.coarse")]);
        // Written again, it names the graph by role and drops the old key.
        let mut again = s.clone();
        again.graphs = [(Role::Field, "field.onnx".into())].into();
        again.networks = None;
        let text = serde_json::to_string(&again).unwrap();
        assert!(text.contains("\"graphs\":{\"field\":\"field.onnx\"}") && !text.contains("networks"), "{text}");
    }
}
