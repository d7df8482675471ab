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
use crate::camera_model::{OpenCvDistortion, PinholeCamera, PixelCenter};
use crate::error::{Error, Result};
use crate::scene_transform::SceneTransform;

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
mod tests {
    use super::*;
    use crate::dataset::capture::CaptureSplit;
    use glam::Vec3;

    fn write_image(path: &Path, w: u32, h: u32) {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        image::RgbImage::from_pixel(w, h, image::Rgb([200, 100, 50]))
            .save(path)
            .unwrap();
    }

    /// A frame at x = `k` looking down −z, with extra JSON fields `extra`.
    fn frame(file_path: &str, k: usize, extra: &str) -> String {
        format!(
            r#"{{"file_path": "{file_path}", "transform_matrix": [[1,0,0,{k}],[0,1,0,0],[0,0,1,4],[0,0,0,1]]{extra}}}"#
        )
    }

    fn write_json(dir: &Path, top: &str, frames: &[String]) {
        std::fs::write(
            dir.join("transforms.json"),
            format!(r#"{{{top} "frames": [{}]}}"#, frames.join(",")),
        )
        .unwrap();
    }

    #[test]
    fn shared_and_per_frame_intrinsics() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        write_image(&d.join("images/0001.jpg"), 8, 6);
        write_image(&d.join("images/0002.png"), 8, 6);
        write_image(&d.join("images/0003.png"), 4, 2);
        write_json(
            d,
            r#""fl_x": 10, "fl_y": 11, "cx": 4.2, "cy": 3.1, "w": 8, "h": 6, "k1": 0.1, "p2": 0.002, "aabb_scale": 4,"#,
            &[
                frame("images/0001.jpg", 0, ""),
                // No extension: resolved to .png.
                frame("./images/0002", 1, r#", "fl_x": 20, "k1": 0"#),
                frame(
                    "images/0003.png",
                    2,
                    r#", "w": 4, "h": 2, "cx": 2, "cy": 1, "fl_x": 5, "fl_y": 5, "k1": 0, "p2": 0"#,
                ),
            ],
        );
        let c = load_instant_ngp(d).unwrap();
        assert_eq!(c.format, CaptureFormat::InstantNgp);
        assert_eq!(c.views.len(), 3);
        assert!(c.warnings.is_empty(), "{:?}", c.warnings);
        let cam = c.views[0].camera;
        assert_eq!(
            (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy),
            (8, 6, 10.0, 11.0, 4.2, 3.1)
        );
        assert_eq!(cam.pixel_center, PixelCenter::HalfPixel);
        assert_eq!(
            cam.distortion,
            Some(OpenCvDistortion {
                k1: 0.1,
                k2: 0.0,
                p1: 0.0,
                p2: 0.002
            })
        );
        // Frame 1 overrides fl_x and k1 only.
        let cam = c.views[1].camera;
        assert_eq!((cam.fx, cam.fy), (20.0, 11.0));
        assert_eq!(
            cam.distortion,
            Some(OpenCvDistortion {
                k1: 0.0,
                k2: 0.0,
                p1: 0.0,
                p2: 0.002
            })
        );
        assert_eq!(c.views[1].name, "0002");
        assert!(c.views[1].image_path.ends_with("images/0002.png"));
        // Frame 2 has its own size and no distortion left.
        let cam = c.views[2].camera;
        assert_eq!(
            (cam.width, cam.height, cam.fx, cam.cx, cam.distortion),
            (4, 2, 5.0, 2.0, None)
        );
        // aabb_scale without scale/offset: instant-ngp's defaults x·0.33 (+0.5 − 0.5).
        assert_eq!((c.aabb_scale, c.scale, c.offset), (Some(4.0), None, None));
        assert_eq!(c.transform, SceneTransform::instant_ngp(0.33, [0.5; 3]));
        assert!((c.views[2].pose.origin() - Vec3::new(0.66, 0.0, 1.32)).length() < 1e-6);
    }

    #[test]
    fn camera_angle_fallback_and_image_size() {
        // No fl_x, w or h: focal from camera_angle_x at the image width; fy = fx without
        // camera_angle_y; principal point at the centre.
        let fields = CameraFields {
            camera_angle_x: Some(2.0 * 0.5f64.atan()),
            ..Default::default()
        };
        let cam = camera_from_fields(&fields, (40, 30)).unwrap();
        // 0.5·40 / tan(atan(0.5)) = 40.
        assert!((cam.fx - 40.0).abs() < 1e-4 && cam.fx == cam.fy, "{cam:?}");
        assert_eq!((cam.cx, cam.cy), (20.0, 15.0));
        let fields = CameraFields {
            camera_angle_y: Some(2.0 * 0.25f64.atan()),
            ..fields
        };
        // 0.5·30 / 0.25 = 60.
        assert!((camera_from_fields(&fields, (40, 30)).unwrap().fy - 60.0).abs() < 1e-4);
        let err = camera_from_fields(&CameraFields::default(), (4, 4)).unwrap_err();
        assert!(err.contains("no focal length"), "{err}");
        let f = CameraFields {
            fl_x: Some(5.0),
            w: Some(8.0),
            ..Default::default()
        };
        let err = camera_from_fields(&f, (4, 4)).unwrap_err();
        assert!(err.contains("w, h = 8×4 but the image is 4×4"), "{err}");
        let f = CameraFields {
            fl_x: Some(5.0),
            camera_model: Some("OPENCV_FISHEYE".into()),
            ..Default::default()
        };
        assert!(
            camera_from_fields(&f, (4, 4))
                .unwrap_err()
                .contains("OPENCV_FISHEYE")
        );
        let f = CameraFields {
            fl_x: Some(5.0),
            k3: Some(0.1),
            ..Default::default()
        };
        assert!(
            camera_from_fields(&f, (4, 4))
                .unwrap_err()
                .contains("k3 = 0.1")
        );
        let f = CameraFields {
            fl_x: Some(-5.0),
            ..Default::default()
        };
        assert!(
            camera_from_fields(&f, (4, 4))
                .unwrap_err()
                .contains("positive")
        );
    }

    #[test]
    fn missing_images_are_skipped_with_warnings() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        write_image(&d.join("a.png"), 4, 4);
        write_image(&d.join("c.png"), 4, 4);
        write_json(
            d,
            r#""fl_x": 4,"#,
            &[
                frame("a.png", 0, ""),
                frame("b.png", 1, ""),
                frame("c", 2, ""),
                frame("d", 3, ""),
            ],
        );
        let c = load_instant_ngp(d).unwrap();
        let names: Vec<&str> = c.views.iter().map(|v| v.name.as_str()).collect();
        assert_eq!(names, ["a", "c"]);
        assert_eq!(c.warnings.len(), 2);
        assert!(
            c.warnings[0].contains("frame 1") && c.warnings[0].contains("b.png not found"),
            "{:?}",
            c.warnings
        );
        // No aabb_scale/scale/offset: centroid (1, 0, 4) to the origin, farthest camera at 1.
        assert!((c.views[0].pose.origin() - Vec3::new(-1.0, 0.0, 0.0)).length() < 1e-6);
        assert!((c.views[1].pose.origin() - Vec3::new(1.0, 0.0, 0.0)).length() < 1e-6);
        assert_eq!(c.transform.scale, 1.0);
        // Two cameras looking the same way: forward-facing.
        assert!(c.forward_facing);
        // A single camera cannot be scaled to fit: left as it is, with a warning.
        write_json(d, r#""fl_x": 4,"#, &[frame("a.png", 3, "")]);
        let c = load_instant_ngp(d).unwrap();
        assert_eq!(
            (c.transform, c.views[0].pose.origin()),
            (SceneTransform::identity(), Vec3::new(3.0, 0.0, 4.0))
        );
        assert!(
            c.warnings[0].contains("poses left unnormalised"),
            "{:?}",
            c.warnings
        );
        // No image at all is an error.
        std::fs::remove_file(d.join("a.png")).unwrap();
        std::fs::remove_file(d.join("c.png")).unwrap();
        let err = load_instant_ngp(d).unwrap_err().to_string();
        assert!(err.contains("no frame has its image (1 listed)"), "{err}");
    }

    #[test]
    fn scale_offset_and_explicit_splits() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        for k in 0..4 {
            write_image(&d.join(format!("{k}.png")), 4, 4);
        }
        let frames: Vec<String> = (0..5).map(|k| frame(&format!("{k}.png"), k, "")).collect();
        write_json(
            d,
            r#""fl_x": 4, "scale": 0.5, "offset": [0.5, 1.0, 0.5], "test_filenames": ["./1.png", "4.png"],"#,
            &frames,
        );
        let c = load_instant_ngp(d).unwrap();
        // x' = 0.5·x + offset − 0.5: frame 2 at (2, 0, 4) → (1, 0.5, 2).
        assert!((c.views[2].pose.origin() - Vec3::new(1.0, 0.5, 2.0)).length() < 1e-6);
        assert_eq!(
            (c.scale, c.offset, c.aabb_scale),
            (Some(0.5), Some([0.5, 1.0, 0.5]), None)
        );
        // 4.png is missing: skipped in the split with a warning; val = test; train = the rest.
        assert_eq!(c.split_indices(CaptureSplit::Test), vec![1]);
        assert_eq!(c.split_indices(CaptureSplit::Val), vec![1]);
        assert_eq!(c.split_indices(CaptureSplit::Train), vec![0, 2, 3]);
        assert_eq!(c.warnings.len(), 2, "{:?}", c.warnings);
        let bad = std::fs::read_to_string(d.join("transforms.json"))
            .unwrap()
            .replace("\"4.png\"]", "\"9.png\"]");
        std::fs::write(d.join("transforms.json"), bad).unwrap();
        let err = load_instant_ngp(d).unwrap_err().to_string();
        assert!(
            err.contains("test_filenames names \"9.png\", which is not a frame"),
            "{err}"
        );
    }

