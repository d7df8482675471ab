//! Pinhole cameras and ray generation, in the bmild/nerf convention.
//!
//! Camera-to-world matrices are OpenGL style: the camera looks down its −z axis with +y up.
//! Ray directions are *not* normalised (their z component in camera space is −1), and pixel
//! centres carry no +0.5 offset — both exactly as the reference code, because the trained
//! networks and the δ scaling depend on it.
//!
//! Rays come from one camera model, [`PinholeCamera`] (focal lengths, principal point, lens
//! distortion); [`Intrinsics`] is the Blender camera it generalises (`PinholeCamera::from`).
//!
//! - [`intrinsics`]: the Blender camera; [`pinhole`]: the full pinhole model of real captures
//!   (fx, fy, cx, cy, pixel convention, OpenCV distortion undone on the rays).
//! - [`pose`]: camera-to-world poses; [`rays`]: pixel → ray.
//! - [`ndc`]: NDC rays for forward-facing scenes; [`transform`]: the recorded normalisation of
//!   a capture's poses.

pub mod intrinsics;
pub mod ndc;
pub mod pinhole;
pub mod pose;
pub mod rays;
pub mod transform;

pub use intrinsics::Intrinsics;
pub use pinhole::{OpenCvDistortion, PinholeCamera, PixelCenter};
pub use pose::{ORBIT_FRAMES, Pose, length, point_at};
pub use rays::Rays;
pub use transform::SceneTransform;

#[cfg(test)]
mod tests;
