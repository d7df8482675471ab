//! The full pinhole camera of real captures: separate focal lengths, a principal point anywhere,
//! a pixel-centre convention and OpenCV radial-tangential distortion.
//!
//! Directions come out in the OpenGL camera frame of [`crate::camera`] (x right, y up, the
//! camera looking down −z, z component −1). Distortion is defined, as in OpenCV, on the
//! normalised image coordinates with y pointing *down*: `x = (u − cx)/fx`, `y = (v − cy)/fy`.
//! Rays are undistorted (the images are left as they are), as instant-ngp and nerfstudio do.

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::camera::Intrinsics;
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
mod tests {
    use super::*;
    use crate::camera::Pose;

    const D: OpenCvDistortion = OpenCvDistortion {
        k1: 0.1,
        k2: 0.01,
        p1: 0.001,
        p2: 0.002,
    };

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn distortion_matches_hand_computed_values() {
        // r² = 0.3125, r⁴ = 0.09765625, radial = 1 + 0.03125 + 0.0009765625 = 1.0322265625.
        // xd = 0.5·radial + 2·0.001·0.5·(−0.25) + 0.002·(0.3125 + 0.5)
        //    = 0.51611328125 − 0.00025 + 0.001625 = 0.51748828125.
        // yd = −0.25·radial + 0.001·(0.3125 + 0.125) + 2·0.002·0.5·(−0.25)
        //    = −0.258056640625 + 0.0004375 − 0.0005 = −0.258119140625.
        // (The coefficients are f32: 0.1 is 0.100000001…, hence tolerances of 1e-8.)
        let (xd, yd) = D.distort(0.5, -0.25);
        assert!(
            close(xd, 0.51748828125, 1e-8) && close(yd, -0.258119140625, 1e-8),
            "{xd} {yd}"
        );
        // Pure radial on the axis: k1 = 0.1 at (1, 0): radial = 1.1 + 0.01 (k2) → 1.11.
        let radial = OpenCvDistortion {
            k1: 0.1,
            k2: 0.01,
            p1: 0.0,
            p2: 0.0,
        };
        assert!(close(radial.distort(1.0, 0.0).0, 1.11, 1e-8));
        // The centre never moves; all-zero coefficients are the identity.
        assert_eq!(D.distort(0.0, 0.0), (0.0, 0.0));
        let zero = OpenCvDistortion {
            k1: 0.0,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
        };
        assert!(zero.is_zero() && !D.is_zero());
        assert_eq!(zero.distort(0.3, -0.7), (0.3, -0.7));
    }

