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

use crate::camera::{PinholeCamera, Pose};
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
    /// Leave empty for good the cells that fewer training cameras than this see ([`UNSEEN`],
    /// [`OccupancyGrid::mark_unseen`]; world rays only, not NDC's). 0: none.
    #[serde(default)]
    pub min_views: usize,
}

impl Default for OccupancyConfig {
    fn default() -> Self {
        OccupancyConfig { resolution: 64, bound: 1.5, threshold: 0.05, decay: 0.95, update_every: 16, warmup_steps: 256, threshold_at_most_mean: false, contraction: None, min_views: 0 }
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
    /// [`Self::corner_reach`] per octant, each made on first use and dropped by any change.
    corners: [std::sync::OnceLock<Vec<u8>>; 8],
}

/// Grids are equal when their cells and settings are (the cached tables are derived from them).
impl PartialEq for OccupancyGrid {
    fn eq(&self, other: &Self) -> bool {
        (self.resolution, self.bound, self.threshold, self.contraction) == (other.resolution, other.bound, other.threshold, other.contraction) && self.density == other.density
    }
}

/// The density estimate of a cell that no training camera sees (instant-ngp's untrained cells,
/// nerfacc's invisible ones): below every threshold, and kept by [`OccupancyGrid::update`].
/// Nothing trains the field there, so whatever density it has there is a floater in views
/// from elsewhere.
pub const UNSEEN: f32 = -1.0;

/// The sides (in cells) of the cubes [`OccupancyGrid::corner_reach`] records, as the Python
/// package's `CORNER_SIDES`: each side at most doubles the one before, so a table is three
/// shifted ANDs of the grid per side.
pub const CORNER_SIDES: [usize; 10] = [1, 2, 3, 4, 6, 8, 12, 16, 24, 32];
/// The bit of a [`OccupancyGrid::corner_reach`] value that marks an occupied cell (the rest is
/// the side of the cube).
pub const OCCUPIED_CUBE: u8 = 0x80;

impl OccupancyGrid {
    /// A grid with every cell occupied (no information yet).
    pub fn new(resolution: usize, bound: f32, threshold: f32) -> Self {
        OccupancyGrid { resolution, bound, threshold, density: vec![f32::INFINITY; resolution.pow(3)], contraction: None, corners: Default::default() }
    }

    /// A grid over ±`bound` whose cells are occupied where `occupied` (`[R³]`, cell order) is
    /// true: the cells a bundle's renderer reads, without their densities (threshold 0,
    /// occupied cells density 1, the rest 0).
    ///
    /// # Panics
    /// If `occupied` does not hold one flag per cell.
    pub fn from_occupied(resolution: usize, bound: f32, occupied: &[bool]) -> Self {
        assert_eq!(occupied.len(), resolution.pow(3), "one flag per cell");
        let density = occupied.iter().map(|&o| if o { 1.0 } else { 0.0 }).collect();
        OccupancyGrid { resolution, bound, threshold: 0.0, density, contraction: None, corners: Default::default() }
    }

    /// A fresh grid as `config` describes.
    pub fn from_config(config: &OccupancyConfig) -> Self {
        Self::new(config.resolution, config.bound, config.threshold).with_contraction(config.contraction)
    }

