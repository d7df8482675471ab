//! Pinhole cameras and ray generation, in the bmild/nerf convention.
//!
//! Camera-to-world matrices are OpenGL style: the camera looks down its −z axis with +y up.
//! Ray directions are *not* normalised (their z component in camera space is −1), and pixel
//! centres carry no +0.5 offset — both exactly as the reference code, because the trained
//! networks and the δ scaling depend on it.
//!
//! Rays come from one camera model, [`PinholeCamera`] (focal lengths, principal point, lens
//! distortion); [`Intrinsics`] is the Blender camera it generalises (`PinholeCamera::from`).

use glam::{Mat3, Mat4, Vec3, Vec4};
use serde::{Deserialize, Serialize};

use crate::camera_model::PinholeCamera;

/// Image size and focal length (pixels) of a pinhole camera with its principal point at the
/// image centre.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length in pixels.
    pub focal: f32,
}

impl Intrinsics {
    /// Blender's `camera_angle_x` (horizontal field of view, radians) → focal = 0.5·W / tan(0.5·angle).
    pub fn from_camera_angle_x(width: u32, height: u32, camera_angle_x: f32) -> Self {
        let focal = 0.5 * width as f32 / (0.5 * camera_angle_x).tan();
        Intrinsics { width, height, focal }
    }

    /// The same field of view at another resolution: focal scales with the width.
    pub fn resized(&self, width: u32, height: u32) -> Self {
        Intrinsics { width, height, focal: self.focal * width as f32 / self.width as f32 }
    }

    /// Number of pixels (= rays per image).
    pub fn num_pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// A camera-to-world transform: rotation columns are the camera axes in world space, the last
/// column is the camera centre. Stored as the top 3×4 of the 4×4 matrix, row-major.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose(pub [[f32; 4]; 3]);

impl Pose {
    /// From a row-major 4×4 matrix (the Blender `transform_matrix`); the last row is dropped.
    pub fn from_rows(rows: [[f32; 4]; 4]) -> Self {
        Pose([rows[0], rows[1], rows[2]])
    }

    /// Whether every entry is finite.
    pub fn is_finite(&self) -> bool {
        self.0.iter().flatten().all(|v| v.is_finite())
    }

    /// The camera centre in world space.
    pub fn origin(&self) -> Vec3 {
        Vec3::new(self.0[0][3], self.0[1][3], self.0[2][3])
    }

    /// The rotation part (camera → world).
    pub fn rotation(&self) -> Mat3 {
        let r = &self.0;
        Mat3::from_cols(
            Vec3::new(r[0][0], r[1][0], r[2][0]),
            Vec3::new(r[0][1], r[1][1], r[2][1]),
            Vec3::new(r[0][2], r[1][2], r[2][2]),
        )
    }

    /// The 4×4 matrix (glam is column-major).
    pub fn to_mat4(&self) -> Mat4 {
        let r = &self.0;
        Mat4::from_cols(
            Vec4::new(r[0][0], r[1][0], r[2][0], 0.0),
            Vec4::new(r[0][1], r[1][1], r[2][1], 0.0),
            Vec4::new(r[0][2], r[1][2], r[2][2], 0.0),
            Vec4::new(r[0][3], r[1][3], r[2][3], 1.0),
        )
    }

    /// From a 4×4 glam matrix.
    pub fn from_mat4(m: Mat4) -> Self {
        let row = |k: usize| {
            let r = m.row(k);
            [r.x, r.y, r.z, r.w]
        };
        Pose([row(0), row(1), row(2)])
    }

    /// The reference code's `pose_spherical(theta, phi, radius)` (degrees): a camera on a
    /// sphere of `radius` about the origin, looking at it, azimuth `theta`, elevation `phi`.
    pub fn spherical(theta_deg: f32, phi_deg: f32, radius: f32) -> Self {
        let trans_t = Mat4::from_translation(Vec3::new(0.0, 0.0, radius));
        let (sp, cp) = phi_deg.to_radians().sin_cos();
        // rot_phi rows: [1,0,0],[0,c,−s],[0,s,c]; rot_theta rows: [c,0,−s],[0,1,0],[s,0,c].
        let rot_phi = Mat4::from_cols(
            Vec4::new(1.0, 0.0, 0.0, 0.0),
            Vec4::new(0.0, cp, sp, 0.0),
            Vec4::new(0.0, -sp, cp, 0.0),
            Vec4::W,
        );
        let (st, ct) = theta_deg.to_radians().sin_cos();
        let rot_theta = Mat4::from_cols(
            Vec4::new(ct, 0.0, st, 0.0),
            Vec4::Y,
            Vec4::new(-st, 0.0, ct, 0.0),
            Vec4::W,
        );
        let swap = Mat4::from_cols(
            Vec4::new(-1.0, 0.0, 0.0, 0.0),
            Vec4::new(0.0, 0.0, 1.0, 0.0),
            Vec4::new(0.0, 1.0, 0.0, 0.0),
            Vec4::W,
        );
        Pose::from_mat4(swap * rot_theta * rot_phi * trans_t)
    }

