//! Normalised device coordinates for forward-facing captures, as nerf-pytorch's
//! `ndc_rays(H, W, focal, near, rays_o, rays_d)`.
//!
//! The frustum in front of the (recentred) cameras, from the plane z = −near to infinity, maps
//! to the cube [−1, 1]³: a point (x, y, z) goes to `(−fx/(W/2)·x/z, −fy/(H/2)·y/z, 1 + 2·near/z)`.
//! Each ray is first moved to start on the plane z = −near; in NDC it then runs from t = 0
//! (the near plane) to t = 1 (infinity), so training samples `near = 0, far = 1`.

use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::rays::Rays;
use super::pinhole::PinholeCamera;

/// The NDC projection of one camera: image size, focal length(s) and the near plane.
/// Only the ratios `fx/W`, `fy/H` matter, so one projection serves every downscale.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ndc {
    /// Image width in pixels.
    pub width: f32,
    /// Image height in pixels.
    pub height: f32,
    /// Horizontal focal length (nerf-pytorch has one `focal` for both).
    pub fx: f32,
    /// Vertical focal length.
    pub fy: f32,
    /// Distance of the near plane (nerf-pytorch passes 1.0 after its bounds rescaling).
    pub near: f32,
}

impl Ndc {
    /// nerf-pytorch's parameters: one focal length for both axes.
    pub fn new(width: u32, height: u32, focal: f32, near: f32) -> Self {
        Ndc {
            width: width as f32,
            height: height as f32,
            fx: focal,
            fy: focal,
            near,
        }
    }

    /// The projection of `camera` (nerf-pytorch takes the training images' H, W and focal).
    pub fn for_camera(camera: &PinholeCamera, near: f32) -> Self {
        Ndc { width: camera.width as f32, height: camera.height as f32, fx: camera.fx, fy: camera.fy, near }
    }

    /// Whether every value is finite and positive.
    pub fn is_valid(&self) -> bool {
        [self.width, self.height, self.fx, self.fy, self.near].iter().all(|v| v.is_finite() && *v > 0.0)
    }

    /// A point in camera-aligned world space (z < 0 in front) to NDC.
    pub fn point(&self, p: Vec3) -> Vec3 {
        let (ax, ay) = (-2.0 * self.fx / self.width, -2.0 * self.fy / self.height);
        Vec3::new(ax * p.x / p.z, ay * p.y / p.z, 1.0 + 2.0 * self.near / p.z)
    }

    /// One ray (origin, direction) to NDC, term by term as nerf-pytorch:
    /// `t = −(near + o_z)/d_z`, `o ← o + t·d`, then
    /// `o' = (−fx/(W/2)·o_x/o_z, −fy/(H/2)·o_y/o_z, 1 + 2·near/o_z)`,
    /// `d' = (−fx/(W/2)·(d_x/d_z − o_x/o_z), −fy/(H/2)·(d_y/d_z − o_y/o_z), −2·near/o_z)`.
    /// A ray parallel to the near plane (d_z = 0) gives non-finite values, as in the reference.
    pub fn ray(&self, o: Vec3, d: Vec3) -> (Vec3, Vec3) {
        let t = -(self.near + o.z) / d.z;
        let o = o + t * d;
        let (ax, ay) = (-2.0 * self.fx / self.width, -2.0 * self.fy / self.height);
        let origin = Vec3::new(ax * o.x / o.z, ay * o.y / o.z, 1.0 + 2.0 * self.near / o.z);
        let direction = Vec3::new(
            ax * (d.x / d.z - o.x / o.z),
            ay * (d.y / d.z - o.y / o.z),
            -2.0 * self.near / o.z,
        );
        (origin, direction)
    }