    /// The same grid over a contracted world (or not).
    pub fn with_contraction(mut self, contraction: Option<Contraction>) -> Self {
        self.contraction = contraction;
        self.corners = Default::default();
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
        self.corners = Default::default();
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

    /// The (i, j, k) of cell index `cell` (the inverse of [`Self::cell`]'s numbering).
    fn cell_indices(&self, cell: usize) -> [usize; 3] {
        let r = self.resolution;
        [cell / (r * r), (cell / r) % r, cell % r]
    }

    /// Whether `p` lies in an occupied cell.
    pub fn is_occupied(&self, p: [f32; 3]) -> bool {
        self.cell(p).is_some_and(|c| self.is_cell_occupied(c))
    }

    /// Whether cell `cell` (an index as [`Self::cell`] returns) is occupied.
    pub fn is_cell_occupied(&self, cell: usize) -> bool {
        self.density[cell] > self.threshold
    }

    /// For rays heading into `octant` (bit 2: x grows, bit 1: y, bit 0: z), per cell: the largest
    /// side s of [`CORNER_SIDES`] such that the cube of s cells a side with this cell at its
    /// corner, reaching along the octant's directions, is all in the cell's state: all empty
    /// (cells past the grid count as empty) or all occupied (and inside the grid). An empty
    /// cell's value is s, an occupied cell's s | [`OCCUPIED_CUBE`]. A ray in the cell heading into
    /// the octant crosses that cube from the cell on, so marching jumps through it. Made on first
    /// use per octant and kept until the grid changes. Shape `[R³]`, cell order.
    ///
    /// Example: one occupied cell, (2, 3, 4). For octant +x+y+z, cell (1, 1, 1)'s cube of side 3
    /// (cells 1..=3 per axis) is empty, that of side 4 holds (2, 3, 4): 3; for −x−y−z every cube
    /// from (1, 1, 1) is empty: 32; (2, 3, 4) itself: 1 | [`OCCUPIED_CUBE`].
    pub fn corner_reach(&self, octant: usize) -> &[u8] {
        self.corners[octant & 7].get_or_init(|| {
            let state: Vec<u8> = (0..self.len()).map(|c| if self.is_cell_occupied(c) { 0b10 } else { 0b01 }).collect();
            let mut sides = corner_sides(self.resolution, state, octant);
            sides.iter_mut().zip(0..).filter(|(_, c)| self.is_cell_occupied(*c)).for_each(|(s, _)| *s |= OCCUPIED_CUBE);
            sides
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

    /// Mean of the cells' density estimates (cells not measured yet count as 0, [`UNSEEN`]
    /// cells not at all). instant-ngp caps the occupancy threshold at this, so a young field
    /// that is faint everywhere still has occupied cells.
    pub fn mean_density(&self) -> f32 {
        let seen = self.density.iter().filter(|&&d| d != UNSEEN);
        let (sum, count) = seen.fold((0.0f64, 0usize), |(sum, count), &d| (if d.is_finite() { sum + d as f64 } else { sum }, count + 1));
        (sum / count.max(1) as f64) as f32
    }

    /// Mark [`UNSEEN`] every cell that fewer than `min_views` cameras of `views` see (a camera
    /// sees a cell when part of the cell's bounding sphere projects into its image, or the
    /// sphere holds it). 1 is instant-ngp's rule: cells no camera sees; 2 also leaves empty
    /// what only one camera sees, whose depth nothing pins down. Returns how many cells that
    /// marked. For grids whose rays are world rays (not NDC's).
    pub fn mark_unseen(&mut self, views: &[(PinholeCamera, Pose)], min_views: usize) -> usize {
        let r = self.resolution;
        let size = 2.0 * self.bound / r as f32;
        let cameras: Vec<_> = views.iter().map(|(camera, pose)| (camera, pose.origin(), pose.rotation().transpose())).collect();
        let mut marked = 0;
        for c in 0..self.len() {
            let lo = self.cell_indices(c).map(|n| -self.bound + n as f32 * size);
            let (centre, radius) = self.cell_sphere(lo, size);
            let seeing = cameras.iter().filter(|&&(camera, origin, to_camera)| sphere_in_view(camera, to_camera * (glam::Vec3::from(centre) - origin), radius));
            if seeing.take(min_views).count() < min_views {
                self.density[c] = UNSEEN;
                marked += 1;
            }
        }
        self.corners = Default::default();
        marked
    }

    /// The world centre and bounding radius of the cell whose (grid-space) corner is `lo`.
    fn cell_sphere(&self, lo: [f32; 3], size: f32) -> ([f32; 3], f32) {
        let centre = lo.map(|v| v + 0.5 * size);
        match self.contraction {
            None => (centre, 0.5 * size * 3f32.sqrt()),
            Some(c) => {
                // The cell's world box is bounded by its corners' images (the inverse is
                // monotonic per axis within a cell); corners on the boundary lie at infinity.
                let world = c.invert(centre);
                let radius = (0..8)
                    .map(|k| {
                        let corner = c.invert([0, 1, 2].map(|a| lo[a] + if k >> a & 1 == 1 { size } else { 0.0 }));
                        (0..3).map(|a| (corner[a] - world[a]).powi(2)).sum::<f32>().sqrt()
                    })
                    .fold(0.0f32, |m, d| if d.is_nan() { f32::INFINITY } else { m.max(d) });
                (world, radius)
            }
        }
    }

    /// One uniformly random point inside every cell, in cell order (world points: on a
    /// contracted grid, the point of the world drawn there).
    pub fn random_cell_points(&self, rng: &mut Rng) -> Vec<[f32; 3]> {
        let r = self.resolution;
        let size = 2.0 * self.bound / r as f32;
        (0..self.len())
            .map(|c| {
                let p = self.cell_indices(c).map(|n| -self.bound + (n as f32 + rng.uniform()) * size);
                match self.contraction {
                    Some(c) => c.invert(p),
                    None => p,
                }
            })
            .collect()
    }

    /// Fold in densities (σ after ReLU) measured at one point per cell (cell order, as from
    /// [`random_cell_points`](Self::random_cell_points)). [`UNSEEN`] cells stay so.
    pub fn update(&mut self, sigma: &[f32], decay: f32) {
        assert_eq!(sigma.len(), self.len(), "one density per cell");
        self.corners = Default::default();
        for (d, &s) in self.density.iter_mut().zip(sigma).filter(|(d, _)| **d != UNSEEN) {
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
        Ok(OccupancyGrid { resolution, bound, threshold, density, contraction, corners: Default::default() })
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

/// Whether a sphere of `radius` around `centre` (camera space, OpenGL: the camera looks down
/// −z) reaches into `camera`'s image: generous, never the other way round (a sphere that holds
/// the camera or crosses its plane counts as seen; the image is grown by the sphere's projected
/// radius, half again for the lens's distortion).
fn sphere_in_view(camera: &PinholeCamera, centre: glam::Vec3, radius: f32) -> bool {
    let depth = -centre.z;
    if !radius.is_finite() || centre.length() <= radius || (depth <= radius && depth > -radius) {
        return true;
    }
    if depth <= 0.0 {
        return false;
    }
    let Some((i, j)) = camera.project(centre) else { return true };
    let margin = 1.5 * radius * camera.fx.max(camera.fy) / (depth * depth - radius * radius).sqrt();
    i >= -margin && i <= camera.width as f32 + margin && j >= -margin && j <= camera.height as f32 + margin
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

/// For `cube` ([R³]: per cell, bit 0 set when empty, bit 1 when occupied) and rays heading into
/// `octant`: per cell, the largest side of [`CORNER_SIDES`] whose cube from the cell (reaching
/// along the octant) is all in the cell's state, cells past the grid counting as empty. The cube
/// of side `side + shift` at c is the 8 cubes of side `side` at c + shift·{0, 1}³ (shift ≤ side):
/// an AND with the cubes `shift` cells on, one axis at a time, a line of cells at a time (both
/// states at once, one bit each; a cell's own bit stays set while its cube is all its state).
fn corner_sides(r: usize, mut cube: Vec<u8>, octant: usize) -> Vec<u8> {
    const PAST: u8 = 0b01;
    let mut sides = vec![1u8; cube.len()];
    let mut row = vec![0u8; r];
    let mut side = 1;
    for &target in &CORNER_SIDES[1..] {
        let shift = target - side;
        for axis in 0..3 {
            let up = octant >> (2 - axis) & 1 == 1;
            // Along x the lines are the grid's slabs, along y a slab's rows, along z single cells.
            let line = [r * r, r, 1][axis];
            cube.chunks_mut(line * r).for_each(|block| and_shifted(block, line, shift, up, PAST, &mut row));
        }
        side = target;
        sides.iter_mut().zip(&cube).for_each(|(s, &c)| *s = if c != 0 { side as u8 } else { *s });
    }
    sides
}

/// `block`'s lines of `len` cells, each ANDed in place with the line `shift` on (up) or back
/// (down), a line past the block counting as `past`. Lines one at a time in the order that reads
/// a line before it is written; single cells (`len` 1) from a copy of the block in `row`.
fn and_shifted(block: &mut [u8], len: usize, shift: usize, up: bool, past: u8, row: &mut [u8]) {
    let lines = block.len() / len;
    if len == 1 {
        let reach = lines.saturating_sub(shift);
        row[..lines].copy_from_slice(block);
        let (keep, edge) = if up { (&mut block[..reach], &row[shift.min(lines)..lines]) } else { (&mut block[lines - reach..], &row[..reach]) };
        keep.iter_mut().zip(edge).for_each(|(x, &y)| *x &= y);
        let past_end = if up { &mut block[reach..] } else { &mut block[..lines - reach] };
        past_end.iter_mut().for_each(|x| *x &= past);
        return;
    }
    for step in 0..lines {
        let m = if up { step } else { lines - 1 - step };
        let partner = if up { m + shift } else { m.wrapping_sub(shift) };
        if partner < lines {
            // Two disjoint lines: split where the later one starts.
            let (first, second) = block.split_at_mut(m.max(partner) * len);
            let (line, other) = if up { (&mut first[m * len..][..len], &second[..len]) } else { (&mut second[..len], &first[partner * len..][..len]) };
            line.iter_mut().zip(other).for_each(|(x, &y)| *x &= y);
        } else {
            block[m * len..][..len].iter_mut().for_each(|x| *x &= past);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::OpenCvDistortion;

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
    fn a_grid_from_flags_is_occupied_where_they_are_true() {
        let mut flags = vec![false; 8];
        flags[4 + 2 + 1] = true; // cell (1, 1, 1): x, y, z > 0
        let grid = OccupancyGrid::from_occupied(2, 1.0, &flags);
        assert!(grid.is_occupied([0.5, 0.5, 0.5]));
        assert!(!grid.is_occupied([0.5, 0.5, -0.5]));
        assert!(!grid.is_occupied([-0.5, 0.5, 0.5]));
        assert_eq!(grid.occupied_fraction(), 1.0 / 8.0);
        assert_eq!(grid.corner_reach(7)[0], 1, "cell (0, 0, 0)'s cube of 2 holds (1, 1, 1)");
        assert_eq!(grid.corner_reach(0)[0], 32, "heading −x−y−z, past the grid is empty");
    }

    #[test]
    fn corner_reach_is_the_largest_cube_of_the_cells_state_along_the_octant() {
        // 24³, one occupied cell at (2, 3, 4).
        let r = 24;
        let at = |i: usize, j: usize, k: usize| (i * r + j) * r + k;
        let mut density = vec![0.0; r * r * r];
        density[at(2, 3, 4)] = 1.0;
        let mut grid = OccupancyGrid::new(r, 1.0, 0.5);
        grid.update(&density, 1.0);
        let (up, down) = (grid.corner_reach(0b111).to_vec(), grid.corner_reach(0b000).to_vec());
        // +x+y+z from (1, 1, 1): side 3 spans cells 1..=3 (z misses 4), side 4 holds (2, 3, 4).
        assert_eq!(up[at(1, 1, 1)], 3);
        // −x−y−z: nothing occupied below, past the grid counts as empty.
        assert_eq!(down[at(1, 1, 1)], 32);
        assert_eq!((up[at(2, 3, 4)], down[at(2, 3, 4)]), (OCCUPIED_CUBE | 1, OCCUPIED_CUBE | 1));
        // (2, 3, 3) heading +z: side 2 would hold (2, 3, 4); heading −z, (2, 3, 4) is never reached.
        assert_eq!((grid.corner_reach(0b001)[at(2, 3, 3)], grid.corner_reach(0b110)[at(2, 3, 3)]), (1, 32));
        // +x−y−z from (0, 3, 4): the cube of side 3 reaches x = 2 with y = 3 and z = 4 in it.
        assert_eq!(grid.corner_reach(0b100)[at(0, 3, 4)], 2);
        // Every value against the definition, computed cube by cube, on a few cells and octants.
        let occupied = |i: i64, j: i64, k: i64| (0..r as i64).contains(&i) && (0..r as i64).contains(&j) && (0..r as i64).contains(&k) && density[at(i as usize, j as usize, k as usize)] > 0.5;
        for octant in 0..8 {
            let sign = [(octant >> 2) & 1, (octant >> 1) & 1, octant & 1].map(|b| if b == 1 { 1i64 } else { -1 });
            let table = grid.corner_reach(octant);
            for c in [(0, 0, 0), (1, 2, 3), (2, 3, 4), (5, 5, 5), (23, 0, 11), (3, 3, 3), (2, 4, 4)] {
                let state = occupied(c.0, c.1, c.2);
                let fits = |s: i64| (0..s).all(|a| (0..s).all(|b| (0..s).all(|e| occupied(c.0 + a * sign[0], c.1 + b * sign[1], c.2 + e * sign[2]) == state)));
                let side = CORNER_SIDES.iter().rev().find(|&&s| fits(s as i64)).copied().unwrap_or(0) as u8;
                assert_eq!(table[at(c.0 as usize, c.1 as usize, c.2 as usize)], side | if state { OCCUPIED_CUBE } else { 0 }, "octant {octant}, cell {c:?}");
            }
        }
        // Every cell of a 13³ grid, every octant: a tenth of the cells occupied, a solid 5³ block
        // inside and a 4³ one in a corner of the grid (an occupied cube stops at the grid's faces).
        let r13 = 13usize;
        let mut rng = crate::rng::Rng::new(13);
        let mut cells: Vec<f32> = (0..r13.pow(3)).map(|_| if rng.uniform() < 0.1 { 1.0 } else { 0.0 }).collect();
        for (i, j, k) in (0..r13).flat_map(|i| (0..r13).flat_map(move |j| (0..r13).map(move |k| (i, j, k)))) {
            if ((2..7).contains(&i) && (3..8).contains(&j) && (4..9).contains(&k)) || (i >= 9 && j < 4 && k >= 9) {
                cells[(i * r13 + j) * r13 + k] = 1.0;
            }
        }
        let mut other = OccupancyGrid::new(r13, 1.0, 0.5);
        other.update(&cells, 1.0);
        let inside = |v: i64| (0..r13 as i64).contains(&v);
        let full = |i: i64, j: i64, k: i64| inside(i) && inside(j) && inside(k) && cells[((i as usize) * r13 + j as usize) * r13 + k as usize] > 0.5;
        for octant in 0..8 {
            let sign = [(octant >> 2) & 1, (octant >> 1) & 1, octant & 1].map(|b| if b == 1 { 1i64 } else { -1 });
            let table = other.corner_reach(octant);
            for c in 0..r13.pow(3) {
                let (i, j, k) = ((c / (r13 * r13)) as i64, (c / r13 % r13) as i64, (c % r13) as i64);
                let state = full(i, j, k);
                let fits = |s: i64| (0..s).all(|a| (0..s).all(|b| (0..s).all(|e| full(i + a * sign[0], j + b * sign[1], k + e * sign[2]) == state)));
                let side = CORNER_SIDES.iter().take_while(|&&s| fits(s as i64)).last().copied().unwrap_or(0) as u8;
                assert_eq!(table[c], side | if state { OCCUPIED_CUBE } else { 0 }, "13³, octant {octant}, cell {i} {j} {k}");
            }
        }
        // Kept until the grid changes: a second occupied cell at (2, 3, 8).
        density[at(2, 3, 8)] = 1.0;
        grid.update(&density, 1.0);
        assert_eq!(grid.corner_reach(0b001)[at(2, 3, 6)], 2);
        grid.set_threshold(2.0);
        assert!(grid.corner_reach(0b001).iter().all(|&s| s == 32), "nothing is occupied above 2");
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

    fn pinhole(width: u32, height: u32, focal: f32) -> PinholeCamera {
        PinholeCamera::from_intrinsics(&crate::camera::Intrinsics { width, height, focal })
    }

    #[test]
    fn a_camera_inside_the_grid_leaves_unseen_only_the_cells_behind_it() {
        // Cells of side 1 over [−2, 2]³ (bounding spheres of radius √3/2 ≈ 0.87); the camera at
        // the origin looks down −z, 2·atan(50/10) ≈ 157° wide. Cells centred at z = 1.5 end
        // 0.63 behind its plane: unseen. Those at z = 0.5 cross its plane and those at −0.5
        // hold it within their sphere: seen. Those at −1.5 project at most (±1.5/1.5)·10 px
        // from the image centre: seen.
        let identity = Pose::from_rows([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]);
        let mut grid = OccupancyGrid::new(4, 2.0, 0.5);
        assert_eq!(grid.mark_unseen(&[(pinhole(100, 100, 10.0), identity)], 1), 16);
        for c in 0..grid.len() {
            assert_eq!(grid.density[c] == UNSEEN, c % 4 == 3, "cell {c}: k = {}", c % 4);
            assert_eq!(grid.is_cell_occupied(c), c % 4 != 3, "cell {c}");
        }
        // Updates keep them empty; the mean counts only the others.
        grid.update(&[8.0; 64], 0.5);
        assert_eq!(grid.occupied_fraction(), 0.75);
        assert_eq!(grid.mean_density(), 8.0);
        // Without cameras nothing is seen.
        assert_eq!(OccupancyGrid::new(2, 1.0, 0.5).mark_unseen(&[], 1), 8);
        // Nor with one camera, when two are asked for; nothing is marked when none are.
        assert_eq!(OccupancyGrid::new(4, 2.0, 0.5).mark_unseen(&[(pinhole(100, 100, 10.0), identity)], 2), 64);
        assert_eq!(OccupancyGrid::new(4, 2.0, 0.5).mark_unseen(&[], 0), 0);
    }

    #[test]
    fn no_point_that_enough_cameras_see_lies_in_an_unseen_cell() {
        // A camera sees a point when it projects into the image and the ray of that pixel
        // points at it (beyond the distortion's fold, projections land in the image without a
        // ray there).
        let mut camera = pinhole(64, 48, 80.0);
        camera.distortion = Some(OpenCvDistortion { k1: 0.06, k2: -0.08, p1: -1e-3, p2: 2e-4 });
        let views: Vec<(PinholeCamera, Pose)> = (0..3).map(|k| (camera, Pose::spherical(120.0 * k as f32 + 10.0, -20.0, 1.0 + k as f32))).collect();
        let seeing = |p: [f32; 3]| {
            let sees = |(camera, pose): &&(PinholeCamera, Pose)| {
                let v = pose.rotation().transpose() * (glam::Vec3::from(p) - pose.origin());
                camera.project(v).is_some_and(|(i, j)| {
                    let inside = i >= 0.0 && i <= camera.width as f32 && j >= 0.0 && j <= camera.height as f32;
                    inside && camera.camera_direction(i, j).normalize().dot(v.normalize()) > 1.0 - 1e-5
                })
            };
            views.iter().filter(sees).count()
        };
        let mut rng = Rng::new(5);
        for contraction in [None, Some(Contraction::Linf)] {
            let bound = if contraction.is_some() { 2.0 } else { 1.5 };
            let mut previous = 0;
            for min_views in [1, 2] {
                let mut grid = OccupancyGrid::new(16, bound, 0.5).with_contraction(contraction);
                let unseen = grid.mark_unseen(&views, min_views);
                assert!(unseen > previous && unseen < grid.len(), "{contraction:?}, {min_views}: {unseen} unseen cells");
                previous = unseen;
                for _ in 0..20 {
                    for (c, p) in grid.random_cell_points(&mut rng).into_iter().enumerate() {
                        if grid.density[c] == UNSEEN {
                            let n = seeing(p);
                            assert!(n < min_views, "{contraction:?}: cell {c} marked unseen by {min_views}, yet {n} cameras see {p:?} in it");
                        }
                    }
                }
            }
        }
    }
}
