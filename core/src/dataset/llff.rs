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
use crate::camera_model::{PinholeCamera, PixelCenter};
use crate::error::{Error, Result};
use crate::npy::read_npy;
use crate::scene_transform::{SceneTransform, pose_from};

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
mod tests {
    use super::*;
    use crate::npy::{encode_npy, f8_bytes};

    fn assert_close(a: Vec3, b: Vec3, tol: f32) {
        assert!((a - b).abs().max_element() <= tol, "{a:?} != {b:?}");
    }

    /// A row: LLFF columns down, right, back, centre given as world vectors.
    fn row(
        down: [f64; 3],
        right: [f64; 3],
        back: [f64; 3],
        centre: [f64; 3],
        hwf: [f64; 3],
        bounds: [f64; 2],
    ) -> [f64; 17] {
        let mut r = [0.0; 17];
        for i in 0..3 {
            r[i * 5] = down[i];
            r[i * 5 + 1] = right[i];
            r[i * 5 + 2] = back[i];
            r[i * 5 + 3] = centre[i];
            r[i * 5 + 4] = hwf[i];
        }
        r[15] = bounds[0];
        r[16] = bounds[1];
        r
    }

    #[test]
    fn columns_become_opengl_as_in_nerf_pytorch() {
        // down = −y, right = x, back = z (a camera looking down −z, y up in LLFF terms).
        let r = row(
            [0.0, -1.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, 2.0, 3.0],
            [300.0, 400.0, 320.0],
            [2.0, 9.0],
        );
        let c = llff_row(&r);
        // [right, −down, back] = [x, y, z]: the identity rotation.
        assert_eq!(
            c.pose,
            Pose([
                [1.0, 0.0, 0.0, 1.0],
                [0.0, 1.0, 0.0, 2.0],
                [0.0, 0.0, 1.0, 3.0]
            ])
        );
        assert_eq!((c.hwf, c.bounds), ([300.0, 400.0, 320.0], (2.0, 9.0)));
        // A general row: 3×5 row-major values 0..15; new columns [c1, −c0, c2, c3].
        let mut r = [0.0; 17];
        for (k, v) in r.iter_mut().enumerate() {
            *v = k as f64;
        }
        let c = llff_row(&r);
        assert_eq!(c.pose.0[0], [1.0, -0.0, 2.0, 3.0]);
        assert_eq!(c.pose.0[1], [6.0, -5.0, 7.0, 8.0]);
        assert_eq!(c.pose.0[2], [11.0, -10.0, 12.0, 13.0]);
        assert_eq!(c.hwf, [4.0, 9.0, 14.0]);
    }

    #[test]
    fn poses_avg_and_recentering_match_hand_values() {
        // Two cameras looking down −z at x = 0 and x = 2 (identity rotations), and one turned
        // about y: the average centre is the mean, the average axes re-orthogonalised.
        let p = |x: f32| {
            Pose([
                [1.0, 0.0, 0.0, x],
                [0.0, 1.0, 0.0, 1.0],
                [0.0, 0.0, 1.0, 5.0],
            ])
        };
        let avg = poses_avg(&[p(0.0), p(2.0)]);
        assert_eq!(avg, p(1.0));
        let centred = recenter_poses(&[p(0.0), p(2.0)]);
        assert_close(centred[0].origin(), Vec3::new(-1.0, 0.0, 0.0), 1e-6);
        assert_close(centred[1].origin(), Vec3::new(1.0, 0.0, 0.0), 1e-6);
        // A rotated pair: z axes at ±30° about y sum to z; after recentering the average is I.
        let turned = |deg: f32, x: f32| {
            let r = Mat3::from_rotation_y(deg.to_radians());
            pose_from(r, Vec3::new(x, 0.0, 0.0))
        };
        let base = Mat3::from_rotation_x(0.3);
        let pair: Vec<Pose> = [turned(30.0, 0.0), turned(-30.0, 4.0)]
            .iter()
            .map(|q| {
                pose_from(
                    base * q.rotation(),
                    base * q.origin() + Vec3::new(0.0, 0.0, 7.0),
                )
            })
            .collect();
        let avg = poses_avg(&pair);
        assert_close(avg.rotation().z_axis, base * Vec3::Z, 1e-6);
        assert_close(
            avg.origin(),
            base * Vec3::new(2.0, 0.0, 0.0) + Vec3::new(0.0, 0.0, 7.0),
            1e-5,
        );
        let again = poses_avg(&recenter_poses(&pair));
        for (a, b) in again
            .0
            .iter()
            .flatten()
            .zip(Pose::from_mat4(glam::Mat4::IDENTITY).0.iter().flatten())
        {
            assert!((a - b).abs() < 1e-5, "{again:?}");
        }
        // The recentred cameras sit at ∓2 on x, turned by ±30°.
        let c = recenter_poses(&pair);
        assert_close(c[0].origin(), Vec3::new(-2.0, 0.0, 0.0), 1e-5);
        assert_close(
            c[0].rotation().z_axis,
            Vec3::new(0.5, 0.0, 0.75f32.sqrt()),
            1e-5,
        );
    }

