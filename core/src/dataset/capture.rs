//! The format-free result of parsing a real capture (instant-ngp/nerfstudio `transforms.json`,
//! LLFF `poses_bounds.npy`): per-view images, full cameras and OpenGL poses, the scene
//! normalisation that was applied, bounds, and the split rule shared by every format.

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use glam::{Mat3, Vec3};
use serde::{Deserialize, Serialize};

use super::Split;
use crate::camera::Pose;
use crate::camera::PinholeCamera;
use crate::error::{Error, Result};
use crate::io::image::load_rgba;
use crate::camera::transform::SceneTransform;

/// Every how-many-th frame is held out for testing (LLFF's `llffhold`, nerf-pytorch's default).
pub const HOLDOUT_EVERY: usize = 8;

/// The dataset formats `nerf --data DIR` understands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CaptureFormat {
    /// NeRF synthetic: `transforms_{train,val,test}.json`.
    Blender,
    /// instant-ngp / nerfstudio: a single `transforms.json`.
    InstantNgp,
    /// LLFF: `poses_bounds.npy` and `images/`.
    Llff,
}

impl CaptureFormat {
    /// `"blender"`, `"instant_ngp"` or `"llff"`.
    pub fn name(self) -> &'static str {
        match self {
            CaptureFormat::Blender => "blender",
            CaptureFormat::InstantNgp => "instant_ngp",
            CaptureFormat::Llff => "llff",
        }
    }
}

impl fmt::Display for CaptureFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for CaptureFormat {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "blender" => Ok(CaptureFormat::Blender),
            "instant_ngp" | "instant-ngp" | "nerfstudio" => Ok(CaptureFormat::InstantNgp),
            "llff" => Ok(CaptureFormat::Llff),
            other => Err(Error::Argument(format!(
                "unknown format {other:?} (expected blender, instant-ngp or llff)"
            ))),
        }
    }
}

/// Which format `dir` holds, by its files: `transforms_train.json` → Blender, else
/// `transforms.json` → instant-ngp, else `poses_bounds.npy` → LLFF; otherwise an error that
/// names the directory and the files looked for.
pub fn detect_format(dir: &Path) -> Result<CaptureFormat> {
    const EXPECTED: &str = "expected transforms_train.json (Blender), transforms.json (instant-ngp/nerfstudio) or poses_bounds.npy (LLFF)";
    if !dir.is_dir() {
        return Err(Error::invalid(dir, format!("not a directory: {EXPECTED}")));
    }
    let candidates = [
        ("transforms_train.json", CaptureFormat::Blender),
        ("transforms.json", CaptureFormat::InstantNgp),
        ("poses_bounds.npy", CaptureFormat::Llff),
    ];
    candidates
        .iter()
        .find(|(file, _)| dir.join(file).is_file())
        .map(|&(_, f)| f)
        .ok_or_else(|| Error::invalid(dir, format!("no dataset found: {EXPECTED}")))
}

/// A split of a capture: `--split train|val|test|all`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CaptureSplit {
    /// Everything not held out.
    Train,
    /// The test views unless the file names its own.
    Val,
    /// Every 8th view (0, 8, 16, …) unless the file names its own.
    Test,
    /// Every view.
    All,
}

impl From<Split> for CaptureSplit {
    fn from(s: Split) -> Self {
        match s {
            Split::Train => CaptureSplit::Train,
            Split::Val => CaptureSplit::Val,
            Split::Test => CaptureSplit::Test,
        }
    }
}

impl fmt::Display for CaptureSplit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            CaptureSplit::Train => "train",
            CaptureSplit::Val => "val",
            CaptureSplit::Test => "test",
            CaptureSplit::All => "all",
        })
    }
}

impl FromStr for CaptureSplit {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "all" => Ok(CaptureSplit::All),
            other => other.parse::<Split>().map(CaptureSplit::from).map_err(|_| {
                Error::Argument(format!(
                    "unknown split {other:?} (expected train, val, test or all)"
                ))
            }),
        }
    }
}

