//! The Blender camera: image size and one focal length, principal point at the centre.

use serde::{Deserialize, Serialize};

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
