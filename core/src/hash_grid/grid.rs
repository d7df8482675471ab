//! The hash-grid table and its forward and backward passes (plain Rust, rayon).
//!
//! # Conventions (tiny-cuda-nn's `kernel_grid` / `kernel_grid_backward`)
//! A coordinate x ∈ [0, 1] lands at `pos = x · scale + 0.5` on level l (scale `N_min·bˡ − 1`),
//! its cell corner is `⌊pos⌋` (as u32) and its weight along that axis `pos − ⌊pos⌋`. The 8
//! corners are visited in the order `idx = 0..8`, bit d of `idx` choosing `+1` along axis d, with
//! weight `Π_d (bit ? frac_d : 1 − frac_d)` multiplied from axis 0 to 2. Entry indices are
//! [`LevelLayout::index`]. Features are level-major: output column `l·F + f`.
//!
//! tiny-cuda-nn computes `pos` with one fused multiply-add; we round the product and the sum
//! separately, exactly as the exported graph's `Mul` and `Add` do, so that both pick the same
//! cell.
//!
//! Points outside the unit cube are clamped to it first (each coordinate to [0, 1]; NaN reads
//! as 0): a point outside reads the value on the cube's boundary. tiny-cuda-nn does not clamp
//! (instant-ngp only feeds it points inside its box, and a negative coordinate would wrap
//! through the u32 cast); clamping makes that case defined, and the graph does the same.
//!
//! # Backward without races or table-sized fills
//! The gradient of level l only touches level l's entries, so levels are the unit of
//! parallelism: one rayon task per level scans all points in order and scatters `w · ∂L/∂y`
//! into that level's buffer. No two tasks share an entry, the sum for an entry is always taken
//! in point order (bitwise the same result for any thread count, and for one pass or several
//! consecutive ones), and only one level's buffer (≤ T·F floats) is hot per thread.
//! A per-level bitset marks the entries touched since [`HashGridGradient::clear`]; the first
//! touch overwrites the entry, later ones add, so the value buffers are never zero-filled
//! (clearing costs T/64 words per level).

use super::config::{HashGridConfig, LevelLayout};
use crate::error::{Error, Result};
use crate::rng::Rng;
use rayon::prelude::*;

/// Points per forward chunk: large, so that each level's table is reused across many points
/// (a chunk's scratch is `FORWARD_CHUNK × L·F` floats).
const FORWARD_CHUNK: usize = 1 << 18;
/// Rows per rayon task when transposing the scratch into the output.
const TRANSPOSE_ROWS: usize = 4096;

/// The encoding's parameters: one table of `total_entries × F` floats, level after level,
/// each entry's F features adjacent (tiny-cuda-nn's layout).
#[derive(Debug, Clone, PartialEq)]
pub struct HashGrid {
    config: HashGridConfig,
    levels: Vec<LevelLayout>,
    params: Vec<f32>,
}

/// The 8 corners of one point's cell on one level: entries within the level and weights.
#[derive(Debug, Clone, Copy)]
pub struct Corners {
    /// Entry of each corner (within the level, before adding its offset).
    pub index: [u32; 8],
    /// Trilinear weight of each corner (they sum to 1).
    pub weight: [f32; 8],
}

/// The corners and weights of `x` (any point; clamped to the unit cube) on `level`.
///
/// The same entries as [`LevelLayout::index`] on each corner, computed from per-axis terms:
/// the hash is a XOR of one term per axis and the dense index a sum, so each axis needs its
/// two terms once rather than eight products and eight divisions.
#[inline(always)]
pub fn corners(level: &LevelLayout, x: [f32; 3]) -> Corners {
    let mut cell = [0u32; 3];
    let mut w = [[0f32; 2]; 3];
    for d in 0..3 {
        let pos = x[d].max(0.0).min(1.0) * level.scale + 0.5;
        let floor = pos.floor();
        cell[d] = floor as u32;
        let frac = pos - floor;
        w[d] = [1.0 - frac, frac];
    }
    // terms[d][b]: axis d's contribution for the corner at cell[d] + b.
    let stride = if level.dense { [1, level.resolution, level.resolution.wrapping_mul(level.resolution)] } else { super::config::PRIMES };
    let terms = [0, 1, 2].map(|d| [cell[d].wrapping_mul(stride[d]), (cell[d] + 1).wrapping_mul(stride[d])]);
    let mut out = Corners { index: [0; 8], weight: [0.0; 8] };
    for k in 0..8 {
        let (bx, by, bz) = (k & 1, (k >> 1) & 1, (k >> 2) & 1);
        // (1 · wx) · wy · wz, tiny-cuda-nn's order of products.
        out.weight[k] = w[0][bx] * w[1][by] * w[2][bz];
        out.index[k] = if level.dense {
            // < 2·entries (res + res² + res³ < 2·res³ for res ≥ 2; 3 < 16 for res 1): one
            // subtraction is the modulo.
            let i = terms[0][bx] + terms[1][by] + terms[2][bz];
            if i >= level.entries { i - level.entries } else { i }
        } else {
            (terms[0][bx] ^ terms[1][by] ^ terms[2][bz]) & (level.entries - 1)
        };
    }
    out
}

