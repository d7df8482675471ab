//! LLFF captures (`poses_bounds.npy` + `images/`), read as nerf-pytorch's `load_llff_data`.
//!
//! Each row of the N×17 array is a 3×5 matrix, row-major — columns `[down, right, back,
//! centre, (H, W, focal)]` — followed by the near and far depth bounds of that image. Rows
//! belong to the images of `images/` sorted by file name. nerf-pytorch then: reorders the
//! columns to OpenGL `[right, up, back]` (`poses[:, 1:2], −poses[:, 0:1], poses[:, 2:]`),
//! scales translations and bounds by `1/(min bound · 0.75)` (`bd_factor`), and recentres the
//! poses on their average camera (`recenter_poses`), so that forward-facing scenes look down
//! −z from near the origin, as NDC rays need.

use std::path::{Path, PathBuf};

use glam::{Mat3, Vec3};

use super::capture::{
    Capture, CaptureFormat, CaptureView, FORWARD_FACING_MAX_DEG, is_forward_facing, view_name,
};
use crate::camera::Pose;
use crate::camera::{PinholeCamera, PixelCenter};
use crate::error::{Error, Result};
use crate::io::npy::read_npy;
use crate::camera::transform::{SceneTransform, pose_from};

/// nerf-pytorch's `bd_factor`: the nearest bound lands at 1/0.75 after scaling, so that the
/// NDC near plane at 1 sits in front of all content.
pub const BD_FACTOR: f32 = 0.75;

/// One row of `poses_bounds.npy`, converted: the OpenGL camera-to-world pose, the `[H, W,
/// focal]` column, and the near/far bounds, all in the file's units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LlffRow {
    /// Camera-to-world with columns `[right, up, back, centre]`.
    pub pose: Pose,
    /// `[H, W, focal]` as stored (possibly for another resolution than the images).
    pub hwf: [f32; 3],
    /// Near and far depth.
    pub bounds: (f32, f32),
}

/// Converts one 17-number row: the 3×5 matrix's columns `[down, right, back, centre, hwf]`
/// become the pose `[right, −down, back, centre]` (nerf-pytorch's column shuffle).
pub fn llff_row(row: &[f64; 17]) -> LlffRow {
    let m = |r: usize, c: usize| row[r * 5 + c] as f32;
    let pose = Pose(std::array::from_fn(|r| {
        [m(r, 1), -m(r, 0), m(r, 2), m(r, 3)]
    }));
    LlffRow {
        pose,
        hwf: [m(0, 4), m(1, 4), m(2, 4)],
        bounds: (row[15] as f32, row[16] as f32),
    }
}

/// nerf-pytorch's `poses_avg` (without hwf): centre = mean of the camera centres, z = the
/// normalised sum of the back axes, y from the summed up axes, re-orthogonalised
/// (`viewmatrix(z, up, centre)`: x = normalize(up × z), y = normalize(z × x)).
pub fn poses_avg(poses: &[Pose]) -> Pose {
    let centre = poses.iter().map(Pose::origin).sum::<Vec3>() / poses.len().max(1) as f32;
    let z = poses
        .iter()
        .map(|p| p.rotation().z_axis)
        .sum::<Vec3>()
        .normalize();
    let up = poses.iter().map(|p| p.rotation().y_axis).sum::<Vec3>();
    let x = up.cross(z).normalize();
    let y = z.cross(x).normalize();
    pose_from(Mat3::from_cols(x, y, z), centre)
}

/// nerf-pytorch's `recenter_poses`: every pose left-multiplied by the inverse of
/// [`poses_avg`], so that the average camera becomes the identity.
pub fn recenter_poses(poses: &[Pose]) -> Vec<Pose> {
    let inv = poses_avg(poses).to_mat4().inverse();
    poses
        .iter()
        .map(|p| Pose::from_mat4(inv * p.to_mat4()))
        .collect()
}

/// nerf-pytorch's scale `1/(min near bound · bd_factor)`; an error when the smallest bound is
/// not positive and finite.
pub fn bd_factor_scale(bounds: &[(f32, f32)], bd_factor: f32) -> Result<f32> {
    let min = bounds
        .iter()
        .map(|b| b.0.min(b.1))
        .fold(f32::INFINITY, f32::min);
    if !(min > 0.0 && min.is_finite() && bd_factor > 0.0) {
        return Err(Error::Argument(format!(
            "cannot rescale by the bounds: the smallest bound is {min} (must be positive)"
        )));
    }
    Ok(1.0 / (min * bd_factor))
}

/// The whole LLFF normalisation as one recorded transform: translations scaled by `scale`
/// ([`bd_factor_scale`]) then [`recenter_poses`]; with `R`, `c` the average camera's rotation
/// and centre, `x' = scale · (Rᵀ·x − Rᵀ·c)` (the average rotation is unchanged by scaling).
pub fn llff_normalisation(poses: &[Pose], scale: f32) -> SceneTransform {
    let avg = poses_avg(poses);
    let rt = avg.rotation().transpose();
    SceneTransform::new(scale, rt, -(rt * avg.origin()))
}

/// The images of an LLFF `images/` folder: `.png`, `.jpg`, `.jpeg` (any case), sorted by file
/// name, hidden files skipped.
pub fn llff_images(images_dir: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(images_dir).map_err(|e| Error::io(images_dir, e))?;
    let mut files = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| Error::io(images_dir, e))?.path();
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        if !name.starts_with('.')
            && matches!(ext.as_deref(), Some("png" | "jpg" | "jpeg"))
            && path.is_file()
        {
            files.push(path);
        }
    }
    files.sort();
    Ok(files)
}

