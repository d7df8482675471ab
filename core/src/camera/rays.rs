//! Batches of rays from a camera and a pose.

use super::pinhole::PinholeCamera;
use super::pose::Pose;
use glam::Vec3;

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
        Rays::for_image_points(camera, pose, pixels.iter().map(|&(i, j)| (i as f32, j as f32)))
    }

    /// The rays through image points `(column, row)` in pixel units, fractional: a pixel's
    /// ray is at its integer coordinates, so `(i ± 0.5, j ± 0.5)` are the corners of its area
    /// (training rays jittered within their pixel, as instant-ngp draws them).
    pub fn for_image_points(camera: &PinholeCamera, pose: &Pose, points: impl ExactSizeIterator<Item = (f32, f32)>) -> Rays {
        let rotation = pose.rotation();
        let origin = pose.origin().to_array();
        let mut rays = Rays::with_capacity(points.len());
        for (x, y) in points {
            let d = rotation * camera.camera_direction(x, y);
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