impl HashGrid {
    /// A grid with every parameter drawn from U(−1e-4, 1e-4) (tiny-cuda-nn's initialisation),
    /// deterministic in `seed`.
    pub fn new(config: HashGridConfig, seed: u64) -> Result<Self> {
        let levels = config.layout()?;
        let n = total_entries(&levels) * config.features_per_level;
        let mut rng = Rng::new(seed);
        let params = (0..n).map(|_| (rng.uniform() * 2.0 - 1.0) * 1e-4).collect();
        Ok(HashGrid { config, levels, params })
    }

    /// A grid with the given parameters (`total_entries × F` floats, e.g. from a checkpoint).
    pub fn from_params(config: HashGridConfig, params: Vec<f32>) -> Result<Self> {
        let levels = config.layout()?;
        let want = total_entries(&levels) * config.features_per_level;
        if params.len() != want {
            return Err(Error::Argument(format!("hash grid: {} parameters given, the config needs {want}", params.len())));
        }
        Ok(HashGrid { config, levels, params })
    }

    /// The configuration.
    pub fn config(&self) -> &HashGridConfig {
        &self.config
    }

    /// The per-level layout.
    pub fn levels(&self) -> &[LevelLayout] {
        &self.levels
    }

    /// The table, `[total_entries, F]` row-major.
    pub fn params(&self) -> &[f32] {
        &self.params
    }

    /// The table, mutable (optimisers, tests).
    pub fn params_mut(&mut self) -> &mut [f32] {
        &mut self.params
    }

    /// Output width L·F.
    pub fn output_dim(&self) -> usize {
        self.config.output_dim()
    }

    /// Encode points of the unit cube.
    ///
    /// # Shapes
    /// `points`: `[n, 3]` → `[n, L·F]` row-major.
    pub fn forward(&self, points: &[[f32; 3]]) -> Vec<f32> {
        let mut out = vec![0.0; points.len() * self.output_dim()];
        self.forward_into(points, &mut out);
        out
    }

    /// [`forward`](Self::forward) into a caller's buffer of `points.len() × L·F` floats.
    ///
    /// Level-major like the backward pass: one rayon task per level evaluates a whole chunk of
    /// points (so the level's part of the table is reused from cache across the chunk) into a
    /// level-major scratch buffer, which is then transposed into the rows.
    pub fn forward_into(&self, points: &[[f32; 3]], out: &mut [f32]) {
        let width = self.output_dim();
        let f = self.config.features_per_level;
        assert_eq!(out.len(), points.len() * width, "hash grid forward: output buffer is not [n, L·F]");
        let mut scratch = vec![0.0f32; points.len().min(FORWARD_CHUNK) * width];
        for (pts, rows) in points.chunks(FORWARD_CHUNK).zip(out.chunks_mut(FORWARD_CHUNK * width)) {
            let n = pts.len();
            scratch[..n * width].par_chunks_mut(n * f).zip(self.levels.par_iter()).for_each(|(column, level)| {
                let table = &self.params[level.offset as usize * f..(level.offset + level.entries) as usize * f];
                match f {
                    1 => forward_level::<1>(level, table, pts, column),
                    2 => forward_level::<2>(level, table, pts, column),
                    4 => forward_level::<4>(level, table, pts, column),
                    _ => forward_level::<8>(level, table, pts, column),
                }
            });
            let scratch = &scratch[..n * width];
            rows.par_chunks_mut(TRANSPOSE_ROWS * width).enumerate().for_each(|(b, block)| {
                for (r, row) in block.chunks_exact_mut(width).enumerate() {
                    let i = b * TRANSPOSE_ROWS + r;
                    for (l, dst) in row.chunks_exact_mut(f).enumerate() {
                        dst.copy_from_slice(&scratch[(l * n + i) * f..(l * n + i + 1) * f]);
                    }
                }
            });
        }
    }

