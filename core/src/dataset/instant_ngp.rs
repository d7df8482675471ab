//! instant-ngp / nerfstudio captures: one `transforms.json` with shared or per-frame
//! intrinsics (`fl_x, fl_y, cx, cy, w, h`, OpenCV `k1, k2, p1, p2`, `camera_angle_x/y` as a
//! fallback) and OpenGL camera-to-world `transform_matrix` per frame.
//!
//! `cx`, `cy` are in pixel-edge coordinates (the ray of pixel (i, j) passes through
//! (i + 0.5, j + 0.5)), as instant-ngp and nerfstudio use them. Frames whose image is missing
//! are skipped with a warning (instant-ngp drops them silently).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::capture::{
    Capture, CaptureFormat, CaptureView, ExplicitSplits, FORWARD_FACING_MAX_DEG, centroid,
    is_forward_facing, view_name,
};
use crate::camera::Pose;
use crate::camera::{OpenCvDistortion, PinholeCamera, PixelCenter};
use crate::error::{Error, Result};
use crate::camera::transform::SceneTransform;

/// instant-ngp's default `scale` when the file gives none.
pub const NGP_DEFAULT_SCALE: f32 = 0.33;
/// instant-ngp's default `offset` when the file gives none.
pub const NGP_DEFAULT_OFFSET: [f32; 3] = [0.5; 3];

/// Camera fields that may appear at the top level (shared) or in a frame (its own).
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
pub struct CameraFields {
    /// Horizontal focal length in pixels.
    pub fl_x: Option<f64>,
    /// Vertical focal length in pixels.
    pub fl_y: Option<f64>,
    /// Principal point (pixel-edge coordinates).
    pub cx: Option<f64>,
    /// Principal point, vertical.
    pub cy: Option<f64>,
    /// Image width.
    pub w: Option<f64>,
    /// Image height.
    pub h: Option<f64>,
    /// Horizontal field of view (radians), used when `fl_x` is absent.
    pub camera_angle_x: Option<f64>,
    /// Vertical field of view (radians), used when `fl_y` is absent.
    pub camera_angle_y: Option<f64>,
    /// OpenCV radial coefficient.
    pub k1: Option<f64>,
    /// OpenCV radial coefficient.
    pub k2: Option<f64>,
    /// OpenCV radial coefficient (only 0 is supported).
    pub k3: Option<f64>,
    /// Fisheye coefficient (only 0 is supported).
    pub k4: Option<f64>,
    /// OpenCV tangential coefficient.
    pub p1: Option<f64>,
    /// OpenCV tangential coefficient.
    pub p2: Option<f64>,
    /// nerfstudio's camera model name (`OPENCV`, `PINHOLE`; others are refused).
    pub camera_model: Option<String>,
}

impl CameraFields {
    /// These fields with `own` taking precedence wherever it has a value.
    fn overridden_by(&self, own: &CameraFields) -> CameraFields {
        let pick = |a: Option<f64>, b: Option<f64>| b.or(a);
        CameraFields {
            fl_x: pick(self.fl_x, own.fl_x),
            fl_y: pick(self.fl_y, own.fl_y),
            cx: pick(self.cx, own.cx),
            cy: pick(self.cy, own.cy),
            w: pick(self.w, own.w),
            h: pick(self.h, own.h),
            camera_angle_x: pick(self.camera_angle_x, own.camera_angle_x),
            camera_angle_y: pick(self.camera_angle_y, own.camera_angle_y),
            k1: pick(self.k1, own.k1),
            k2: pick(self.k2, own.k2),
            k3: pick(self.k3, own.k3),
            k4: pick(self.k4, own.k4),
            p1: pick(self.p1, own.p1),
            p2: pick(self.p2, own.p2),
            camera_model: own
                .camera_model
                .clone()
                .or_else(|| self.camera_model.clone()),
        }
    }
}

