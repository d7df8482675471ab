//! The full pinhole camera of real captures: separate focal lengths, a principal point anywhere,
//! a pixel-centre convention and OpenCV radial-tangential distortion.
//!
//! Directions come out in the OpenGL camera frame of [`crate::camera`] (x right, y up, the
//! camera looking down −z, z component −1). Distortion is defined, as in OpenCV, on the
//! normalised image coordinates with y pointing *down*: `x = (u − cx)/fx`, `y = (v − cy)/fy`.
//! Rays are undistorted (the images are left as they are), as instant-ngp and nerfstudio do.

use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::intrinsics::Intrinsics;
use crate::error::{Error, Result};

/// Where the ray of pixel (column `i`, row `j`) crosses the image plane, in the coordinates
/// that `cx`, `cy` are given in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PixelCenter {
    /// Through `(i, j)`: bmild/nerf, nerf-pytorch, our Blender loader (principal point W/2, H/2).
    Integer,
    /// Through `(i + 0.5, j + 0.5)`: instant-ngp, nerfstudio, OpenCV/COLMAP (pixel-edge
    /// coordinates, the image spans `[0, W] × [0, H]`).
    HalfPixel,
}

impl PixelCenter {
    /// The offset added to the integer pixel index: 0 or 0.5.
    pub fn offset(self) -> f32 {
        match self {
            PixelCenter::Integer => 0.0,
            PixelCenter::HalfPixel => 0.5,
        }
    }
}

/// OpenCV's radial-tangential model (`k1, k2, p1, p2`; k3 = 0) on normalised coordinates:
/// with `r² = x² + y²` and `radial = 1 + k1·r² + k2·r⁴`,
/// `x_d = x·radial + 2·p1·x·y + p2·(r² + 2x²)`, `y_d = y·radial + p1·(r² + 2y²) + 2·p2·x·y`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OpenCvDistortion {
    /// r² radial coefficient.
    pub k1: f32,
    /// r⁴ radial coefficient.
    pub k2: f32,
    /// First tangential coefficient.
    pub p1: f32,
    /// Second tangential coefficient.
    pub p2: f32,
}

/// Newton steps of [`OpenCvDistortion::undistort`] at most (it stops earlier once converged).
const UNDISTORT_MAX_STEPS: usize = 20;

impl OpenCvDistortion {
    /// Whether every coefficient is zero (the model is then the identity).
    pub fn is_zero(&self) -> bool {
        [self.k1, self.k2, self.p1, self.p2]
            .iter()
            .all(|&c| c == 0.0)
    }

    /// Undistorted → distorted normalised coordinates (y down).
    ///
    /// Example: k1 = 0.1, k2 = 0.01, p1 = 0.001, p2 = 0.002 moves (0.5, −0.25) to
    /// (0.517 488 281 25, −0.258 119 140 625).
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let (d, _) = self.distort_with_jacobian(x, y);
        d
    }

    /// The distorted point and the Jacobian `[[∂xd/∂x, ∂xd/∂y], [∂yd/∂x, ∂yd/∂y]]`.
    fn distort_with_jacobian(&self, x: f64, y: f64) -> ((f64, f64), [[f64; 2]; 2]) {
        let (k1, k2, p1, p2) = (
            self.k1 as f64,
            self.k2 as f64,
            self.p1 as f64,
            self.p2 as f64,
        );
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + k2 * r2);
        // ∂radial/∂(r²) · ∂(r²)/∂x = (k1 + 2·k2·r²)·2x.
        let dradial = k1 + 2.0 * k2 * r2;
        let (drx, dry) = (dradial * 2.0 * x, dradial * 2.0 * y);
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        let jacobian = [
            [
                radial + x * drx + 2.0 * p1 * y + 6.0 * p2 * x,
                x * dry + 2.0 * p1 * x + 2.0 * p2 * y,
            ],
            [
                y * drx + 2.0 * p1 * x + 2.0 * p2 * y,
                radial + y * dry + 6.0 * p1 * y + 2.0 * p2 * x,
            ],
        ];
        ((xd, yd), jacobian)
    }

    /// Distorted → undistorted normalised coordinates: Newton's method on
    /// `distort(x, y) − (xd, yd) = 0` from `(xd, yd)` (as nerfstudio's
    /// `radial_and_tangential_undistort`), at most 20 steps, stopping when a step moves less
    /// than 1e-12. Converges for any calibrated lens inside its image; a point where the model
    /// folds over (Jacobian singular) keeps the last estimate.
    pub fn undistort(&self, xd: f64, yd: f64) -> (f64, f64) {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..UNDISTORT_MAX_STEPS {
            let ((fx, fy), [[a, b], [c, d]]) = self.distort_with_jacobian(x, y);
            let (rx, ry) = (fx - xd, fy - yd);
            let det = a * d - b * c;
            if det.abs() < 1e-12 {
                break;
            }
            // Solve J·Δ = r by Cramer's rule.
            let dx = (d * rx - b * ry) / det;
            let dy = (a * ry - c * rx) / det;
            x -= dx;
            y -= dy;
            if dx.abs().max(dy.abs()) < 1e-12 {
                break;
            }
        }
        (x, y)
    }
}