    #[test]
    fn distortion_jacobian_matches_finite_differences() {
        let h = 1e-6;
        for &(x, y) in &[(0.5, -0.25), (-0.8, 0.6), (0.1, 0.9), (0.0, 0.0)] {
            let (_, jac) = D.distort_with_jacobian(x, y);
            let (xp, yp) = D.distort(x + h, y);
            let (xm, ym) = D.distort(x - h, y);
            let (xq, yq) = D.distort(x, y + h);
            let (xn, yn) = D.distort(x, y - h);
            let numeric = [
                [(xp - xm) / (2.0 * h), (xq - xn) / (2.0 * h)],
                [(yp - ym) / (2.0 * h), (yq - yn) / (2.0 * h)],
            ];
            for r in 0..2 {
                for c in 0..2 {
                    assert!(
                        close(jac[r][c], numeric[r][c], 1e-7),
                        "({x}, {y}) [{r}][{c}]: {jac:?} vs {numeric:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn undistort_inverts_distort() {
        // The fox capture's coefficients and a strong barrel lens.
        let fox = OpenCvDistortion {
            k1: 0.0578421,
            k2: -0.0805099,
            p1: -0.000980296,
            p2: 0.00015575,
        };
        let barrel = OpenCvDistortion {
            k1: -0.3,
            k2: 0.1,
            p1: 0.002,
            p2: -0.001,
        };
        for d in [D, fox, barrel] {
            for k in 0..50 {
                // Points over a normalised image of ±0.8 × ±0.6.
                let (x, y) = (
                    -0.8 + 1.6 * (k % 10) as f64 / 9.0,
                    -0.6 + 1.2 * (k / 10) as f64 / 4.0,
                );
                let (xd, yd) = d.distort(x, y);
                let (ux, uy) = d.undistort(xd, yd);
                assert!(
                    close(ux, x, 1e-10) && close(uy, y, 1e-10),
                    "{d:?} ({x}, {y}) → ({ux}, {uy})"
                );
            }
        }
        // Hand value: undistort(0.51748828125, −0.258119140625) = (0.5, −0.25).
        let (x, y) = D.undistort(0.51748828125, -0.258119140625);
        assert!(close(x, 0.5, 1e-8) && close(y, -0.25, 1e-8), "{x} {y}");
    }

    fn camera(pixel_center: PixelCenter, distortion: Option<OpenCvDistortion>) -> PinholeCamera {
        PinholeCamera {
            width: 4,
            height: 2,
            fx: 2.0,
            fy: 4.0,
            cx: 2.5,
            cy: 1.5,
            pixel_center,
            distortion,
        }
    }

    #[test]
    fn directions_follow_the_pixel_convention() {
        let half = camera(PixelCenter::HalfPixel, None);
        // (0.5 − 2.5)/2 = −1, −(0.5 − 1.5)/4 = 0.25.
        assert_eq!(half.camera_direction(0.0, 0.0), Vec3::new(-1.0, 0.25, -1.0));
        // Pixel (2, 1) is centred on (2.5, 1.5): the optical axis.
        assert_eq!(half.camera_direction(2.0, 1.0), Vec3::new(0.0, 0.0, -1.0));
        let integer = camera(PixelCenter::Integer, None);
        // (0 − 2.5)/2 = −1.25, −(0 − 1.5)/4 = 0.375.
        assert_eq!(
            integer.camera_direction(0.0, 0.0),
            Vec3::new(-1.25, 0.375, -1.0)
        );
        // With distortion: the normalised point (−1, −0.25) (y down) is undistorted, then y flips.
        let distorted = camera(PixelCenter::HalfPixel, Some(D));
        let dir = distorted.camera_direction(0.0, 0.0);
        let (x, y) = D.undistort(-1.0, -0.25);
        assert!(close(dir.x as f64, x, 1e-6) && close(dir.y as f64, -y, 1e-6) && dir.z == -1.0);
        // Distortion pulls an edge ray outwards under k1 > 0, so undistorting moves it in.
        assert!(dir.x > -1.0, "{dir:?}");
    }

    #[test]
    fn fox_directions_match_opencv_undistort_points() {
        // The fox capture's camera; expected values from OpenCV 5.0's
        // `cv2.undistortPoints([[i + 0.5, j + 0.5]], K, (k1, k2, p1, p2))` (100 iterations),
        // y negated into OpenGL.
        let fox = PinholeCamera {
            width: 216,
            height: 384,
            fx: 275.104,
            fy: 274.898,
            cx: 110.9116,
            cy: 193.0536,
            pixel_center: PixelCenter::HalfPixel,
            distortion: Some(OpenCvDistortion {
                k1: 0.0578421,
                k2: -0.0805099,
                p1: -0.000980296,
                p2: 0.00015575,
            }),
        };
        let cases: [((f32, f32), (f64, f64)); 4] = [
            ((0.0, 0.0), (-0.39941427, 0.69628246)),
            ((215.0, 383.0), (0.37869988, -0.69087819)),
            ((100.0, 17.0), (-0.03747789, 0.63097599)),
            ((3.0, 300.0), (-0.38691716, -0.38757754)),
        ];
        for ((i, j), (x, y)) in cases {
            let d = fox.camera_direction(i, j);
            let (dx, dy) = (d.x as f64, d.y as f64);
            assert!(
                (dx - x).abs() < 2e-6 && (dy - y).abs() < 2e-6 && d.z == -1.0,
                "({i}, {j}): {d:?}"
            );
        }
    }

    #[test]
    fn project_inverts_camera_direction() {
        for c in [
            camera(PixelCenter::HalfPixel, Some(D)),
            camera(PixelCenter::Integer, None),
        ] {
            for &(i, j) in &[(0.0, 0.0), (3.0, 1.0), (1.25, 0.5)] {
                let (pi, pj) = c.project(c.camera_direction(i, j)).unwrap();
                assert!(
                    (pi - i).abs() < 1e-4 && (pj - j).abs() < 1e-4,
                    "({i}, {j}) → ({pi}, {pj})"
                );
            }
            assert_eq!(c.project(Vec3::new(0.0, 0.0, 1.0)), None);
        }
    }

    #[test]
    fn intrinsics_round_trip_and_refusals() {
        let k = Intrinsics {
            width: 400,
            height: 300,
            focal: 323.5,
        };
        let c = PinholeCamera::from_intrinsics(&k);
        assert_eq!((c.cx, c.cy, c.fx, c.fy), (200.0, 150.0, 323.5, 323.5));
        assert_eq!(c.to_intrinsics().unwrap(), k);
        // The Blender rays, bit for bit: ((i − W/2)/f, −(j − H/2)/f, −1) in f32.
        for &(i, j) in &[(0.0f32, 0.0f32), (399.0, 17.0), (123.0, 299.0), (7.0, 3.0)] {
            let blender = Vec3::new((i - 200.0) / 323.5, -(j - 150.0) / 323.5, -1.0);
            assert_eq!(c.camera_direction(i, j), blender);
        }
        // A half-pixel camera centred on (W/2 + 0.5, H/2 + 0.5) is the same camera.
        let shifted = PinholeCamera {
            cx: 200.5,
            cy: 150.5,
            pixel_center: PixelCenter::HalfPixel,
            ..c
        };
        assert_eq!(shifted.to_intrinsics().unwrap(), k);
        assert_eq!(
            c.resized(100, 75).to_intrinsics().unwrap(),
            k.resized(100, 75)
        );
        let msg = |c: PinholeCamera| c.to_intrinsics().unwrap_err().to_string();
        assert!(msg(PinholeCamera { fy: 300.0, ..c }).contains("fy = 300"));
        // The fox's principal point (edge convention) is not the centre in integer pixels.
        let fox = PinholeCamera {
            cx: 110.9116,
            pixel_center: PixelCenter::HalfPixel,
            width: 216,
            ..c
        };
        assert!(msg(fox).contains("principal point"), "{}", msg(fox));
        assert!(
            msg(PinholeCamera {
                distortion: Some(D),
                ..c
            })
            .contains("distortion")
        );
        // Zero coefficients are no distortion.
        let zero = Some(OpenCvDistortion {
            k1: 0.0,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
        });
        assert!(
            PinholeCamera {
                distortion: zero,
                ..c
            }
            .to_intrinsics()
            .is_ok()
        );
    }

    #[test]
    fn resizing_scales_focal_and_principal_point() {
        let c = PinholeCamera {
            width: 1080,
            height: 1920,
            fx: 1375.52,
            fy: 1374.49,
            cx: 554.558,
            cy: 965.268,
            pixel_center: PixelCenter::HalfPixel,
            distortion: Some(D),
        };
        let small = c.resized(216, 384);
        assert!(
            (small.fx - 275.104).abs() < 1e-3 && (small.cy - 193.0536).abs() < 1e-3,
            "{small:?}"
        );
        assert_eq!(small.distortion, c.distortion);
        // In pixel-edge coordinates the same point of the scene keeps its relative position:
        // the ray through the original pixel edge 540 is the ray through the small one's 108.
        let big = c.camera_direction(540.0 - 0.5, 960.0 - 0.5);
        let sm = small.camera_direction(108.0 - 0.5, 192.0 - 0.5);
        assert!((big - sm).abs().max_element() < 1e-5, "{big:?} {sm:?}");
    }

    #[test]
    fn json_reads_the_full_model_and_the_older_focal() {
        let c = camera(PixelCenter::HalfPixel, Some(D));
        let text = serde_json::to_string(&c).unwrap();
        assert!(text.contains("\"pixel_center\":\"half_pixel\"") && text.contains("\"k1\":0.1"), "{text}");
        assert_eq!(serde_json::from_str::<PinholeCamera>(&text).unwrap(), c);
        // A camera.json written before: focal only → the Blender camera.
        let old: PinholeCamera =
            serde_json::from_str(r#"{"width": 400, "height": 300, "focal": 323.5}"#).unwrap();
        let k = Intrinsics { width: 400, height: 300, focal: 323.5 };
        assert_eq!(old, PinholeCamera::from(k));
        // Neither fx nor focal: NaN, refused by the limits check (naming fx).
        let none: PinholeCamera = serde_json::from_str(r#"{"width": 4, "height": 4}"#).unwrap();
        assert!(none.fx.is_nan());
    }

    #[test]
    fn rays_rotate_into_the_world() {
        // c2w: camera x → world x, camera y → world z, camera z → world −y; centre (0.5, −4, 1).
        let pose = Pose([
            [1.0, 0.0, 0.0, 0.5],
            [0.0, 0.0, -1.0, -4.0],
            [0.0, 1.0, 0.0, 1.0],
        ]);
        let c = camera(PixelCenter::HalfPixel, None);
        let rays = crate::camera::Rays::for_pixels(&c, &pose, &[(0, 0), (2, 1)]);
        // Camera (−1, 0.25, −1) → world (−1, 1, 0.25); the axis (0, 0, −1) → (0, 1, 0).
        assert_eq!(rays.directions, vec![[-1.0, 1.0, 0.25], [0.0, 1.0, 0.0]]);
        assert_eq!(rays.origins, vec![[0.5, -4.0, 1.0]; 2]);
        assert_eq!(c.num_pixels(), 8);
    }
}
