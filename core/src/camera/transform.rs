//! The similarity that maps a capture's poses (any units, any placement) into the field's
//! frame, recorded so that runs and bundles can map later poses the same way (nerfstudio's
//! `dataparser_transforms.json`).
//!
//! A point `x` of the file's world goes to `x' = scale · (R·x + t)`; a camera-to-world pose
//! keeps unit axes: its rotation becomes `R·R_c` and its centre is mapped as a point. Depths
//! and near/far bounds scale by `scale`.

use glam::{Mat3, Vec3};
use serde::{Deserialize, Serialize};

use super::pose::Pose;
use crate::error::{Error, Result};

/// `x' = scale · (rotation · x + translation)`; `rotation` is row-major and orthonormal.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SceneTransform {
    /// Uniform scale, > 0.
    pub scale: f32,
    /// Rotation, row-major (identity when the transform only recentres and scales).
    #[serde(default = "identity_rows")]
    pub rotation: [[f32; 3]; 3],
    /// Translation, applied before the scale (in the file's units).
    pub translation: [f32; 3],
}

fn identity_rows() -> [[f32; 3]; 3] {
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
}

impl Default for SceneTransform {
    fn default() -> Self {
        Self::identity()
    }
}

impl SceneTransform {
    /// Leaves everything in place.
    pub fn identity() -> Self {
        SceneTransform {
            scale: 1.0,
            rotation: identity_rows(),
            translation: [0.0; 3],
        }
    }

    /// From a rotation matrix.
    pub fn new(scale: f32, rotation: Mat3, translation: Vec3) -> Self {
        let r = rotation.transpose().to_cols_array_2d();
        SceneTransform {
            scale,
            rotation: r,
            translation: translation.to_array(),
        }
    }

    /// The rotation as a glam matrix.
    pub fn rotation_matrix(&self) -> Mat3 {
        Mat3::from_cols_array_2d(&self.rotation).transpose()
    }

    /// Centre `centre` at the origin and scale so that the camera farthest from it sits at
    /// distance `radius`. An error when no camera is away from `centre` or a value is not finite.
    pub fn fit_cameras(poses: &[Pose], centre: Vec3, radius: f32) -> Result<Self> {
        let farthest = poses
            .iter()
            .map(|p| (p.origin() - centre).length())
            .fold(0.0f32, f32::max);
        if !(farthest > 0.0 && farthest.is_finite() && radius > 0.0 && radius.is_finite()) {
            return Err(Error::Argument(format!(
                "cannot fit {} cameras into radius {radius} about {centre}: farthest camera at distance {farthest}",
                poses.len()
            )));
        }
        Ok(SceneTransform {
            scale: radius / farthest,
            rotation: identity_rows(),
            translation: (-centre).to_array(),
        })
    }

    /// instant-ngp's mapping of a `transforms.json` into its unit cube, `x·scale + offset`
    /// (its defaults are 0.33 and (0.5, 0.5, 0.5)), shifted so that the cube's centre 0.5 is
    /// the origin: `aabb_scale` then gives the scene box as `[−aabb_scale/2, aabb_scale/2]³`.
    /// (instant-ngp also permutes its axes; the OpenGL world axes are kept here.)
    pub fn instant_ngp(scale: f32, offset: [f32; 3]) -> Self {
        let t = offset.map(|o| (o - 0.5) / scale);
        SceneTransform {
            scale,
            rotation: identity_rows(),
            translation: t,
        }
    }

    /// A point of the file's world in the normalised frame.
    pub fn apply_point(&self, x: Vec3) -> Vec3 {
        self.scale * (self.rotation_matrix() * x + Vec3::from_array(self.translation))
    }

    /// A point of the normalised frame back in the file's world.
    pub fn invert_point(&self, y: Vec3) -> Vec3 {
        self.rotation_matrix().transpose() * (y / self.scale - Vec3::from_array(self.translation))
    }

    /// A camera-to-world pose in the normalised frame.
    pub fn apply_pose(&self, pose: &Pose) -> Pose {
        let r = self.rotation_matrix() * pose.rotation();
        pose_from(r, self.apply_point(pose.origin()))
    }

    /// A pose of the normalised frame back in the file's world.
    pub fn invert_pose(&self, pose: &Pose) -> Pose {
        let r = self.rotation_matrix().transpose() * pose.rotation();
        pose_from(r, self.invert_point(pose.origin()))
    }

    /// This transform followed by `next` (`next.apply_point(self.apply_point(x))`):
    /// `s₂s₁·(R₂R₁·x + R₂t₁ + t₂/s₁)`.
    pub fn then(&self, next: &SceneTransform) -> SceneTransform {
        let (r1, r2) = (self.rotation_matrix(), next.rotation_matrix());
        let t = r2 * Vec3::from_array(self.translation)
            + Vec3::from_array(next.translation) / self.scale;
        SceneTransform::new(self.scale * next.scale, r2 * r1, t)
    }
}