    #[test]
    fn bad_files_give_clear_errors() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let msg = || load_instant_ngp(d).unwrap_err().to_string();
        assert!(msg().contains("transforms.json"), "{}", msg());
        write_image(&d.join("a.png"), 4, 4);
        std::fs::write(d.join("transforms.json"), r#"{"fl_x": 4, "frames": [}"#).unwrap();
        assert!(msg().contains("invalid JSON"), "{}", msg());
        write_json(d, r#""fl_x": 4,"#, &[]);
        assert!(msg().contains("\"frames\" is empty"), "{}", msg());
        let f =
            r#"{"file_path": "a.png", "transform_matrix": [[1,0,0],[0,1,0],[0,0,1]]}"#.to_string();
        write_json(d, r#""fl_x": 4,"#, &[f]);
        assert!(
            msg().contains("frame 0 (a.png): transform_matrix must be 4 rows of 4"),
            "{}",
            msg()
        );
        // Python's json writes a NaN pose as NaN, which is not JSON.
        let f = frame("a.png", 0, "").replace("[0,1,0,0]", "[0,NaN,0,0]");
        write_json(d, r#""fl_x": 4,"#, &[f]);
        assert!(
            msg().contains("transforms.json: line 1: NaN is not a finite number"),
            "{}",
            msg()
        );
        // A finite but huge entry that overflows f32 is caught as non-finite.
        let f = frame("a.png", 0, "").replace("[0,1,0,0]", "[0,1e300,0,0]");
        write_json(d, r#""fl_x": 4,"#, &[f]);
        assert!(
            msg().contains("frame 0 (a.png): transform_matrix has a non-finite entry"),
            "{}",
            msg()
        );
        write_json(d, r#""fl_x": 4, "w": 8,"#, &[frame("a.png", 0, "")]);
        assert!(msg().contains("frame 0 (a.png): w, h = 8×4"), "{}", msg());
        write_json(d, "", &[frame("a.png", 0, "")]);
        assert!(
            msg().contains("frame 0 (a.png): no focal length"),
            "{}",
            msg()
        );
        std::fs::write(d.join("a.png"), b"not an image").unwrap();
        write_json(d, r#""fl_x": 4,"#, &[frame("a.png", 0, "")]);
        assert!(msg().contains("a.png"), "{}", msg());
    }

    #[test]
    fn resolve_image_tries_extensions() {
        let dir = tempfile::tempdir().unwrap();
        write_image(&dir.path().join("x/a.JPG"), 2, 2);
        assert_eq!(
            resolve_image(dir.path(), "./x/a"),
            Some(dir.path().join("x/a.JPG"))
        );
        assert_eq!(
            resolve_image(dir.path(), "x/a.JPG"),
            Some(dir.path().join("x/a.JPG"))
        );
        assert_eq!(resolve_image(dir.path(), "x/b"), None);
    }
}
