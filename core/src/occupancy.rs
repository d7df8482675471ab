//! Empty-space skipping: an occupancy grid over the scene's bounding cube (instant-ngp's density
//! grid, nerfacc's `OccupancyGrid`).
//!
//! Each cell keeps a running estimate of the largest density seen in it: every update evaluates
//! the density at one random point per cell and stores `max(decay · old, new)`. Cells whose
//! estimate is at most `threshold` are empty; samples there are not sent to the network and
//! count as σ = 0. Points outside the cube are empty too. Before its first update every cell is
//! occupied (the estimate is +∞), so a fresh grid changes nothing.
//!
//! # File format (`occupancy.bin`, little-endian)
//! | bytes | content |
//! |---|---|
//! | 8 | magic `NERFOCC1` |
//! | 4 | `u32` resolution R (cells per axis) |
//! | 4 | `f32` bound b: the grid covers [−b, b]³ in world coordinates |
//! | 4 | `f32` threshold: a cell is occupied when its density estimate is greater |
//! | 4·R³ | `f32` density estimates, cell (i, j, k) at index (i·R + j)·R + k, where i, j, k index x, y, z |
//!
//! From numpy: `np.fromfile(f, "<f4", offset=20).reshape(R, R, R) > threshold`.

use crate::error::{Error, Result};
use crate::rng::Rng;
use crate::camera::{Intrinsics, Pose};
use crate::camera::Rays;
use crate::compositing::{RayOutput, TRANSMITTANCE_EPS, alpha_from_density, over_white};
use crate::render::{Field, MARCH_SEGMENT, RenderOptions, RenderedImage, Stage, render_image, render_image_by};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The grid's file name in checkpoints and scene bundles.
pub const FILE_NAME: &str = "occupancy.bin";
const MAGIC: &[u8; 8] = b"NERFOCC1";
const HEADER_BYTES: usize = 20;

/// How the grid is built and maintained during training.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OccupancyConfig {
    /// Cells per axis.
    pub resolution: usize,
    /// The grid covers [−bound, bound]³ (Blender synthetic scenes fit in 1.5).
    pub bound: f32,
    /// Density (σ, after ReLU) above which a cell counts as occupied.
    pub threshold: f32,
    /// Per-update decay of the running maximum.
    pub decay: f32,
    /// Steps between updates.
    pub update_every: usize,
    /// Steps of dense training before the first update.
    pub warmup_steps: usize,
}

impl Default for OccupancyConfig {
    fn default() -> Self {
        OccupancyConfig { resolution: 64, bound: 1.5, threshold: 0.05, decay: 0.95, update_every: 16, warmup_steps: 256 }
    }
}

/// The grid itself.
#[derive(Debug, Clone, PartialEq)]
pub struct OccupancyGrid {
    resolution: usize,
    bound: f32,
    threshold: f32,
    density: Vec<f32>,
}

impl OccupancyGrid {
    /// A grid with every cell occupied (no information yet).
    pub fn new(resolution: usize, bound: f32, threshold: f32) -> Self {
        OccupancyGrid { resolution, bound, threshold, density: vec![f32::INFINITY; resolution.pow(3)] }
    }

    /// A fresh grid as `config` describes.
    pub fn from_config(config: &OccupancyConfig) -> Self {
        Self::new(config.resolution, config.bound, config.threshold)
    }

    /// Cells per axis.
    pub fn resolution(&self) -> usize {
        self.resolution
    }

    /// Half the side of the covered cube.
    pub fn bound(&self) -> f32 {
        self.bound
    }

    /// The density above which a cell is occupied.
    pub fn threshold(&self) -> f32 {
        self.threshold
    }

    /// The same grid with another occupancy threshold (render-time tuning: higher skips more).
    pub fn with_threshold(mut self, threshold: f32) -> Self {
        self.threshold = threshold;
        self
    }

    /// Number of cells.
    pub fn len(&self) -> usize {
        self.density.len()
    }

    /// Whether the grid has no cells.
    pub fn is_empty(&self) -> bool {
        self.density.is_empty()
    }

    /// The cell holding `p`, or `None` outside the cube.
    pub fn cell(&self, p: [f32; 3]) -> Option<usize> {
        let r = self.resolution;
        let mut index = 0;
        for v in p {
            let u = (v + self.bound) / (2.0 * self.bound) * r as f32;
            // `!(u >= 0)` also rejects NaN.
            if !(u >= 0.0) || u >= r as f32 {
                return None;
            }
            index = index * r + u as usize;
        }
        Some(index)
    }

