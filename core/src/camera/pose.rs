//! Camera-to-world poses (OpenGL convention) and points along rays.

use glam::{Mat3, Mat4, Vec3, Vec4};
use serde::{Deserialize, Serialize};

use super::pinhole::PinholeCamera;

/// Frames of the orbit a bundle stores and `nerf demo` renders.
pub const ORBIT_FRAMES: usize = 40;

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