/// A `transforms.json` (unknown fields are ignored).
#[derive(Debug, Clone, Deserialize)]
pub struct TransformsFile {
    /// Shared camera fields.
    #[serde(flatten)]
    pub camera: CameraFields,
    /// instant-ngp's scene box size relative to its unit cube.
    pub aabb_scale: Option<f64>,
    /// instant-ngp's pose scale.
    pub scale: Option<f64>,
    /// instant-ngp's pose offset.
    pub offset: Option<[f64; 3]>,
    /// nerfstudio's explicit splits (file paths as in `frames`).
    pub train_filenames: Option<Vec<String>>,
    /// Validation frames.
    pub val_filenames: Option<Vec<String>>,
    /// Test frames.
    pub test_filenames: Option<Vec<String>>,
    /// The frames.
    pub frames: Vec<NgpFrame>,
}

/// One frame of a `transforms.json`.
#[derive(Debug, Clone, Deserialize)]
pub struct NgpFrame {
    /// Image path relative to the file's directory, with or without extension.
    pub file_path: String,
    /// Camera-to-world, 4 rows of 4 (or the top 3 rows).
    pub transform_matrix: Vec<Vec<f64>>,
    /// Per-frame camera fields.
    #[serde(flatten)]
    pub camera: CameraFields,
}

/// Extensions tried, in order, for a `file_path` that does not name an existing file.
const IMAGE_EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "PNG", "JPG", "JPEG"];

/// The image of `file_path` under `dir`: the path as written when it is a file, else with
/// each of `.png`, `.jpg`, `.jpeg` (either case) appended; `None` when none exists.
pub fn resolve_image(dir: &Path, file_path: &str) -> Option<PathBuf> {
    let rel = file_path.strip_prefix("./").unwrap_or(file_path);
    let direct = dir.join(rel);
    if direct.is_file() {
        return Some(direct);
    }
    IMAGE_EXTENSIONS
        .iter()
        .map(|ext| dir.join(format!("{rel}.{ext}")))
        .find(|p| p.is_file())
}

/// The pose of a frame: 3 or 4 rows of 4 finite numbers (a 4th row is ignored).
fn frame_pose(matrix: &[Vec<f64>]) -> std::result::Result<Pose, String> {
    if !(matrix.len() == 3 || matrix.len() == 4) || matrix.iter().any(|r| r.len() != 4) {
        let shape: Vec<usize> = matrix.iter().map(Vec::len).collect();
        return Err(format!(
            "transform_matrix must be 4 rows of 4 numbers, got rows of {shape:?}"
        ));
    }
    let pose = Pose(std::array::from_fn(|r| {
        std::array::from_fn(|c| matrix[r][c] as f32)
    }));
    // Checked in f32: a value beyond f32's range is as unusable as a NaN.
    if !pose.is_finite() {
        return Err("transform_matrix has a non-finite entry".into());
    }
    Ok(pose)
}

/// The camera of a frame from its merged fields and the image's real size. The error is the
/// problem alone (the caller names the file and the frame).
pub fn camera_from_fields(
    f: &CameraFields,
    image_size: (u32, u32),
) -> std::result::Result<PinholeCamera, String> {
    if let Some(model) = &f.camera_model
        && !matches!(model.as_str(), "OPENCV" | "PINHOLE" | "SIMPLE_PINHOLE")
    {
        return Err(format!(
            "camera_model {model:?} is not supported (OPENCV or PINHOLE)"
        ));
    }
    for (name, v) in [("k3", f.k3), ("k4", f.k4)] {
        if v.is_some_and(|v| v != 0.0) {
            return Err(format!(
                "{name} = {} is not supported (only k1, k2, p1, p2)",
                v.unwrap_or(0.0)
            ));
        }
    }
    let (iw, ih) = image_size;
    let (w, h) = (f.w.unwrap_or(iw as f64), f.h.unwrap_or(ih as f64));
    if (w, h) != (iw as f64, ih as f64) {
        return Err(format!("w, h = {w}×{h} but the image is {iw}×{ih}"));
    }
    let from_angle = |size: f64, angle: Option<f64>| angle.map(|a| 0.5 * size / (0.5 * a).tan());
    let fx = f.fl_x.or_else(|| from_angle(w, f.camera_angle_x));
    let fy = f.fl_y.or_else(|| from_angle(h, f.camera_angle_y));
    let (fx, fy) = match (fx, fy) {
        (Some(x), Some(y)) => (x, y),
        (Some(x), None) => (x, x),
        (None, Some(y)) => (y, y),
        (None, None) => return Err("no focal length: give fl_x/fl_y or camera_angle_x".into()),
    };
    let (cx, cy) = (f.cx.unwrap_or(0.5 * w), f.cy.unwrap_or(0.5 * h));
    let coeffs = [f.k1, f.k2, f.p1, f.p2].map(|c| c.unwrap_or(0.0));
    let values = [
        ("focal", fx),
        ("focal", fy),
        ("cx", cx),
        ("cy", cy),
        ("k1", coeffs[0]),
        ("k2", coeffs[1]),
        ("p1", coeffs[2]),
        ("p2", coeffs[3]),
    ];
    if let Some((name, v)) = values.iter().find(|(_, v)| !v.is_finite()) {
        return Err(format!("{name} = {v} is not finite"));
    }
    if !(fx > 0.0 && fy > 0.0) {
        return Err(format!("focal lengths ({fx}, {fy}) must be positive"));
    }
    let [k1, k2, p1, p2] = coeffs.map(|c| c as f32);
    let distortion = OpenCvDistortion { k1, k2, p1, p2 };
    Ok(PinholeCamera {
        width: iw,
        height: ih,
        fx: fx as f32,
        fy: fy as f32,
        cx: cx as f32,
        cy: cy as f32,
        pixel_center: PixelCenter::HalfPixel,
        distortion: (!distortion.is_zero()).then_some(distortion),
    })
}