    /// Whether `p` lies in an occupied cell.
    pub fn is_occupied(&self, p: [f32; 3]) -> bool {
        self.cell(p).is_some_and(|c| self.density[c] > self.threshold)
    }

    /// Indices of the points that lie in occupied cells, in order.
    pub fn occupied_indices(&self, points: &[[f32; 3]]) -> Vec<usize> {
        (0..points.len()).filter(|&i| self.is_occupied(points[i])).collect()
    }

    /// Fraction of cells that are occupied.
    pub fn occupied_fraction(&self) -> f32 {
        self.density.iter().filter(|d| **d > self.threshold).count() as f32 / self.len().max(1) as f32
    }

    /// One uniformly random point inside every cell, in cell order.
    pub fn random_cell_points(&self, rng: &mut Rng) -> Vec<[f32; 3]> {
        let r = self.resolution;
        let size = 2.0 * self.bound / r as f32;
        (0..self.len())
            .map(|c| {
                let (i, j, k) = (c / (r * r), (c / r) % r, c % r);
                [i, j, k].map(|n| -self.bound + (n as f32 + rng.uniform()) * size)
            })
            .collect()
    }

    /// Fold in densities (σ after ReLU) measured at one point per cell (cell order, as from
    /// [`random_cell_points`](Self::random_cell_points)).
    pub fn update(&mut self, sigma: &[f32], decay: f32) {
        assert_eq!(sigma.len(), self.len(), "one density per cell");
        for (d, &s) in self.density.iter_mut().zip(sigma) {
            let s = s.max(0.0);
            *d = if d.is_finite() { (*d * decay).max(s) } else { s };
        }
    }

    /// Serialise in the documented format.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(HEADER_BYTES + 4 * self.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&(self.resolution as u32).to_le_bytes());
        out.extend_from_slice(&self.bound.to_le_bytes());
        out.extend_from_slice(&self.threshold.to_le_bytes());
        for d in &self.density {
            out.extend_from_slice(&d.to_le_bytes());
        }
        out
    }

    /// Parse the documented format; `path` only names the source in errors.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self> {
        let bad = |problem: String| Error::invalid(path, problem);
        if bytes.len() < HEADER_BYTES || &bytes[..8] != MAGIC {
            return Err(bad("not an occupancy grid (missing NERFOCC1 header)".into()));
        }
        let word = |at: usize| [bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]];
        let resolution = u32::from_le_bytes(word(8)) as usize;
        let bound = f32::from_le_bytes(word(12));
        let threshold = f32::from_le_bytes(word(16));
        if resolution == 0 || resolution > 1024 || !(bound > 0.0 && bound.is_finite()) || !threshold.is_finite() {
            return Err(bad(format!("bad header: resolution {resolution}, bound {bound}, threshold {threshold}")));
        }
        let want = HEADER_BYTES + 4 * resolution.pow(3);
        if bytes.len() != want {
            return Err(bad(format!("{} bytes, expected {want} for a {resolution}³ grid (truncated?)", bytes.len())));
        }
        let density = bytes[HEADER_BYTES..].chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        Ok(OccupancyGrid { resolution, bound, threshold, density })
    }

    /// Read a grid file.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = crate::error::read_regular_file(path)?;
        Self::from_bytes(&bytes, path)
    }

    /// Write a grid file atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        crate::error::write_atomic(path, &self.to_bytes())
    }
}

