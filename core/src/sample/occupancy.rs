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
//!
//! A grid over a contracted world ([`crate::sample::contraction`]) is written as `NERFOCC2`:
//! the same fields, then a `u32` contraction (1: [`Contraction::Linf`]) before the cells
//! (24 header bytes). Its cells are boxes of the contracted cube [−b, b]³ (b = 2): a point is
//! contracted before its cell is found. Readers that know only `NERFOCC1` refuse it.

use crate::error::{Error, Result};
use crate::rng::Rng;
use crate::sample::contraction::Contraction;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The grid's file name in checkpoints and scene bundles.
pub const FILE_NAME: &str = "occupancy.bin";
const MAGIC: &[u8; 8] = b"NERFOCC1";
const HEADER_BYTES: usize = 20;
/// A contracted grid's magic and header size.
const MAGIC_CONTRACTED: &[u8; 8] = b"NERFOCC2";
const HEADER_BYTES_CONTRACTED: usize = 24;

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
    /// After each update, lower the threshold to the grid's mean density when that is smaller
    /// (instant-ngp's rule: a young field that is faint everywhere still has occupied cells).
    #[serde(default)]
    pub threshold_at_most_mean: bool,
    /// Cells over the contracted world (unbounded captures; `bound` is then 2). Absent: none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contraction: Option<Contraction>,
}

impl Default for OccupancyConfig {
    fn default() -> Self {
        OccupancyConfig { resolution: 64, bound: 1.5, threshold: 0.05, decay: 0.95, update_every: 16, warmup_steps: 256, threshold_at_most_mean: false, contraction: None }
    }
}

/// The grid itself.
#[derive(Debug, Clone)]
pub struct OccupancyGrid {
    resolution: usize,
    bound: f32,
    threshold: f32,
    density: Vec<f32>,
    /// Points are contracted before their cell is found.
    contraction: Option<Contraction>,
    /// [`Self::empty_reach`], made on first use and dropped by any change.
    reach: std::sync::OnceLock<Vec<u8>>,
}

/// Grids are equal when their cells and settings are (the cached reach is derived from them).
impl PartialEq for OccupancyGrid {
    fn eq(&self, other: &Self) -> bool {
        (self.resolution, self.bound, self.threshold, self.contraction) == (other.resolution, other.bound, other.threshold, other.contraction) && self.density == other.density
    }
}

/// The farthest [`OccupancyGrid::empty_reach`] records: 8 cells.
pub const MAX_REACH: usize = 8;

impl OccupancyGrid {
    /// A grid with every cell occupied (no information yet).
    pub fn new(resolution: usize, bound: f32, threshold: f32) -> Self {
        OccupancyGrid { resolution, bound, threshold, density: vec![f32::INFINITY; resolution.pow(3)], contraction: None, reach: Default::default() }
    }

    /// A fresh grid as `config` describes.
    pub fn from_config(config: &OccupancyConfig) -> Self {
        Self::new(config.resolution, config.bound, config.threshold).with_contraction(config.contraction)
    }

    /// The same grid over a contracted world (or not).
    pub fn with_contraction(mut self, contraction: Option<Contraction>) -> Self {
        self.contraction = contraction;
        self.reach.take();
        self
    }

    /// The contraction points go through before their cell is found.
    pub fn contraction(&self) -> Option<Contraction> {
        self.contraction
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
        self.set_threshold(threshold);
        self
    }

    /// Change the occupancy threshold in place.
    pub fn set_threshold(&mut self, threshold: f32) {
        self.threshold = threshold;
        self.reach.take();
    }

    /// One occupied cell covering [−bound, bound]³: marching through it evaluates every
    /// interval inside the cube (for fields defined only there, rendered without their grid).
    pub fn whole_cube(bound: f32) -> Self {
        Self::new(1, bound, 0.0)
    }