    /// Every ray of a batch to NDC; the world directions stay the view directions.
    ///
    /// # Shapes
    /// `Rays` of `[n]` → `Rays` of `[n]`.
    pub fn rays(&self, rays: Rays) -> Rays {
        let mut out = Rays::with_capacity(rays.len());
        for (o, d) in rays.origins.iter().zip(&rays.directions) {
            let (o, d) = self.ray(Vec3::from_array(*o), Vec3::from_array(*d));
            out.origins.push(o.to_array());
            out.directions.push(d.to_array());
        }
        out.viewdirs = Some(rays.viewdirs.unwrap_or(rays.directions));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_close(a: Vec3, b: Vec3, tol: f32) {
        assert!((a - b).abs().max_element() <= tol, "{a:?} != {b:?}");
    }

    #[test]
    fn matches_nerf_pytorch_on_hand_computed_values() {
        // W = 4, H = 2, focal = 2, near = 1; o = (0.5, −0.5, 0), d = (1, 0.5, −2).
        // t = −(1 + 0)/(−2) = 0.5 → o = (1, −0.25, −1).
        // o' = (−1/(4/4)·1/(−1), −1/(2/4)·(−0.25)/(−1), 1 + 2/(−1)) = (1, −0.5, −1).
        // d' = (−1·(1/(−2) − 1/(−1)), −2·(0.5/(−2) − (−0.25)/(−1)), −2/(−1)) = (−0.5, 1, 2).
        let ndc = Ndc::new(4, 2, 2.0, 1.0);
        let (o, d) = ndc.ray(Vec3::new(0.5, -0.5, 0.0), Vec3::new(1.0, 0.5, -2.0));
        assert_close(o, Vec3::new(1.0, -0.5, -1.0), 1e-6);
        assert_close(d, Vec3::new(-0.5, 1.0, 2.0), 1e-6);
        // The central ray of a camera at the origin: o' = (0, 0, −1), d' = (0, 0, 2).
        let (o, d) = ndc.ray(Vec3::ZERO, Vec3::new(0.0, 0.0, -1.0));
        assert_close(o, Vec3::new(0.0, 0.0, -1.0), 0.0);
        assert_close(d, Vec3::new(0.0, 0.0, 2.0), 0.0);
        // A batch is converted ray by ray.
        let rays = Rays {
            origins: vec![[0.5, -0.5, 0.0], [0.0; 3]],
            directions: vec![[1.0, 0.5, -2.0], [0.0, 0.0, -1.0]],
            viewdirs: None,
        };
        let out = ndc.rays(rays.clone());
        // The networks still see the world directions (nerf-pytorch's viewdirs).
        assert_eq!(out.viewdirs.as_ref(), Some(&rays.directions));
        assert_eq!(out.view_directions()[1], [0.0, 0.0, -1.0]);
        assert_close(
            Vec3::from_array(out.directions[0]),
            Vec3::new(-0.5, 1.0, 2.0),
            1e-6,
        );
        assert_eq!(out.origins[1], [0.0, 0.0, -1.0]);
    }

    #[test]
    fn ndc_ray_passes_through_the_projected_world_points() {
        // Separate focal lengths and an off-axis camera: every world point on the ray beyond
        // the near plane lands on the NDC ray at some t in [0, 1).
        let ndc = Ndc {
            width: 400.0,
            height: 300.0,
            fx: 320.0,
            fy: 300.0,
            near: 1.0,
        };
        let (o, d) = (Vec3::new(0.3, -0.2, 0.4), Vec3::new(0.2, 0.1, -1.0));
        let (on, dn) = ndc.ray(o, d);
        let mut last_t = -1.0;
        for s in [1.4, 2.0, 5.0, 40.0] {
            let p = ndc.point(o + s * d);
            let t = (p.z - on.z) / dn.z;
            assert_close(on + t * dn, p, 1e-5);
            assert!((0.0..1.0).contains(&t) && t > last_t, "t = {t}");
            last_t = t;
        }
        // The near-plane point is t = 0.
        assert_close(ndc.point(o + 1.4 * d), on, 1e-5);
    }
}