/// Render `rays` by marching through the grid's occupied cells with the last stage's network
/// (fine if there is one): `steps` equal intervals over [near, far], one sample at each
/// interval's middle, only those in occupied cells evaluated (packed), front to back
/// [`MARCH_SEGMENT`] at a time, each ray stopping once its transmittance is below
/// `min_transmittance`. Unevaluated intervals are empty (σ = 0); evaluated ones get
/// α = 1 − exp(−σ·δ) with δ = the interval length · ‖d‖. Compositing is the reference one
/// (exclusive product of 1 − α + 1e-10, white background as rgb + 1 − acc).
pub fn march_rays<F: Field>(
    field: &mut F,
    grid: &OccupancyGrid,
    rays: &Rays,
    options: &RenderOptions,
) -> std::result::Result<Vec<RayOutput>, F::Error> {
    let s = &options.sampling;
    let steps = options.march_steps.max(1);
    let stage = if s.n_fine > 0 { Stage::Fine } else { Stage::Coarse };
    let min_transmittance = options.min_transmittance.unwrap_or(0.0);
    let interval = (s.far - s.near) / steps as f32;
    let viewdirs = rays.view_directions();
    // Each sample's δ: the interval in world units along its (unnormalised) ray.
    let deltas: Vec<f32> = rays.directions.iter().map(|d| interval * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()).collect();
    // Per ray: the occupied interval midpoints, front to back.
    let occupied: Vec<Vec<f32>> = (0..rays.len())
        .map(|r| {
            let (o, d) = (rays.origins[r], rays.directions[r]);
            (0..steps)
                .map(|k| s.near + (k as f32 + 0.5) * interval)
                .filter(|&t| grid.is_occupied([o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]))
                .collect()
        })
        .collect();
    let mut out = vec![RayOutput::default(); rays.len()];
    let mut transmittance = vec![1.0f32; rays.len()];
    let mut next = vec![0usize; rays.len()];
    let mut active: Vec<usize> = (0..rays.len()).filter(|&r| !occupied[r].is_empty()).collect();
    let (mut points, mut dirs, mut owner) = (Vec::new(), Vec::new(), Vec::new());
    while !active.is_empty() {
        points.clear();
        dirs.clear();
        owner.clear();
        for &r in &active {
            let (o, d) = (rays.origins[r], rays.directions[r]);
            let end = (next[r] + MARCH_SEGMENT).min(occupied[r].len());
            for &t in &occupied[r][next[r]..end] {
                points.push([o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]);
                dirs.push(viewdirs[r]);
                owner.push((r, t));
            }
            next[r] = end;
        }
        let part = field.evaluate(stage, &points, &dirs)?;
        for (j, &(r, t)) in owner.iter().enumerate() {
            let alpha = alpha_from_density(part.raw_sigma[j], deltas[r]);
            let w = alpha * transmittance[r];
            let o = &mut out[r];
            for c in 0..3 {
                o.rgb[c] += w * part.rgb[j][c];
            }
            o.depth += w * t;
            o.acc += w;
            transmittance[r] *= 1.0 - alpha + TRANSMITTANCE_EPS;
        }
        active.retain(|&r| transmittance[r] >= min_transmittance && next[r] < occupied[r].len());
    }
    if options.white_background {
        for o in &mut out {
            o.rgb = over_white(o.rgb, o.acc);
        }
    }
    Ok(out)
}