    /// Accumulate the table gradient of `points` with output gradient `grad_out` into `grad`
    /// (added to what it holds since its last [`HashGridGradient::clear`]).
    ///
    /// # Shapes
    /// `points`: `[n, 3]`, `grad_out`: `[n, L·F]` (∂loss/∂features) → the sparse table gradient.
    pub fn backward(&self, points: &[[f32; 3]], grad_out: &[f32], grad: &mut HashGridGradient) {
        let width = self.output_dim();
        assert_eq!(grad_out.len(), points.len() * width, "hash grid backward: grad_out is not [n, L·F]");
        assert!(grad.matches(self), "hash grid backward: the gradient buffer was made for another grid");
        grad.levels.par_iter_mut().zip(self.levels.par_iter()).enumerate().for_each(|(l, (buffer, level))| {
            match self.config.features_per_level {
                1 => backward_level::<1>(level, points, grad_out, width, l, buffer),
                2 => backward_level::<2>(level, points, grad_out, width, l, buffer),
                4 => backward_level::<4>(level, points, grad_out, width, l, buffer),
                _ => backward_level::<8>(level, points, grad_out, width, l, buffer),
            }
        });
    }
}

fn total_entries(levels: &[LevelLayout]) -> usize {
    levels.last().map_or(0, |l| (l.offset + l.entries) as usize)
}

/// One level for `points`, written level-major: `column` is `[points.len(), F]`.
#[inline(always)]
fn forward_level<const F: usize>(level: &LevelLayout, table: &[f32], points: &[[f32; 3]], column: &mut [f32]) {
    for (dst, &x) in column.chunks_exact_mut(F).zip(points) {
        let c = corners(level, x);
        let mut acc = [0f32; F];
        for k in 0..8 {
            let e = c.index[k] as usize * F;
            let value: &[f32; F] = table[e..e + F].try_into().expect("F features");
            for f in 0..F {
                acc[f] += c.weight[k] * value[f];
            }
        }
        dst.copy_from_slice(&acc);
    }
}

#[inline(always)]
fn backward_level<const F: usize>(level: &LevelLayout, points: &[[f32; 3]], grad_out: &[f32], width: usize, l: usize, buffer: &mut LevelGradient) {
    for (row, &x) in grad_out.chunks_exact(width).zip(points) {
        let g: [f32; F] = row[l * F..(l + 1) * F].try_into().expect("F features");
        let c = corners(level, x);
        for k in 0..8 {
            let e = c.index[k] as usize;
            let w = c.weight[k];
            let (word, bit) = (&mut buffer.touched[e >> 6], 1u64 << (e & 63));
            let dst: &mut [f32; F] = (&mut buffer.values[e * F..e * F + F]).try_into().expect("F features");
            if *word & bit == 0 {
                *word |= bit;
                for f in 0..F {
                    dst[f] = w * g[f];
                }
            } else {
                for f in 0..F {
                    dst[f] += w * g[f];
                }
            }
        }
    }
}

/// One level's share of a [`HashGridGradient`].
#[derive(Debug, Clone)]
pub(super) struct LevelGradient {
    /// `entries × F` floats; meaningful only where `touched` is set.
    pub(super) values: Vec<f32>,
    /// One bit per entry: touched since the last clear.
    pub(super) touched: Vec<u64>,
}

/// The sparse gradient of a [`HashGrid`]'s table: per-level buffers plus a touched bitset,
/// reused step after step (allocate once with [`HashGridGradient::new`]).
#[derive(Debug, Clone)]
pub struct HashGridGradient {
    features: usize,
    pub(super) levels: Vec<LevelGradient>,
}