/// A pose from its rotation (camera axes as columns) and centre.
pub(crate) fn pose_from(r: Mat3, origin: Vec3) -> Pose {
    let c = [r.x_axis, r.y_axis, r.z_axis];
    Pose(std::array::from_fn(|row| {
        [c[0][row], c[1][row], c[2][row], origin[row]]
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_close(a: Vec3, b: Vec3) {
        assert!((a - b).abs().max_element() < 1e-5, "{a:?} != {b:?}");
    }

    fn rot_z90() -> Mat3 {
        // x → y, y → −x.
        Mat3::from_cols(Vec3::Y, -Vec3::X, Vec3::Z)
    }

    #[test]
    fn applies_scale_rotation_translation_in_order() {
        let t = SceneTransform::new(2.0, rot_z90(), Vec3::new(1.0, 0.0, -1.0));
        // R·(1, 2, 3) = (−2, 1, 3); + t = (−1, 1, 2); ×2 = (−2, 2, 4).
        assert_close(
            t.apply_point(Vec3::new(1.0, 2.0, 3.0)),
            Vec3::new(-2.0, 2.0, 4.0),
        );
        assert_close(
            t.invert_point(Vec3::new(-2.0, 2.0, 4.0)),
            Vec3::new(1.0, 2.0, 3.0),
        );
        // Row-major storage: the first row of a 90° turn about z is (0, −1, 0).
        assert_eq!(t.rotation[0], [0.0, -1.0, 0.0]);
        // A pose: rotation composed, centre mapped, axes stay unit length.
        let pose = Pose([
            [1.0, 0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0, 2.0],
            [0.0, 1.0, 0.0, 3.0],
        ]);
        let moved = t.apply_pose(&pose);
        assert_close(moved.origin(), Vec3::new(-2.0, 2.0, 4.0));
        // Camera x was world x → now world y.
        assert_close(moved.rotation() * Vec3::X, Vec3::Y);
        assert_close(
            moved.rotation() * Vec3::Z,
            rot_z90() * Vec3::new(0.0, -1.0, 0.0),
        );
        let back = t.invert_pose(&moved);
        for (a, b) in back.0.iter().flatten().zip(pose.0.iter().flatten()) {
            assert!((a - b).abs() < 1e-5, "{back:?} vs {pose:?}");
        }
    }

    #[test]
    fn composition_equals_applying_both() {
        let a = SceneTransform::new(0.5, rot_z90(), Vec3::new(3.0, -1.0, 2.0));
        let b = SceneTransform::new(
            3.0,
            rot_z90().transpose() * rot_z90().transpose(),
            Vec3::new(0.0, 1.0, 0.5),
        );
        let x = Vec3::new(0.7, -1.3, 2.2);
        assert_close(a.then(&b).apply_point(x), b.apply_point(a.apply_point(x)));
        assert_close(
            SceneTransform::identity().then(&a).apply_point(x),
            a.apply_point(x),
        );
    }

    #[test]
    fn fit_cameras_centres_and_scales() {
        let at = |x: f32, y: f32, z: f32| {
            Pose([[1.0, 0.0, 0.0, x], [0.0, 1.0, 0.0, y], [0.0, 0.0, 1.0, z]])
        };
        let poses = [at(10.0, 0.0, 0.0), at(14.0, 0.0, 0.0), at(12.0, 1.0, 0.0)];
        // Centre (12, 0, 0): farthest at 2 → scale 1.5/2 = 0.75.
        let t = SceneTransform::fit_cameras(&poses, Vec3::new(12.0, 0.0, 0.0), 1.5).unwrap();
        assert_eq!(t.scale, 0.75);
        assert_close(t.apply_pose(&poses[1]).origin(), Vec3::new(1.5, 0.0, 0.0));
        assert_close(t.apply_pose(&poses[2]).origin(), Vec3::new(0.0, 0.75, 0.0));
        let err =
            SceneTransform::fit_cameras(&poses[..1], Vec3::new(10.0, 0.0, 0.0), 1.0).unwrap_err();
        assert!(
            err.to_string().contains("farthest camera at distance 0"),
            "{err}"
        );
        assert!(SceneTransform::fit_cameras(&[], Vec3::ZERO, 1.0).is_err());
    }

    #[test]
    fn instant_ngp_cube_centre_is_the_origin() {
        // x·0.33 + 0.5 = 0.5 ⇔ x = 0: the file's origin stays at the origin.
        let t = SceneTransform::instant_ngp(0.33, [0.5; 3]);
        assert_close(t.apply_point(Vec3::ZERO), Vec3::ZERO);
        assert_close(
            t.apply_point(Vec3::new(3.0, 0.0, 0.0)),
            Vec3::new(0.99, 0.0, 0.0),
        );
        // offset (0.6, 0.5, 0.5), scale 0.5: x = (1, 0, 0) → 0.5 + 0.6 − 0.5 = 0.6.
        let t = SceneTransform::instant_ngp(0.5, [0.6, 0.5, 0.5]);
        assert_close(t.apply_point(Vec3::X), Vec3::new(0.6, 0.0, 0.0));
    }

    #[test]
    fn serde_round_trip_and_default_rotation() {
        let t = SceneTransform::new(2.0, rot_z90(), Vec3::new(1.0, 2.0, 3.0));
        let text = serde_json::to_string(&t).unwrap();
        assert_eq!(serde_json::from_str::<SceneTransform>(&text).unwrap(), t);
        let plain: SceneTransform =
            serde_json::from_str(r#"{"scale": 0.5, "translation": [1, 0, 0]}"#).unwrap();
        assert_eq!(plain.rotation, identity_rows());
    }
}