    #[test]
    fn normalisation_equals_scale_then_recenter() {
        let poses: Vec<Pose> = (0..4)
            .map(|k| {
                let r = Mat3::from_rotation_y(0.1 * k as f32) * Mat3::from_rotation_x(0.2);
                pose_from(
                    r,
                    Vec3::new(k as f32, 2.0 - k as f32 * 0.5, 10.0 + k as f32),
                )
            })
            .collect();
        let bounds = [(4.0, 20.0), (2.0, 18.0), (3.0, 30.0), (5.0, 25.0)];
        // 1/(2·0.75) = 2/3.
        let sc = bd_factor_scale(&bounds, BD_FACTOR).unwrap();
        assert!((sc - 2.0 / 3.0).abs() < 1e-7);
        // nerf-pytorch order: poses[:, :3, 3] *= sc, then recenter_poses.
        let scaled: Vec<Pose> = poses
            .iter()
            .map(|p| pose_from(p.rotation(), p.origin() * sc))
            .collect();
        let reference = recenter_poses(&scaled);
        let t = llff_normalisation(&poses, sc);
        for (p, r) in poses.iter().zip(&reference) {
            let ours = t.apply_pose(p);
            for (a, b) in ours.0.iter().flatten().zip(r.0.iter().flatten()) {
                assert!((a - b).abs() < 1e-5, "{ours:?} vs {r:?}");
            }
        }
        assert!(bd_factor_scale(&[(0.0, 1.0)], BD_FACTOR).is_err());
        assert!(bd_factor_scale(&[], BD_FACTOR).is_err());
    }

    /// Writes an LLFF capture: forward-facing cameras along x looking down −z (LLFF columns
    /// down = −y, right = x, back = z), images of `w × h`, `[H, W, f]` = `hwf`.
    fn write_capture(
        dir: &Path,
        names: &[&str],
        w: u32,
        h: u32,
        hwf: [f64; 3],
        v2: bool,
    ) -> Vec<[f64; 17]> {
        std::fs::create_dir_all(dir.join("images")).unwrap();
        for name in names {
            let img = image::RgbImage::from_pixel(w, h, image::Rgb([10, 20, 30]));
            img.save(dir.join("images").join(name)).unwrap();
        }
        let rows: Vec<[f64; 17]> = (0..names.len())
            .map(|k| {
                row(
                    [0.0, -1.0, 0.0],
                    [1.0, 0.0, 0.0],
                    [0.0, 0.0, 1.0],
                    [k as f64, 0.5, 0.0],
                    hwf,
                    [2.0 + k as f64, 40.0],
                )
            })
            .collect();
        write_rows(dir, &rows, v2);
        rows
    }

    fn write_rows(dir: &Path, rows: &[[f64; 17]], v2: bool) {
        let flat: Vec<f64> = rows.iter().flatten().copied().collect();
        std::fs::write(
            dir.join("poses_bounds.npy"),
            encode_npy(&[rows.len(), 17], &f8_bytes(&flat), "<f8", false, v2),
        )
        .unwrap();
    }