/// Loads an LLFF capture from `dir` (`poses_bounds.npy`, `images/`) as nerf-pytorch does with
/// `factor=None, recenter=True, bd_factor=0.75, spherify=False`: poses converted to OpenGL,
/// scaled and recentred (the transform recorded), focal rescaled by image width / W, bounds
/// scaled, `near_far` = (0.9 · min near, max far) as nerf-pytorch's no-NDC bounds, and
/// `forward_facing` from the view directions.
///
/// Errors name the file: a missing or malformed `.npy`, a shape other than N×17, a count of
/// rows different from the images, a non-finite row, a non-positive bound or focal, images of
/// different sizes, or an `[H, W]` whose aspect ratio differs from the images'.
pub fn load_llff(dir: &Path) -> Result<Capture> {
    load_llff_images(dir, "images")
}

/// [`load_llff`] with the images of `dir/<images>` (nerf-pytorch's `factor = 8` reads
/// `images_8`): the cameras follow those images' size.
pub fn load_llff_images(dir: &Path, images: &str) -> Result<Capture> {
    let npy_path = dir.join("poses_bounds.npy");
    let array = read_npy(&npy_path)?;
    if array.shape.len() != 2 || array.shape[1] != 17 {
        return Err(Error::invalid(
            &npy_path,
            format!(
                "shape {:?}: expected N×17 (a 3×5 pose and 2 bounds per image)",
                array.shape
            ),
        ));
    }
    let images_dir = dir.join(images);
    let images = llff_images(&images_dir)?;
    let n = array.shape[0];
    if n != images.len() || n == 0 {
        return Err(Error::invalid(
            &npy_path,
            format!(
                "{n} poses but {} images in {}",
                images.len(),
                images_dir.display()
            ),
        ));
    }
    let mut rows = Vec::with_capacity(n);
    for (k, (values, image)) in array.data.chunks_exact(17).zip(&images).enumerate() {
        let name = image.file_name().unwrap_or_default().to_string_lossy();
        if !values.iter().all(|v| v.is_finite()) {
            return Err(Error::invalid(
                &npy_path,
                format!("row {k} ({name}) has a non-finite value"),
            ));
        }
        let row = llff_row(values.try_into().expect("chunks of 17"));
        let (near, far) = row.bounds;
        if !(near > 0.0 && far > near) {
            return Err(Error::invalid(
                &npy_path,
                format!("row {k} ({name}): bounds ({near}, {far}) are not 0 < near < far"),
            ));
        }
        if !(row.hwf.iter().all(|&v| v > 0.0)) {
            return Err(Error::invalid(
                &npy_path,
                format!(
                    "row {k} ({name}): [H, W, focal] = {:?} must be positive",
                    row.hwf
                ),
            ));
        }
        rows.push(row);
    }

    let (width, height) = image_size(&images[0])?;
    for path in &images[1..] {
        let size = image_size(path)?;
        if size != (width, height) {
            return Err(Error::invalid(
                path,
                format!(
                    "image is {}×{} but {} is {width}×{height}",
                    size.0,
                    size.1,
                    images[0].display()
                ),
            ));
        }
    }

    let poses: Vec<Pose> = rows.iter().map(|r| r.pose).collect();
    let bounds: Vec<(f32, f32)> = rows.iter().map(|r| r.bounds).collect();
    let transform = llff_normalisation(&poses, bd_factor_scale(&bounds, BD_FACTOR)?);
    let r = transform.rotation_matrix();
    if !(r.is_finite() && Vec3::from_array(transform.translation).is_finite()) {
        return Err(Error::invalid(
            &npy_path,
            "the average camera is degenerate (its up and back axes are parallel): cannot recentre",
        ));
    }
    let mut views = Vec::with_capacity(n);
    for (k, (row, path)) in rows.iter().zip(&images).enumerate() {
        let [h, w, f] = row.hwf;
        let s = width as f32 / w;
        // nerf-pytorch overwrites H, W from the image and scales focal by the width alone;
        // a different height ratio means the [H, W] column is not this image's.
        if (h * s - height as f32).abs() > 1.0 {
            return Err(Error::invalid(
                &npy_path,
                format!(
                    "row {k}: [H, W] = [{h}, {w}] has another aspect ratio than the {width}×{height} images"
                ),
            ));
        }
        let camera = PinholeCamera {
            width,
            height,
            fx: f * s,
            fy: f * s,
            cx: 0.5 * width as f32,
            cy: 0.5 * height as f32,
            pixel_center: PixelCenter::Integer,
            distortion: None,
        };
        views.push(CaptureView {
            name: view_name(path),
            image_path: path.clone(),
            camera,
            pose: transform.apply_pose(&row.pose),
            bounds: Some((
                row.bounds.0 * transform.scale,
                row.bounds.1 * transform.scale,
            )),
        });
    }
    let near = views
        .iter()
        .filter_map(|v| v.bounds)
        .map(|b| b.0)
        .fold(f32::INFINITY, f32::min);
    let far = views
        .iter()
        .filter_map(|v| v.bounds)
        .map(|b| b.1)
        .fold(0.0, f32::max);
    let poses: Vec<Pose> = views.iter().map(|v| v.pose).collect();
    Ok(Capture {
        format: CaptureFormat::Llff,
        source: npy_path,
        forward_facing: is_forward_facing(&poses, FORWARD_FACING_MAX_DEG),
        views,
        transform,
        near_far: Some((0.9 * near, far)),
        aabb_scale: None,
        scale: None,
        offset: None,
        explicit_splits: None,
        warnings: Vec::new(),
    })
}

fn image_size(path: &Path) -> Result<(u32, u32)> {
    image::image_dimensions(path).map_err(|source| Error::Image {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests;