/// Loads `dir/transforms.json`.
///
/// Frames whose image is missing are skipped with a warning in `Capture::warnings`. Poses
/// are normalised with instant-ngp's mapping (`x·scale + offset`, centred: see
/// [`SceneTransform::instant_ngp`]; its defaults 0.33 and 0.5 when the file has `aabb_scale`
/// but no `scale`/`offset`); a file with none of the three (nerfstudio) is centred on its
/// cameras' centroid with the farthest camera at distance 1 (nerfstudio's `auto_scale_poses`
/// uses the largest |coordinate| instead; a single camera is left as it is, with a warning).
/// [`Capture::fit_cameras`] can refit either to the field's bounds. nerfstudio's
/// `*_filenames` lists become explicit splits (val = test when only test is given, train =
/// the rest when it is absent).
///
/// Errors name the file and the frame: malformed JSON, no frames, a matrix that is not 4×4 or
/// 3×4 or has a non-finite entry, no focal length, `w`/`h` that differ from the image, an
/// unsupported camera model or coefficient, no image present at all, or a split naming an
/// unknown file.
pub fn load_instant_ngp(dir: &Path) -> Result<Capture> {
    let path = dir.join("transforms.json");
    let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
    let file: TransformsFile =
        serde_json::from_str(&text).map_err(|e| json_error(&path, &text, e))?;
    if file.frames.is_empty() {
        return Err(Error::invalid(&path, "\"frames\" is empty"));
    }
    let mut views = Vec::with_capacity(file.frames.len());
    let mut warnings = Vec::new();
    // file_path (without "./") → view index, for explicit splits.
    let mut index_of: HashMap<String, Option<usize>> = HashMap::new();
    for (k, frame) in file.frames.iter().enumerate() {
        let frame_err = |problem: String| {
            Error::invalid(&path, format!("frame {k} ({}): {problem}", frame.file_path))
        };
        let pose = frame_pose(&frame.transform_matrix).map_err(frame_err)?;
        let key = frame
            .file_path
            .strip_prefix("./")
            .unwrap_or(&frame.file_path)
            .to_string();
        let Some(image_path) = resolve_image(dir, &frame.file_path) else {
            warnings.push(format!(
                "{}: frame {k}: image {} not found, skipped",
                path.display(),
                dir.join(&key).display()
            ));
            index_of.insert(key, None);
            continue;
        };
        // The image's own error names the image; say which frame of which file wants it.
        let size = image::image_dimensions(&image_path).map_err(|source| {
            frame_err(Error::Image { path: image_path.clone(), source }.to_string())
        })?;
        let fields = file.camera.overridden_by(&frame.camera);
        let camera = camera_from_fields(&fields, size).map_err(frame_err)?;
        index_of.insert(key, Some(views.len()));
        views.push(CaptureView {
            name: view_name(&image_path),
            image_path,
            camera,
            pose,
            bounds: None,
        });
    }
    if views.is_empty() {
        return Err(Error::invalid(
            &path,
            format!("no frame has its image ({} listed)", file.frames.len()),
        ));
    }
    let explicit_splits = explicit_splits(&file, &index_of, views.len(), &mut warnings)
        .map_err(|p| Error::invalid(&path, p))?;

    let poses: Vec<Pose> = views.iter().map(|v| v.pose).collect();
    let is_ngp = file.aabb_scale.is_some() || file.scale.is_some() || file.offset.is_some();
    let transform = if is_ngp {
        let scale = file.scale.map_or(NGP_DEFAULT_SCALE, |s| s as f32);
        let offset = file
            .offset
            .map_or(NGP_DEFAULT_OFFSET, |o| o.map(|v| v as f32));
        if !(scale > 0.0 && scale.is_finite() && offset.iter().all(|o| o.is_finite())) {
            return Err(Error::invalid(
                &path,
                format!("scale {scale} must be positive and offset {offset:?} finite"),
            ));
        }
        SceneTransform::instant_ngp(scale, offset)
    } else {
        // One camera (or all at one place) gives no scale: leave the poses as they are.
        SceneTransform::fit_cameras(&poses, centroid(&poses), 1.0).unwrap_or_else(|e| {
            warnings.push(format!("{}: poses left unnormalised: {e}", path.display()));
            SceneTransform::identity()
        })
    };
    for v in &mut views {
        v.pose = transform.apply_pose(&v.pose);
    }
    let poses: Vec<Pose> = views.iter().map(|v| v.pose).collect();
    let forward_facing = is_forward_facing(&poses, FORWARD_FACING_MAX_DEG);
    Ok(Capture {
        format: CaptureFormat::InstantNgp,
        source: path,
        views,
        transform,
        near_far: None,
        forward_facing,
        aabb_scale: file.aabb_scale.map(|a| a as f32),
        scale: file.scale.map(|s| s as f32),
        offset: file.offset.map(|o| o.map(|v| v as f32)),
        explicit_splits,
        warnings,
    })
}