/// The indices of `split` among `n` views by the LLFF rule: test = every `every`-th view
/// starting with the first (nerf-pytorch's `np.arange(N)[::llffhold]`), val = test, train =
/// the rest, all = every view.
///
/// Example: n = 17, every = 8 → test [0, 8, 16], train the other 14.
pub fn holdout_split(n: usize, every: usize, split: CaptureSplit) -> Vec<usize> {
    let every = every.max(1);
    let held = |k: &usize| k.is_multiple_of(every);
    match split {
        CaptureSplit::All => (0..n).collect(),
        CaptureSplit::Test | CaptureSplit::Val => (0..n).filter(held).collect(),
        CaptureSplit::Train => (0..n).filter(|k| !held(k)).collect(),
    }
}

/// Splits named by the file itself (nerfstudio's `train_filenames`, `val_filenames`,
/// `test_filenames`), as view indices.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ExplicitSplits {
    /// Training views.
    pub train: Vec<usize>,
    /// Validation views (the test views when the file names none).
    pub val: Vec<usize>,
    /// Test views.
    pub test: Vec<usize>,
}

/// One view of a capture.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureView {
    /// The image's file stem (`images/0001.jpg` → `0001`).
    pub name: String,
    /// The image file (it existed when the capture was parsed).
    pub image_path: PathBuf,
    /// Its camera, at the image's resolution.
    pub camera: PinholeCamera,
    /// Camera-to-world, OpenGL axes, in the capture's normalised frame.
    pub pose: Pose,
    /// Near and far scene depth seen by this view (LLFF), in the normalised frame.
    pub bounds: Option<(f32, f32)>,
}

impl CaptureView {
    /// Decodes the image (PNG or JPEG, grey/RGB/RGBA, 8 or 16 bits) to straight RGBA in
    /// `[0, 1]`, row-major; an error names the file if its size differs from the camera's.
    ///
    /// # Shapes
    /// Returns `[camera.height · camera.width]` pixels.
    pub fn load_rgba(&self) -> Result<Vec<[f32; 4]>> {
        let (w, h, pixels) = load_rgba(&self.image_path)?;
        if (w, h) != (self.camera.width, self.camera.height) {
            return Err(Error::invalid(
                &self.image_path,
                format!(
                    "image is {w}×{h} but its camera is {}×{}",
                    self.camera.width, self.camera.height
                ),
            ));
        }
        Ok(pixels)
    }
}

/// A parsed capture: views in file order and what the file says about the scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Capture {
    /// Which parser produced it.
    pub format: CaptureFormat,
    /// The file the cameras came from (`transforms.json`, `poses_bounds.npy`).
    pub source: PathBuf,
    /// The views whose images exist, in file order.
    pub views: Vec<CaptureView>,
    /// The mapping from the file's world to the frame of `views[..].pose` (already applied).
    pub transform: SceneTransform,
    /// Near and far for rays without NDC, in the normalised frame, when the format gives them.
    pub near_far: Option<(f32, f32)>,
    /// Whether all cameras look the same way (see [`is_forward_facing`]): NDC rays by default.
    pub forward_facing: bool,
    /// instant-ngp's `aabb_scale`: the scene box is `[−a/2, a/2]³` in the normalised frame.
    pub aabb_scale: Option<f32>,
    /// instant-ngp's `scale`, when the file gives it.
    pub scale: Option<f32>,
    /// instant-ngp's `offset`, when the file gives it.
    pub offset: Option<[f32; 3]>,
    /// Splits the file names itself; `None` means the every-8th rule.
    pub explicit_splits: Option<ExplicitSplits>,
    /// Things skipped or guessed while parsing (missing images...), for the CLI to print.
    pub warnings: Vec<String>,
}

impl Capture {
    /// The view indices of `split`: the file's own lists when it has them, else
    /// [`holdout_split`] with [`HOLDOUT_EVERY`].
    pub fn split_indices(&self, split: CaptureSplit) -> Vec<usize> {
        match (&self.explicit_splits, split) {
            (_, CaptureSplit::All) => (0..self.views.len()).collect(),
            (Some(s), CaptureSplit::Train) => s.train.clone(),
            (Some(s), CaptureSplit::Val) => s.val.clone(),
            (Some(s), CaptureSplit::Test) => s.test.clone(),
            (None, split) => holdout_split(self.views.len(), HOLDOUT_EVERY, split),
        }
    }