/// Render an image through `field`: marching through the occupied cells of `occupancy` when a
/// grid is given ([`march_rays`]), else the dense hierarchical path ([`render_image`]).
pub fn render_image_with<F: Field>(
    mut field: F,
    occupancy: Option<&OccupancyGrid>,
    intrinsics: &Intrinsics,
    pose: &Pose,
    options: &RenderOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> std::result::Result<RenderedImage, F::Error> {
    match occupancy {
        Some(grid) => render_image_by(intrinsics, pose, options.chunk, progress, |rays| march_rays(&mut field, grid, rays, options)),
        None => render_image(&mut field, intrinsics, pose, options, progress),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::FieldOutput;
    use crate::sampling::SamplingConfig;

    #[test]
    fn cells_cover_the_cube_in_documented_order() {
        let grid = OccupancyGrid::new(4, 1.0, 0.5);
        // Cell size 0.5: x = −0.9 → i = 0, y = 0.1 → j = 2, z = 0.99 → k = 3.
        assert_eq!(grid.cell([-0.9, 0.1, 0.99]), Some(2 * 4 + 3));
        assert_eq!(grid.cell([0.6, -1.0, -0.2]), Some((3 * 4) * 4 + 1));
        assert_eq!(grid.cell([1.0, 0.0, 0.0]), None, "the upper face is outside");
        assert_eq!(grid.cell([0.0, f32::NAN, 0.0]), None);
        assert!(grid.is_occupied([0.0, 0.0, 0.0]), "a fresh grid is all occupied");
        assert!(!grid.is_occupied([0.0, 0.0, 2.0]), "outside is empty");
    }

    #[test]
    fn updates_keep_a_decaying_maximum() {
        let mut grid = OccupancyGrid::new(2, 1.0, 0.5);
        let mut sigma = vec![0.0; 8];
        sigma[3] = 2.0;
        sigma[5] = -1.0; // raw densities below zero count as zero
        grid.update(&sigma, 0.5);
        assert_eq!(grid.occupied_fraction(), 1.0 / 8.0);
        grid.update(&[0.0; 8], 0.5);
        // Cell 3 is (i, j, k) = (0, 1, 1): x < 0, y > 0, z > 0.
        assert!(grid.is_occupied([-0.5, 0.5, 0.5]));
        assert_eq!(grid.density[3], 1.0);
        grid.update(&[0.0; 8], 0.5);
        assert_eq!(grid.density[3], 0.5);
        assert_eq!(grid.occupied_fraction(), 0.0, "0.5 is not above the threshold");
    }

    #[test]
    fn random_points_fall_in_their_own_cells() {
        let grid = OccupancyGrid::new(5, 1.5, 0.1);
        let points = grid.random_cell_points(&mut Rng::new(1));
        assert_eq!(points.len(), 125);
        for (c, p) in points.iter().enumerate() {
            assert_eq!(grid.cell(*p), Some(c), "{p:?}");
        }
    }

    #[test]
    fn file_round_trip_and_errors() {
        let mut grid = OccupancyGrid::new(3, 1.5, 0.1);
        grid.update(&(0..27).map(|i| i as f32 * 0.01).collect::<Vec<_>>(), 0.9);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("occupancy.bin");
        grid.save(&path).unwrap();
        assert_eq!(OccupancyGrid::load(&path).unwrap(), grid);
        let bytes = grid.to_bytes();
        let err = OccupancyGrid::from_bytes(&bytes[..bytes.len() - 4], &path).unwrap_err().to_string();
        assert!(err.contains("occupancy.bin") && err.contains("truncated"), "{err}");
        let err = OccupancyGrid::from_bytes(b"garbage garbage garbage", &path).unwrap_err().to_string();
        assert!(err.contains("NERFOCC1"), "{err}");
    }

    /// A ball of density 200 and radius 0.5 at the origin, coloured by position.
    struct Ball(usize);

    impl Field for Ball {
        type Error = std::convert::Infallible;
        fn evaluate(&mut self, _: Stage, points: &[[f32; 3]], _: &[[f32; 3]]) -> std::result::Result<FieldOutput, Self::Error> {
            self.0 += points.len();
            let inside = |p: &[f32; 3]| p[0] * p[0] + p[1] * p[1] + p[2] * p[2] < 0.25;
            Ok(FieldOutput {
                rgb: points.iter().map(|p| p.map(|v| 0.5 + v)).collect(),
                raw_sigma: points.iter().map(|p| if inside(p) { 200.0 } else { 0.0 }).collect(),
            })
        }
    }

    #[test]
    fn marching_through_the_grid_matches_the_dense_path_with_far_fewer_evaluations() {
        // Occupied: the 16³ cells over ±1.5 that touch the ball (known empty space elsewhere).
        let mut grid = OccupancyGrid::new(16, 1.5, 0.5);
        let size = 3.0 / 16.0;
        let touches = |c: usize| {
            let (i, j, k) = (c / 256, (c / 16) % 16, c % 16);
            let nearest = [i, j, k].map(|n| {
                let lo = -1.5 + n as f32 * size;
                0.0f32.clamp(lo, lo + size)
            });
            nearest.iter().map(|v| v * v).sum::<f32>() < 0.25
        };
        grid.update(&(0..grid.len()).map(|c| if touches(c) { 1.0 } else { 0.0 }).collect::<Vec<_>>(), 1.0);
        assert!(grid.occupied_fraction() < 0.05);
        let k = Intrinsics { width: 24, height: 24, focal: 30.0 };
        let pose = Pose::spherical(30.0, -30.0, 4.0);
        let options = RenderOptions {
            sampling: SamplingConfig { n_coarse: 64, n_fine: 128, ..Default::default() },
            white_background: true,
            chunk: 100,
            min_transmittance: Some(1e-4),
            march_steps: crate::render::DEFAULT_MARCH_STEPS,
        };
        let mut field = Ball(0);
        let dense = render_image(&mut field, &k, &pose, &RenderOptions { min_transmittance: None, ..options.clone() }, &mut |_, _| {}).unwrap();
        let dense_points = std::mem::take(&mut field.0);
        let skip = render_image_with(&mut field, Some(&grid), &k, &pose, &options, &mut |_, _| {}).unwrap();
        let skip_points = field.0;
        assert!(skip_points * 20 < dense_points, "{skip_points} points marched vs {dense_points} dense");
        assert!(dense.rays.acc.iter().any(|a| *a > 0.99) && dense.rays.acc.iter().any(|a| *a < 0.01), "the ball is in view");
        let db = crate::metrics::psnr(&skip.rays.rgb, &dense.rays.rgb);
        assert!(db > 35.0, "marching vs dense: {db:.1} dB");
    }
}