/// A pinhole camera with its own focal lengths, principal point, pixel convention and lens
/// distortion (sizes in pixels, at the resolution the images are used at).
///
/// In JSON (`camera.json`, `scene.json`): `width, height, fx, fy, cx, cy, pixel_center`
/// (`"integer"` or `"half_pixel"`), `distortion` (`{k1, k2, p1, p2}` or null). Files written
/// before the full model carry `focal` alone and still read: `fx = fy = focal`, the principal
/// point at the centre, integer pixel centres (the Blender camera).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(from = "CameraRecord")]
pub struct PinholeCamera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Horizontal focal length in pixels.
    pub fx: f32,
    /// Vertical focal length in pixels.
    pub fy: f32,
    /// Principal point, horizontal, in the coordinates of `pixel_center`.
    pub cx: f32,
    /// Principal point, vertical (rows grow downwards).
    pub cy: f32,
    /// Which point of pixel (i, j) its ray passes through.
    pub pixel_center: PixelCenter,
    /// Lens distortion, `None` for an ideal pinhole.
    pub distortion: Option<OpenCvDistortion>,
}

/// A camera as stored: the full model, or the older `focal` alone (see [`PinholeCamera`]).
/// A missing focal length reads as NaN, which the limits check refuses naming `fx`.
#[derive(Deserialize)]
struct CameraRecord {
    width: u32,
    height: u32,
    focal: Option<f32>,
    fx: Option<f32>,
    fy: Option<f32>,
    cx: Option<f32>,
    cy: Option<f32>,
    pixel_center: Option<PixelCenter>,
    #[serde(default)]
    distortion: Option<OpenCvDistortion>,
}

impl From<CameraRecord> for PinholeCamera {
    fn from(r: CameraRecord) -> Self {
        let fx = r.fx.or(r.focal).unwrap_or(f32::NAN);
        PinholeCamera {
            width: r.width,
            height: r.height,
            fx,
            fy: r.fy.unwrap_or(fx),
            cx: r.cx.unwrap_or(0.5 * r.width as f32),
            cy: r.cy.unwrap_or(0.5 * r.height as f32),
            pixel_center: r.pixel_center.unwrap_or(PixelCenter::Integer),
            distortion: r.distortion,
        }
    }
}

impl From<Intrinsics> for PinholeCamera {
    fn from(k: Intrinsics) -> Self {
        PinholeCamera::from_intrinsics(&k)
    }
}

impl PinholeCamera {
    /// Today's [`Intrinsics`] as a full camera: `fx = fy = focal`, principal point at the
    /// image centre, [`PixelCenter::Integer`], no distortion.
    pub fn from_intrinsics(k: &Intrinsics) -> Self {
        PinholeCamera {
            width: k.width,
            height: k.height,
            fx: k.focal,
            fy: k.focal,
            cx: 0.5 * k.width as f32,
            cy: 0.5 * k.height as f32,
            pixel_center: PixelCenter::Integer,
            distortion: None,
        }
    }