    /// The poses of all views, in order.
    pub fn poses(&self) -> Vec<Pose> {
        self.views.iter().map(|v| v.pose).collect()
    }

    /// Centres the cameras on the point their axes meet ([`focus_point`]; their [`centroid`]
    /// when the axes are parallel) and scales so that the farthest is `radius` away, through
    /// [`Capture::renormalise`]. An error when no camera is away from that centre.
    pub fn fit_cameras(&mut self, radius: f32) -> Result<()> {
        let fit = self.camera_fit(radius)?;
        self.renormalise(&fit);
        Ok(())
    }

    /// The transform [`Capture::fit_cameras`] applies.
    pub fn camera_fit(&self, radius: f32) -> Result<SceneTransform> {
        let poses = self.poses();
        let centre = focus_point(&poses).unwrap_or_else(|| centroid(&poses));
        SceneTransform::fit_cameras(&poses, centre, radius).map_err(|e| Error::invalid(&self.source, e.to_string()))
    }

    /// Maps every pose and bound through `next` as well, and records it in `transform`.
    pub fn renormalise(&mut self, next: &SceneTransform) {
        for v in &mut self.views {
            v.pose = next.apply_pose(&v.pose);
            v.bounds = v.bounds.map(|(n, f)| (n * next.scale, f * next.scale));
        }
        self.near_far = self.near_far.map(|(n, f)| (n * next.scale, f * next.scale));
        self.aabb_scale = self.aabb_scale.map(|a| a * next.scale);
        self.transform = self.transform.then(next);
    }
}

/// The mean of the camera centres (the origin for no poses).
pub fn centroid(poses: &[Pose]) -> Vec3 {
    if poses.is_empty() {
        return Vec3::ZERO;
    }
    poses.iter().map(Pose::origin).sum::<Vec3>() / poses.len() as f32
}

/// The point closest to all optical axes in the least-squares sense (instant-ngp's "centre of
/// attention"): solves `Σ (I − d·dᵀ)·p = Σ (I − d·dᵀ)·o` over the cameras' centres `o` and
/// viewing directions `d`. `None` when the axes are (nearly) parallel, as in a forward-facing
/// capture, where no such point is defined.
pub fn focus_point(poses: &[Pose]) -> Option<Vec3> {
    let mut a = Mat3::ZERO;
    let mut b = Vec3::ZERO;
    for p in poses {
        let d = (p.rotation() * Vec3::NEG_Z).normalize();
        let m = Mat3::IDENTITY - Mat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += m;
        b += m * p.origin();
    }
    // Well-conditioned only when the directions span more than a thin cone: compare the
    // smallest "eigenvalue" proxy, det / trace², with a tolerance.
    let det = a.determinant();
    let trace = a.x_axis.x + a.y_axis.y + a.z_axis.z;
    if !(det.is_finite() && trace > 0.0 && det / (trace * trace * trace) > 1e-4) {
        return None;
    }
    Some(a.inverse() * b)
}

/// Whether every camera's viewing direction (−z axis) lies within `max_angle_deg` of the
/// normalised mean viewing direction; false for no poses or directions that cancel out (a
/// 360° ring). LLFF fern: all within 19° of each other; a ring is far from it.
pub fn is_forward_facing(poses: &[Pose], max_angle_deg: f32) -> bool {
    let dirs: Vec<Vec3> = poses
        .iter()
        .map(|p| (p.rotation() * Vec3::NEG_Z).normalize())
        .collect();
    let mean = dirs.iter().sum::<Vec3>();
    if dirs.is_empty() || mean.length() < 1e-3 * dirs.len() as f32 {
        return false;
    }
    let mean = mean.normalize();
    let min_cos = max_angle_deg.to_radians().cos();
    dirs.iter().all(|d| d.dot(mean) >= min_cos)
}

/// The angle within which [`is_forward_facing`] wants all views for NDC rays by default.
pub const FORWARD_FACING_MAX_DEG: f32 = 45.0;

/// The file stem of a path as a view name.
pub(crate) fn view_name(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

#[cfg(test)]
mod tests;