    /// One occupied cell covering the contracted world: every interval is evaluated.
    pub fn whole_world(contraction: Contraction) -> Self {
        Self::new(1, super::contraction::CONTRACTED_HALF_SIZE, 0.0).with_contraction(Some(contraction))
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
        self.cell_coordinates(p).map(|[i, j, k]| (i * r + j) * r + k)
    }

    /// The (i, j, k) of the cell holding `p` (its index is (i·R + j)·R + k), or `None` outside
    /// the cube (`p` contracted first on a contracted grid).
    pub fn cell_coordinates(&self, p: [f32; 3]) -> Option<[usize; 3]> {
        let p = match self.contraction {
            Some(c) => c.apply(p),
            None => p,
        };
        let r = self.resolution as f32;
        let mut cell = [0; 3];
        for (c, v) in cell.iter_mut().zip(p) {
            let u = (v + self.bound) / (2.0 * self.bound) * r;
            // `!(u >= 0)` also rejects NaN.
            if !(u >= 0.0) || u >= r {
                return None;
            }
            *c = u as usize;
        }
        Some(cell)
    }

    /// Whether `p` lies in an occupied cell.
    pub fn is_occupied(&self, p: [f32; 3]) -> bool {
        self.cell(p).is_some_and(|c| self.is_cell_occupied(c))
    }

    /// Whether cell `cell` (an index as [`Self::cell`] returns) is occupied.
    pub fn is_cell_occupied(&self, cell: usize) -> bool {
        self.density[cell] > self.threshold
    }

    /// Per cell, how far empty space reaches around it: its Chebyshev distance in cells to the
    /// nearest occupied cell, capped at [`MAX_REACH`] + 1 (0: the cell is occupied), so every cell
    /// within `reach − 1` of a cell is empty. Made on first use (growing the occupied cells a
    /// cell at a time, a 3-wide dilation per axis, [`MAX_REACH`] times) and kept until the grid
    /// changes. Marching jumps through these empty cubes. Shape `[R³]`, cell order.
    pub fn empty_reach(&self) -> &[u8] {
        self.reach.get_or_init(|| {
            use rayon::prelude::*;
            let r = self.resolution;
            let n = self.len();
            let mut near: Vec<bool> = (0..n).map(|c| self.is_cell_occupied(c)).collect();
            let mut reach: Vec<u8> = near.iter().map(|&o| if o { 0 } else { MAX_REACH as u8 + 1 }).collect();
            let mut grown = vec![false; n];
            for distance in 1..=MAX_REACH as u8 {
                for (axis, stride) in [r * r, r, 1].into_iter().enumerate() {
                    // One (i, ·, ·) slab of cells per task: coordinates by counting, not dividing.
                    grown.par_chunks_mut((r * r).max(1)).enumerate().for_each(|(i, slab)| {
                        for (j, row) in slab.chunks_mut(r).enumerate() {
                            for (k, g) in row.iter_mut().enumerate() {
                                let c = (i * r + j) * r + k;
                                let at = [i, j, k][axis];
                                *g = near[c] || (at > 0 && near[c - stride]) || (at + 1 < r && near[c + stride]);
                            }
                        }
                    });
                    std::mem::swap(&mut near, &mut grown);
                }
                reach.iter_mut().zip(&near).filter(|(d, n)| **n && **d > distance).for_each(|(d, _)| *d = distance);
            }
            reach
        })
    }

    /// Indices of the points that lie in occupied cells, in order.
    pub fn occupied_indices(&self, points: &[[f32; 3]]) -> Vec<usize> {
        (0..points.len()).filter(|&i| self.is_occupied(points[i])).collect()
    }

    /// Fraction of cells that are occupied.
    pub fn occupied_fraction(&self) -> f32 {
        self.density.iter().filter(|d| **d > self.threshold).count() as f32 / self.len().max(1) as f32
    }