    /// The reference 360° orbit: `frames` poses at azimuths linspace(−180, 180, frames+1)[:-1],
    /// elevation −30°, radius 4.
    pub fn orbit(frames: usize) -> Vec<Pose> {
        (0..frames)
            .map(|k| Pose::spherical(-180.0 + 360.0 * k as f32 / frames as f32, -30.0, 4.0))
            .collect()
    }

    /// The world-space (unnormalised) direction of the ray through pixel (`i`, `j`).
    pub fn ray_direction(&self, camera: &PinholeCamera, i: f32, j: f32) -> Vec3 {
        self.rotation() * camera.camera_direction(i, j)
    }
}

/// The point `o + t·d` on a ray.
///
/// Example: o = (1, 0, 0), d = (0, 2, 0), t = 1.5 → (1, 3, 0).
pub fn point_at(origin: [f32; 3], direction: [f32; 3], t: f32) -> [f32; 3] {
    [origin[0] + t * direction[0], origin[1] + t * direction[1], origin[2] + t * direction[2]]
}

/// The Euclidean length ‖d‖ of a (direction) vector: distances along an unnormalised ray are
/// `t · ‖d‖`. Example: (3, 0, 4) → 5.
pub fn length(d: [f32; 3]) -> f32 {
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

/// A batch of rays. Directions are unnormalised (see the module docs).
///
/// # Shapes
/// `origins`, `directions`: `[n_rays]` of 3-vectors.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Rays {
    /// Ray origins.
    pub origins: Vec<[f32; 3]>,
    /// Ray directions (unnormalised).
    pub directions: Vec<[f32; 3]>,
    /// The directions the networks see, when they are not `directions`: rays warped into NDC
    /// keep their world directions here (nerf-pytorch's `viewdirs` come from the rays before
    /// `ndc_rays`). Unnormalised, `[n_rays]` when present.
    pub viewdirs: Option<Vec<[f32; 3]>>,
}

impl Rays {
    /// Number of rays.
    pub fn len(&self) -> usize {
        self.origins.len()
    }

    /// Whether there are no rays.
    pub fn is_empty(&self) -> bool {
        self.origins.is_empty()
    }

    /// The world-space rays (origin, unnormalised direction) of `camera` at `pose` through
    /// the given pixels `(column, row)`: the one ray generator of the project.
    ///
    /// # Shapes
    /// `pixels`: `[n]` → `[n]` rays.
    pub fn for_pixels(camera: &PinholeCamera, pose: &Pose, pixels: &[(u32, u32)]) -> Rays {
        let rotation = pose.rotation();
        let origin = pose.origin().to_array();
        let mut rays = Rays::with_capacity(pixels.len());
        for &(i, j) in pixels {
            let d = rotation * camera.camera_direction(i as f32, j as f32);
            rays.origins.push(origin);
            rays.directions.push(d.to_array());
        }
        rays
    }

    /// The rays of a whole image, row-major (pixel `(i, j)` at index `j·W + i`), or of rows
    /// `rows` only.
    pub fn for_rows(camera: &PinholeCamera, pose: &Pose, rows: std::ops::Range<u32>) -> Rays {
        let pixels: Vec<(u32, u32)> =
            rows.flat_map(|j| (0..camera.width).map(move |i| (i, j))).collect();
        Rays::for_pixels(camera, pose, &pixels)
    }

    /// Empty batch with room for `n` rays.
    pub fn with_capacity(n: usize) -> Rays {
        Rays { origins: Vec::with_capacity(n), directions: Vec::with_capacity(n), viewdirs: None }
    }

    /// Unit view directions (the networks' `viewdirs` input): of [`Rays::viewdirs`] when the
    /// rays were warped, else of the directions.
    pub fn view_directions(&self) -> Vec<[f32; 3]> {
        let source = self.viewdirs.as_ref().unwrap_or(&self.directions);
        source.iter().map(|d| Vec3::from_array(*d).normalize().to_array()).collect()
    }