/// A JSON error; Python's `json.dump` writes non-finite numbers as `NaN`/`Infinity`, which
/// JSON does not allow, so that case is named as what it is.
fn json_error(path: &Path, text: &str, source: serde_json::Error) -> Error {
    let line = text
        .lines()
        .nth(source.line().saturating_sub(1))
        .unwrap_or("");
    match ["NaN", "Infinity"].iter().find(|t| line.contains(*t)) {
        Some(token) => Error::invalid(
            path,
            format!(
                "line {}: {token} is not a finite number (poses and camera values must be finite)",
                source.line()
            ),
        ),
        None => Error::Json {
            path: path.to_path_buf(),
            source,
        },
    }
}

/// nerfstudio's `train/val/test_filenames` as view indices; `None` when the file has none.
fn explicit_splits(
    file: &TransformsFile,
    index_of: &HashMap<String, Option<usize>>,
    n_views: usize,
    warnings: &mut Vec<String>,
) -> std::result::Result<Option<ExplicitSplits>, String> {
    if file.train_filenames.is_none()
        && file.val_filenames.is_none()
        && file.test_filenames.is_none()
    {
        return Ok(None);
    }
    let mut lookup =
        |list: &Option<Vec<String>>, which: &str| -> std::result::Result<Vec<usize>, String> {
            let mut out = Vec::new();
            for name in list.iter().flatten() {
                let key = name.strip_prefix("./").unwrap_or(name);
                match index_of.get(key) {
                    Some(Some(i)) => out.push(*i),
                    Some(None) => {
                        warnings.push(format!("{which}_filenames: {name} has no image, skipped"))
                    }
                    None => {
                        return Err(format!(
                            "{which}_filenames names {name:?}, which is not a frame"
                        ));
                    }
                }
            }
            Ok(out)
        };
    let test = lookup(&file.test_filenames, "test")?;
    let val = if file.val_filenames.is_some() {
        lookup(&file.val_filenames, "val")?
    } else {
        test.clone()
    };
    let train = if file.train_filenames.is_some() {
        lookup(&file.train_filenames, "train")?
    } else {
        (0..n_views)
            .filter(|i| !test.contains(i) && !val.contains(i))
            .collect()
    };
    Ok(Some(ExplicitSplits { train, val, test }))
}

#[cfg(test)]
mod tests;