    #[test]
    fn loads_a_small_capture_with_rescaled_focal() {
        for v2 in [false, true] {
            let dir = tempfile::tempdir().unwrap();
            // Images 8×6, hwf for 16×12 with focal 20 → focal 10 at the images' size.
            // Names sort as a.png < b.jpg < c.PNG, whatever the directory order.
            write_capture(
                dir.path(),
                &["c.PNG", "a.png", "b.jpg"],
                8,
                6,
                [12.0, 16.0, 20.0],
                v2,
            );
            std::fs::write(dir.path().join("images/notes.txt"), b"x").unwrap();
            let capture = load_llff(dir.path()).unwrap();
            assert_eq!(capture.format, CaptureFormat::Llff);
            let names: Vec<&str> = capture.views.iter().map(|v| v.name.as_str()).collect();
            assert_eq!(names, ["a", "b", "c"]);
            let cam = capture.views[0].camera;
            assert_eq!(
                (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy),
                (8, 6, 10.0, 10.0, 4.0, 3.0)
            );
            assert_eq!(cam.pixel_center, PixelCenter::Integer);
            // Bounds: min near 2 → scale 1/(2·0.75) = 2/3; near_far = (0.9·4/3, 40·2/3).
            let s = 2.0 / 3.0;
            assert!((capture.transform.scale - s).abs() < 1e-6);
            let (near, far) = capture.near_far.unwrap();
            assert!((near - 0.9 * 2.0 * s).abs() < 1e-5 && (far - 40.0 * s).abs() < 1e-4);
            assert_eq!(
                capture.views[1].bounds.map(|b| (b.0 / s).round()),
                Some(3.0)
            );
            // Recentred: centres at x = (k − 1)·2/3, y = z = 0, looking down −z.
            for (k, v) in capture.views.iter().enumerate() {
                assert_close(
                    v.pose.origin(),
                    Vec3::new((k as f32 - 1.0) * s, 0.0, 0.0),
                    1e-5,
                );
                assert_close(v.pose.rotation() * Vec3::NEG_Z, Vec3::NEG_Z, 1e-6);
            }
            assert!(capture.forward_facing);
            assert!(capture.warnings.is_empty());
        }
    }

    #[test]
    fn bad_captures_give_clear_errors() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let msg = || load_llff(d).unwrap_err().to_string();
        assert!(msg().contains("poses_bounds.npy"), "{}", msg());
        let rows = write_capture(d, &["a.png", "b.png"], 8, 6, [6.0, 8.0, 10.0], false);
        // Three rows for two images.
        write_rows(d, &[rows[0], rows[1], rows[1]], false);
        assert!(msg().contains("3 poses but 2 images"), "{}", msg());
        // A non-finite value names the row and its image.
        let mut bad = rows[1];
        bad[3] = f64::NAN;
        write_rows(d, &[rows[0], bad], false);
        assert!(
            msg().contains("row 1 (b.png) has a non-finite value"),
            "{}",
            msg()
        );
        let mut bad = rows[0];
        bad[15] = -1.0;
        write_rows(d, &[bad, rows[1]], false);
        assert!(
            msg().contains("row 0 (a.png): bounds (-1, 40)"),
            "{}",
            msg()
        );
        // Wrong shape.
        std::fs::write(
            d.join("poses_bounds.npy"),
            encode_npy(&[2, 15], &f8_bytes(&[1.0; 30]), "<f8", false, false),
        )
        .unwrap();
        assert!(msg().contains("shape [2, 15]: expected N×17"), "{}", msg());
        // Another aspect ratio in [H, W].
        let mut wide = rows.clone();
        for r in &mut wide {
            r[4] = 3.0; // H = 3 with W = 8 → 8×3, but images are 8×6.
        }
        write_rows(d, &wide, false);
        assert!(msg().contains("another aspect ratio"), "{}", msg());
        // Images of different sizes.
        write_rows(d, &rows, false);
        image::RgbImage::new(4, 4)
            .save(d.join("images/b.png"))
            .unwrap();
        assert!(msg().contains("b.png: image is 4×4 but"), "{}", msg());
        // No images folder.
        std::fs::remove_dir_all(d.join("images")).unwrap();
        assert!(msg().contains("images"), "{}", msg());
    }
}