    /// Rays `range` as a new batch.
    pub fn slice(&self, range: std::ops::Range<usize>) -> Rays {
        Rays {
            origins: self.origins[range.clone()].to_vec(),
            directions: self.directions[range.clone()].to_vec(),
            viewdirs: self.viewdirs.as_ref().map(|v| v[range].to_vec()),
        }
    }

    /// Appends `other`'s rays (view directions kept per ray when either batch was warped).
    pub fn extend(&mut self, other: Rays) {
        if self.viewdirs.is_some() || other.viewdirs.is_some() {
            let mut mine = self.viewdirs.take().unwrap_or_else(|| self.directions.clone());
            mine.extend(other.viewdirs.as_ref().unwrap_or(&other.directions));
            self.viewdirs = Some(mine);
        }
        self.origins.extend(other.origins);
        self.directions.extend(other.directions);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_close(a: Vec3, b: Vec3) {
        assert!((a - b).abs().max_element() < 1e-5, "{a:?} != {b:?}");
    }

    #[test]
    fn point_at_and_length() {
        assert_eq!(point_at([1.0, 0.0, 0.0], [0.0, 2.0, 0.0], 1.5), [1.0, 3.0, 0.0]);
        assert_eq!(length([3.0, 0.0, 4.0]), 5.0);
    }

    #[test]
    fn focal_from_camera_angle() {
        // tan(0.5 · 2·atan(0.5)) = 0.5 → focal = 0.5·W / 0.5 = W.
        let k = Intrinsics::from_camera_angle_x(400, 400, 2.0 * 0.5f32.atan());
        assert!((k.focal - 400.0).abs() < 1e-3);
        let half = k.resized(100, 100);
        assert!((half.focal - 100.0).abs() < 1e-3);
    }

    #[test]
    fn ray_directions_for_known_pose_and_focal() {
        // W=4, H=2, f=2; c2w rotates camera x→world x, camera y→world z, camera z→world −y
        // (the "swap" used by pose_spherical's last step would differ; this one is explicit).
        let k = PinholeCamera::from(Intrinsics { width: 4, height: 2, focal: 2.0 });
        let pose = Pose([[1.0, 0.0, 0.0, 0.5], [0.0, 0.0, -1.0, -4.0], [0.0, 1.0, 0.0, 1.0]]);
        // Corner pixel (0,0): camera dir ((0−2)/2, −(0−1)/2, −1) = (−1, 0.5, −1).
        // World = R·d = (−1, −(−1), 0.5) = (−1, 1, 0.5).
        assert_close(pose.ray_direction(&k, 0.0, 0.0), Vec3::new(-1.0, 1.0, 0.5));
        // Centre pixel (2,1): camera (0, 0, −1) → world (0, 1, 0): no +0.5 offset.
        assert_close(pose.ray_direction(&k, 2.0, 1.0), Vec3::new(0.0, 1.0, 0.0));
        // Last corner (3,1): camera (0.5, 0, −1) → world (0.5, 1, 0).
        assert_close(pose.ray_direction(&k, 3.0, 1.0), Vec3::new(0.5, 1.0, 0.0));
        let rays = Rays::for_rows(&k, &pose, 0..2);
        assert_eq!(rays.len(), 8);
        assert_eq!(rays.origins[5], [0.5, -4.0, 1.0]);
        assert_close(Vec3::from_array(rays.directions[0]), Vec3::new(-1.0, 1.0, 0.5));
        assert_close(Vec3::from_array(rays.directions[6]), Vec3::new(0.0, 1.0, 0.0));
        let unit = rays.view_directions();
        assert!((Vec3::from_array(unit[0]).length() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn spherical_pose_looks_at_origin_from_radius() {
        for &(theta, phi) in &[(0.0, -30.0), (90.0, -30.0), (-135.0, 10.0)] {
            let pose = Pose::spherical(theta, phi, 4.0);
            assert!((pose.origin().length() - 4.0).abs() < 1e-5);
            // The camera looks along −z: that axis points from the origin back to the centre.
            let forward = pose.rotation() * Vec3::NEG_Z;
            assert_close(forward, -pose.origin().normalize());
            // Elevation −30° puts the camera above the object (+z up in Blender's world).
            if phi < 0.0 {
                assert!((pose.origin().z - 4.0 * 0.5).abs() < 1e-4, "{:?}", pose.origin());
            }
        }
        // theta = 0, phi = 0: the reference gives the camera at (0, 4, 0)... after the swap:
        // trans (0,0,4) → swap rows (−x, z, y) → (0, 4, 0).
        assert_close(Pose::spherical(0.0, 0.0, 4.0).origin(), Vec3::new(0.0, 4.0, 0.0));
        assert_eq!(Pose::orbit(40).len(), 40);
    }
}