    /// The same camera as [`Intrinsics`] when that loses nothing: one focal length (to 1e-4
    /// relative), the ray of pixel (i, j) through the image centre exactly where
    /// `Intrinsics::camera_direction` puts it (to 1e-3 px), and no distortion. Otherwise an
    /// error saying what `Intrinsics` cannot express.
    pub fn to_intrinsics(&self) -> Result<Intrinsics> {
        let unsupported = |what: String| {
            Err(Error::Argument(format!(
                "the camera cannot be expressed as Intrinsics: {what}"
            )))
        };
        if (self.fx - self.fy).abs() > 1e-4 * self.fx.abs() {
            return unsupported(format!("fx = {} and fy = {} differ", self.fx, self.fy));
        }
        let offset = self.pixel_center.offset();
        let (cx, cy) = (self.cx - offset, self.cy - offset);
        let (w2, h2) = (0.5 * self.width as f32, 0.5 * self.height as f32);
        if (cx - w2).abs() > 1e-3 || (cy - h2).abs() > 1e-3 {
            return unsupported(format!(
                "the principal point is ({cx}, {cy}) in integer pixel coordinates, not the centre ({w2}, {h2})"
            ));
        }
        if self.distortion.is_some_and(|d| !d.is_zero()) {
            return unsupported("it has lens distortion".into());
        }
        Ok(Intrinsics {
            width: self.width,
            height: self.height,
            focal: self.fx,
        })
    }

    /// The same camera at another resolution: focal lengths and principal point scale with
    /// each side (exact in pixel-edge coordinates, and equal to `Intrinsics::resized` for a
    /// centred camera); distortion, defined on normalised coordinates, is unchanged.
    pub fn resized(&self, width: u32, height: u32) -> Self {
        let sx = width as f32 / self.width as f32;
        let sy = height as f32 / self.height as f32;
        PinholeCamera {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            ..*self
        }
    }

    /// Normalised, still distorted coordinates (y down) of the ray through pixel (i, j).
    fn distorted_normalised(&self, i: f32, j: f32) -> (f64, f64) {
        let offset = self.pixel_center.offset() as f64;
        (
            (i as f64 + offset - self.cx as f64) / self.fx as f64,
            (j as f64 + offset - self.cy as f64) / self.fy as f64,
        )
    }

    /// The camera-space (OpenGL) direction of the ray through pixel column `i`, row `j`, with
    /// z = −1: `(x, −y, −1)` for the undistorted normalised coordinates `(x, y)`.
    ///
    /// Example: W = 4, H = 2, fx = 2, fy = 4, cx = 2.5, cy = 1.5, half-pixel centres, no
    /// distortion: pixel (0, 0) → ((0.5 − 2.5)/2, −(0.5 − 1.5)/4, −1) = (−1, 0.25, −1).
    pub fn camera_direction(&self, i: f32, j: f32) -> Vec3 {
        let (xd, yd) = self.distorted_normalised(i, j);
        let (x, y) = match &self.distortion {
            Some(d) => d.undistort(xd, yd),
            None => (xd, yd),
        };
        Vec3::new(x as f32, -y as f32, -1.0)
    }

    /// The pixel (column, row, fractional) whose ray has camera-space direction `dir`, or
    /// `None` when `dir` does not point in front of the camera (z ≥ 0). Inverse of
    /// [`PinholeCamera::camera_direction`].
    pub fn project(&self, dir: Vec3) -> Option<(f32, f32)> {
        if dir.z >= 0.0 {
            return None;
        }
        let (x, y) = ((dir.x / -dir.z) as f64, (-dir.y / -dir.z) as f64);
        let (xd, yd) = match &self.distortion {
            Some(d) => d.distort(x, y),
            None => (x, y),
        };
        let offset = self.pixel_center.offset() as f64;
        let i = xd * self.fx as f64 + self.cx as f64 - offset;
        let j = yd * self.fy as f64 + self.cy as f64 - offset;
        Some((i as f32, j as f32))
    }

    /// Number of pixels.
    pub fn num_pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

#[cfg(test)]
mod tests;