    /// Mean of the cells' density estimates (cells not measured yet count as 0). instant-ngp
    /// caps the occupancy threshold at this, so a young field that is faint everywhere still
    /// has occupied cells.
    pub fn mean_density(&self) -> f32 {
        let sum: f64 = self.density.iter().filter(|d| d.is_finite()).map(|&d| d as f64).sum();
        (sum / self.len().max(1) as f64) as f32
    }

    /// One uniformly random point inside every cell, in cell order (world points: on a
    /// contracted grid, the point of the world drawn there).
    pub fn random_cell_points(&self, rng: &mut Rng) -> Vec<[f32; 3]> {
        let r = self.resolution;
        let size = 2.0 * self.bound / r as f32;
        (0..self.len())
            .map(|c| {
                let (i, j, k) = (c / (r * r), (c / r) % r, c % r);
                let p = [i, j, k].map(|n| -self.bound + (n as f32 + rng.uniform()) * size);
                match self.contraction {
                    Some(c) => c.invert(p),
                    None => p,
                }
            })
            .collect()
    }

    /// Fold in densities (σ after ReLU) measured at one point per cell (cell order, as from
    /// [`random_cell_points`](Self::random_cell_points)).
    pub fn update(&mut self, sigma: &[f32], decay: f32) {
        assert_eq!(sigma.len(), self.len(), "one density per cell");
        self.reach.take();
        for (d, &s) in self.density.iter_mut().zip(sigma) {
            let s = s.max(0.0);
            *d = if d.is_finite() { (*d * decay).max(s) } else { s };
        }
    }

    /// Serialise in the documented format.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(HEADER_BYTES_CONTRACTED + 4 * self.len());
        out.extend_from_slice(if self.contraction.is_some() { MAGIC_CONTRACTED } else { MAGIC });
        out.extend_from_slice(&(self.resolution as u32).to_le_bytes());
        out.extend_from_slice(&self.bound.to_le_bytes());
        out.extend_from_slice(&self.threshold.to_le_bytes());
        if let Some(Contraction::Linf) = self.contraction {
            out.extend_from_slice(&1u32.to_le_bytes());
        }
        for d in &self.density {
            out.extend_from_slice(&d.to_le_bytes());
        }
        out
    }

    /// Parse the documented format; `path` only names the source in errors.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self> {
        let Header { resolution, bound, threshold, contraction, bytes: header } = Self::parse_header(bytes, path)?;
        let want = Self::file_bytes(resolution, header);
        if bytes.len() as u64 != want {
            return Err(Error::invalid(path, format!("{} bytes, expected {want} for a {resolution}³ grid (truncated?)", bytes.len())));
        }
        let density = bytes[header..].chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        Ok(OccupancyGrid { resolution, bound, threshold, density, contraction, reach: Default::default() })
    }

    /// The header from the first bytes (at most [`HEADER_BYTES_CONTRACTED`]), checked (the
    /// resolution against [`MAX_GRID_RESOLUTION`](crate::io::limits::MAX_GRID_RESOLUTION)) before
    /// anything the size of the grid is allocated.
    fn parse_header(bytes: &[u8], path: &Path) -> Result<Header> {
        let bad = |problem: String| Error::invalid(path, problem);
        let contracted = bytes.len() >= HEADER_BYTES_CONTRACTED && &bytes[..8] == MAGIC_CONTRACTED;
        if !contracted && (bytes.len() < HEADER_BYTES || &bytes[..8] != MAGIC) {
            return Err(bad("not an occupancy grid (missing NERFOCC1 or NERFOCC2 header)".into()));
        }
        let word = |at: usize| [bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]];
        let resolution = u32::from_le_bytes(word(8)) as usize;
        let bound = f32::from_le_bytes(word(12));
        let threshold = f32::from_le_bytes(word(16));
        crate::io::limits::check_grid_resolution(resolution, crate::io::limits::Origin::Field(path, "header resolution"))?;
        if !(bound > 0.0 && bound.is_finite()) || !threshold.is_finite() {
            return Err(bad(format!("bad header: resolution {resolution}, bound {bound}, threshold {threshold}")));
        }
        if !contracted {
            return Ok(Header { resolution, bound, threshold, contraction: None, bytes: HEADER_BYTES });
        }
        let contraction = match u32::from_le_bytes(word(20)) {
            1 => Contraction::Linf,
            other => return Err(bad(format!("unknown contraction {other} in the NERFOCC2 header (this version knows 1: L-infinity)"))),
        };
        if bound != super::contraction::CONTRACTED_HALF_SIZE {
            return Err(bad(format!("a contracted grid covers [-2, 2]^3, the header says bound {bound}")));
        }
        Ok(Header { resolution, bound, threshold, contraction: Some(contraction), bytes: HEADER_BYTES_CONTRACTED })
    }

    /// The size of a grid file with `resolution` cells per axis after a `header`-byte header.
    fn file_bytes(resolution: usize, header: usize) -> u64 {
        header as u64 + 4 * (resolution as u64).pow(3)
    }

    /// Read a grid file: the header first, then (once its resolution is within the limit and
    /// the file's size matches it) the cells.
    pub fn load(path: &Path) -> Result<Self> {
        use std::io::Read;
        let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        let meta = file.metadata().map_err(|e| Error::io(path, e))?;
        if !meta.is_file() {
            return Err(Error::invalid(path, "not a regular file"));
        }
        let mut header = Vec::with_capacity(HEADER_BYTES_CONTRACTED);
        (&mut file).take(HEADER_BYTES_CONTRACTED as u64).read_to_end(&mut header).map_err(|e| Error::io(path, e))?;
        let Header { resolution, bytes: header_bytes, .. } = Self::parse_header(&header, path)?;
        let want = Self::file_bytes(resolution, header_bytes);
        if meta.len() != want {
            return Err(Error::invalid(path, format!("{} bytes, expected {want} for a {resolution}³ grid (truncated?)", meta.len())));
        }
        // What was read may run past a NERFOCC1 header into the cells: read on after it.
        let mut bytes = header;
        let have = bytes.len() as u64;
        bytes.reserve_exact((want - have.min(want)) as usize);
        // One byte more than expected, so a file that grew since is reported, not read on.
        file.take(want - have.min(want) + 1).read_to_end(&mut bytes).map_err(|e| Error::io(path, e))?;
        Self::from_bytes(&bytes, path)
    }

    /// Write a grid file atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        crate::io::atomic::write_atomic(path, &self.to_bytes())
    }
}