impl HashGridGradient {
    /// An empty gradient for `grid`.
    pub fn new(grid: &HashGrid) -> Self {
        let f = grid.config.features_per_level;
        let levels = grid
            .levels
            .iter()
            .map(|l| LevelGradient { values: vec![0.0; l.entries as usize * f], touched: vec![0; (l.entries as usize).div_ceil(64)] })
            .collect();
        HashGridGradient { features: f, levels }
    }

    fn matches(&self, grid: &HashGrid) -> bool {
        self.features == grid.config.features_per_level
            && self.levels.len() == grid.levels.len()
            && self.levels.iter().zip(&grid.levels).all(|(g, l)| g.values.len() == l.entries as usize * self.features)
    }

    /// Forget everything accumulated (clears the touched bits only).
    pub fn clear(&mut self) {
        self.levels.par_iter_mut().for_each(|l| l.touched.fill(0));
    }

    /// Number of table entries touched since the last clear.
    pub fn touched_entries(&self) -> usize {
        self.levels.iter().flat_map(|l| &l.touched).map(|w| w.count_ones() as usize).sum()
    }

    /// The gradient as a dense `[total_entries, F]` vector (zeros where untouched; for tests
    /// and small grids).
    pub fn to_dense(&self) -> Vec<f32> {
        let f = self.features;
        let mut out = Vec::new();
        for level in &self.levels {
            for (e, value) in level.values.chunks_exact(f).enumerate() {
                if level.touched[e >> 6] & (1 << (e & 63)) != 0 {
                    out.extend_from_slice(value);
                } else {
                    out.extend(std::iter::repeat_n(0.0, f));
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hash_grid::config::PRIMES;

    fn random_points(n: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut rng = Rng::new(seed);
        (0..n).map(|_| [rng.uniform(), rng.uniform(), rng.uniform()]).collect()
    }

    fn small_config() -> HashGridConfig {
        // Levels 0–1 dense (res 4, 7), 2–3 hashed (res 11, 18 > ∛512 = 8).
        HashGridConfig { levels: 4, features_per_level: 2, log2_table_size: 9, base_resolution: 4, max_resolution: 17 }
    }

    /// The encoding from its definition, written independently: f64 weights, u64 hash.
    fn reference_forward(grid: &HashGrid, x: [f32; 3]) -> Vec<f64> {
        let f = grid.config.features_per_level;
        let mut out = Vec::new();
        for level in &grid.levels {
            let mut cell = [0u64; 3];
            let mut frac = [0f64; 3];
            for d in 0..3 {
                let pos = (x[d].clamp(0.0, 1.0) * level.scale + 0.5) as f64;
                cell[d] = pos.floor() as u64;
                frac[d] = pos - pos.floor();
            }
            let mut acc = vec![0f64; f];
            for (dx, dy, dz) in (0..8).map(|k| (k & 1, (k >> 1) & 1, (k >> 2) & 1)) {
                let c = [cell[0] + dx, cell[1] + dy, cell[2] + dz];
                let w = [dx, dy, dz].iter().zip(frac).map(|(&b, t)| if b == 1 { t } else { 1.0 - t }).product::<f64>();
                let r = level.resolution as u64;
                let entry = if level.dense {
                    (c[0] + c[1] * r + c[2] * r * r) % level.entries as u64
                } else {
                    let h = (0..3).map(|d| (c[d] * PRIMES[d] as u64) % (1 << 32)).fold(0, |a, b| a ^ b);
                    h % level.entries as u64
                };
                let row = (level.offset as u64 + entry) as usize * f;
                for i in 0..f {
                    acc[i] += w * grid.params[row + i] as f64;
                }
            }
            out.extend(acc);
        }
        out
    }

    #[test]
    fn trilinear_case_by_hand() {
        // One dense level, scale 1, resolution 2, 8 entries; entry e holds e, so a corner
        // (cx, cy, cz) holds (cx + 2cy + 4cz) mod 8.
        let config = HashGridConfig { levels: 1, features_per_level: 1, log2_table_size: 3, base_resolution: 2, max_resolution: 2 };
        let grid = HashGrid::from_params(config, (0..8).map(|e| e as f32).collect()).unwrap();
        assert_eq!(grid.levels()[0].resolution, 2);
        // (0.1, 0.2, 0.3) → pos (0.6, 0.7, 0.8) in cell (0, 0, 0): 0.6 + 2·0.7 + 4·0.8 = 5.2.
        // (0.25, 0.5, 0.75) → pos (0.75, 1, 1.25), cell (0, 1, 1), frac (0.75, 0, 0.25): the
        // z + 1 corners sit at z = 2, whose index wraps (−8), so the z part is 0.75·4 + 0.25·0:
        // 0.75 + 2·1 + 3 = 5.75.
        let out = grid.forward(&[[0.1, 0.2, 0.3], [0.25, 0.5, 0.75], [-3.0, 0.2, 7.0]]);
        assert!((out[0] - 5.2).abs() < 1e-5, "{}", out[0]);
        assert!((out[1] - 5.75).abs() < 1e-6, "{}", out[1]);
        // Clamped to (0, 0.2, 1) → pos (0.5, 0.7, 1.5): cell (0, 0, 1), frac (0.5, 0.7, 0.5);
        // z = 1 → 4, z = 2 → wraps to 0: 0.5 + 1.4 + (0.5·4 + 0.5·0) = 3.9.
        assert!((out[2] - 3.9).abs() < 1e-5, "{}", out[2]);
    }

    #[test]
    fn forward_matches_the_reference() {
        for features in [1, 2, 4, 8] {
            let config = HashGridConfig { features_per_level: features, ..small_config() };
            let mut grid = HashGrid::new(config, 3).unwrap();
            let mut rng = Rng::new(9);
            grid.params_mut().iter_mut().for_each(|p| *p = rng.uniform() * 2.0 - 1.0);
            let mut points = random_points(50, 4);
            points.push([1.0, 1.0, 1.0]);
            points.push([0.0, 0.0, 0.0]);
            points.push([1.5, -0.5, 0.5]);
            let out = grid.forward(&points);
            assert_eq!(out.len(), points.len() * 4 * features);
            for (row, &x) in out.chunks_exact(4 * features).zip(&points) {
                for (a, b) in row.iter().zip(reference_forward(&grid, x)) {
                    assert!((*a as f64 - b).abs() < 1e-5, "F {features}, {x:?}: {a} vs {b}");
                }
            }
        }
    }

    #[test]
    fn corners_agree_with_the_layout_index() {
        let mut levels = HashGridConfig::default().layout().unwrap();
        levels.extend(small_config().layout().unwrap());
        levels.extend(HashGridConfig { base_resolution: 1, max_resolution: 3, levels: 3, ..small_config() }.layout().unwrap());
        let mut points = random_points(200, 11);
        points.extend([[1.0, 1.0, 1.0], [0.0, 1.0, 0.0], [0.999_999, 0.5, 1.0]]);
        for level in &levels {
            for &x in &points {
                let c = corners(level, x);
                let cell = x.map(|v| (v * level.scale + 0.5).floor() as u32);
                for k in 0..8 {
                    let corner = [0, 1, 2].map(|d| cell[d] + ((k >> d) & 1) as u32);
                    assert_eq!(c.index[k], level.index(corner), "level {level:?}, {x:?}, corner {k}");
                }
                assert!((c.weight.iter().sum::<f32>() - 1.0).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn levels_are_both_dense_and_hashed_in_the_small_config() {
        let grid = HashGrid::new(small_config(), 0).unwrap();
        let kinds: Vec<bool> = grid.levels().iter().map(|l| l.dense).collect();
        assert_eq!(kinds, [true, true, false, false]);
        assert!(grid.params().iter().all(|p| p.abs() <= 1e-4));
        assert_ne!(grid.params()[0], grid.params()[1]);
        assert_eq!(HashGrid::new(small_config(), 0).unwrap(), grid, "seeded");
        let err = HashGrid::from_params(small_config(), vec![0.0; 5]).unwrap_err().to_string();
        assert!(err.contains("5 parameters"), "{err}");
    }

    /// loss = ½ Σ r ⊙ y², so ∂loss/∂y = r ⊙ y.
    fn loss(grid: &HashGrid, points: &[[f32; 3]], r: &[f32]) -> f64 {
        grid.forward(points).iter().zip(r).map(|(&y, &r)| 0.5 * r as f64 * (y as f64).powi(2)).sum()
    }

    #[test]
    fn backward_matches_finite_differences() {
        let mut grid = HashGrid::new(small_config(), 1).unwrap();
        let mut rng = Rng::new(2);
        grid.params_mut().iter_mut().for_each(|p| *p = rng.uniform() * 2.0 - 1.0);
        let points = random_points(40, 5);
        let r: Vec<f32> = (0..points.len() * grid.output_dim()).map(|_| rng.uniform() * 2.0 - 1.0).collect();
        let y = grid.forward(&points);
        let grad_out: Vec<f32> = y.iter().zip(&r).map(|(y, r)| y * r).collect();
        let mut grad = HashGridGradient::new(&grid);
        grid.backward(&points, &grad_out, &mut grad);
        let dense = grad.to_dense();
        assert!(grad.touched_entries() > 0 && grad.touched_entries() < dense.len() / 2, "some entries, not all");
        let h = 1e-2f32;
        let mut checked_nonzero = 0;
        for k in (0..dense.len()).step_by(7) {
            let old = grid.params()[k];
            grid.params_mut()[k] = old + h;
            let plus = loss(&grid, &points, &r);
            grid.params_mut()[k] = old - h;
            let minus = loss(&grid, &points, &r);
            grid.params_mut()[k] = old;
            let fd = (plus - minus) / (2.0 * h as f64);
            assert!((fd - dense[k] as f64).abs() <= 1e-3 * (1.0 + fd.abs()), "entry {k}: backward {} vs finite difference {fd}", dense[k]);
            checked_nonzero += usize::from(fd.abs() > 1e-3);
        }
        assert!(checked_nonzero > 10, "only {checked_nonzero} non-zero gradients checked");
    }

    #[test]
    fn backward_is_the_adjoint_of_forward() {
        // ⟨g, forward(θ)⟩ = ⟨backward(g), θ⟩ for every table θ (the encoding is linear in θ).
        let mut grid = HashGrid::new(HashGridConfig { features_per_level: 4, ..small_config() }, 1).unwrap();
        let mut rng = Rng::new(8);
        grid.params_mut().iter_mut().for_each(|p| *p = rng.uniform() * 2.0 - 1.0);
        let points = random_points(300, 6);
        let g: Vec<f32> = (0..points.len() * grid.output_dim()).map(|_| rng.uniform() - 0.5).collect();
        let lhs: f64 = grid.forward(&points).iter().zip(&g).map(|(&a, &b)| a as f64 * b as f64).sum();
        let mut grad = HashGridGradient::new(&grid);
        grid.backward(&points, &g, &mut grad);
        let rhs: f64 = grad.to_dense().iter().zip(grid.params()).map(|(&a, &b)| a as f64 * b as f64).sum();
        assert!((lhs - rhs).abs() < 1e-4 * lhs.abs().max(1.0), "{lhs} vs {rhs}");
    }

    #[test]
    fn gradient_is_deterministic_across_threads_and_passes() {
        let grid = HashGrid::new(HashGridConfig { log2_table_size: 12, ..HashGridConfig::default() }, 1).unwrap();
        let points = random_points(5000, 7);
        let mut rng = Rng::new(3);
        let g: Vec<f32> = (0..points.len() * grid.output_dim()).map(|_| rng.uniform() - 0.5).collect();
        let run = |threads: usize, passes: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let mut grad = HashGridGradient::new(&grid);
                // Stale values from an earlier step must not leak in: fill, clear, then accumulate.
                grid.backward(&points, &g, &mut grad);
                grad.clear();
                let per = points.len() / passes;
                let w = grid.output_dim();
                for p in 0..passes {
                    grid.backward(&points[p * per..(p + 1) * per], &g[p * per * w..(p + 1) * per * w], &mut grad);
                }
                grad.to_dense()
            })
        };
        let one = run(1, 1);
        assert!(one.iter().any(|&v| v != 0.0));
        assert_eq!(run(2, 1), one, "2 threads");
        assert_eq!(run(2, 4), one, "4 consecutive passes");
        assert_eq!(run(2, 1), run(2, 1), "repeatable");
    }
}