/// What a grid file's header says.
struct Header {
    resolution: usize,
    bound: f32,
    threshold: f32,
    contraction: Option<Contraction>,
    /// Where the cells start.
    bytes: usize,
}

/// The grid a field is marched through: its occupancy grid, or, for a field defined inside the
/// cube ±`bounded` only, one occupied cell over that cube (every interval inside it is
/// evaluated; over the whole contracted world where the field is `contraction`'s). `None`:
/// sample densely.
pub fn marching_grid(occupancy: Option<OccupancyGrid>, bounded: Option<f32>, contraction: Option<Contraction>) -> Option<OccupancyGrid> {
    occupancy.or_else(|| {
        bounded.map(|b| match contraction {
            Some(c) => OccupancyGrid::whole_world(c),
            None => OccupancyGrid::whole_cube(b),
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn empty_reach_is_the_chebyshev_distance_to_the_nearest_occupied_cell_capped() {
        // 24³, one occupied cell at (2, 3, 4).
        let r = 24;
        let at = |i: usize, j: usize, k: usize| (i * r + j) * r + k;
        let mut density = vec![0.0; r * r * r];
        density[at(2, 3, 4)] = 1.0;
        let mut grid = OccupancyGrid::new(r, 1.0, 0.5);
        grid.update(&density, 1.0);
        let reach = grid.empty_reach();
        assert_eq!((reach[at(2, 3, 4)], reach[at(3, 3, 4)], reach[at(1, 2, 5)]), (0, 1, 1));
        // max(|4 − 2|, |5 − 3|, |4 − 4|) = 2; max(5, 4, 3) = 5; 20 cells away: capped at 9.
        assert_eq!((reach[at(4, 5, 4)], reach[at(7, 7, 7)], reach[at(22, 3, 4)]), (2, 5, MAX_REACH as u8 + 1));
        assert_eq!(reach.iter().filter(|&&d| d == 1).count(), 26);
        // Kept until the grid changes: a second occupied cell at (2, 3, 8).
        density[at(2, 3, 8)] = 1.0;
        grid.update(&density, 1.0);
        assert_eq!((grid.empty_reach()[at(2, 3, 6)], grid.empty_reach()[at(2, 3, 7)]), (2, 1));
        grid.set_threshold(2.0);
        assert!(grid.empty_reach().iter().all(|&d| d == MAX_REACH as u8 + 1), "nothing is occupied above 2");
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
    fn a_contracted_grid_finds_cells_of_contracted_points() {
        // 4 cells per axis over [−2, 2]: cell side 1. (3, 0, 0) → (1.6667, 0, 0): i = 3;
        // (0.5, −1.5, 0) → ‖x‖∞ 1.5, f = (2 − 2/3)·2/3 = 8/9 → (0.444, −1.333, 0): (2, 0, 2).
        let grid = OccupancyGrid::new(4, 2.0, 0.5).with_contraction(Some(Contraction::Linf));
        assert_eq!(grid.cell_coordinates([3.0, 0.0, 0.0]), Some([3, 2, 2]));
        assert_eq!(grid.cell_coordinates([0.5, -1.5, 0.0]), Some([2, 0, 2]));
        assert_eq!(grid.cell_coordinates([-1e20, 0.0, 1e19]), Some([0, 2, 2]), "everything lies inside");
        assert_eq!(grid.cell_coordinates([0.5, 0.5, 0.5]), Some([2, 2, 2]));
        let points = grid.random_cell_points(&mut Rng::new(2));
        for (c, p) in points.iter().enumerate() {
            assert_eq!(grid.cell(*p), Some(c), "{p:?}");
        }
        assert!(points.iter().any(|p| p.iter().any(|v| v.abs() > 2.0)), "outer cells reach past the cube");
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
        // A contracted grid: its own header, round trip, and its cells found after contraction.
        let contracted = OccupancyGrid::new(4, 2.0, 0.1).with_contraction(Some(Contraction::Linf));
        let cbytes = contracted.to_bytes();
        assert_eq!((&cbytes[..8], cbytes.len()), (&b"NERFOCC2"[..], 24 + 4 * 64));
        std::fs::write(&path, &cbytes).unwrap();
        assert_eq!(OccupancyGrid::load(&path).unwrap(), contracted);
        let mut unknown = cbytes.clone();
        unknown[20] = 7;
        let err = OccupancyGrid::from_bytes(&unknown, &path).unwrap_err().to_string();
        assert!(err.contains("unknown contraction 7"), "{err}");
        std::fs::write(&path, &bytes).unwrap();
        // A header claiming 2³¹ cells per axis is refused from its 20 bytes, before any
        // allocation; a file longer than its header says is refused before it is read.
        let mut huge = bytes[..HEADER_BYTES].to_vec();
        huge[8..12].copy_from_slice(&(1u32 << 31).to_le_bytes());
        std::fs::write(&path, &huge).unwrap();
        let err = OccupancyGrid::load(&path).unwrap_err().to_string();
        assert!(err.contains("occupancy.bin: header resolution: 2147483648 cells per axis is more than the limit of 512"), "{err}");
        let mut long = bytes.clone();
        long.extend_from_slice(&[0; 8]);
        std::fs::write(&path, &long).unwrap();
        let err = OccupancyGrid::load(&path).unwrap_err().to_string();
        assert!(err.contains(&format!("{} bytes, expected {}", long.len(), bytes.len())), "{err}");
    }
}
