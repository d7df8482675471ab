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
        // pos ≥ 0.5 (x is clamped to [0, 1], the scale is positive), so truncation is the
        // floor, exactly, in one instruction (`f32::floor` is a libm call on baseline x86_64).
        cell[d] = pos as u32;
        let frac = pos - cell[d] as f32;
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

    /// The gradient with respect to the points of a loss whose gradient with respect to the
    /// features is `grad_out` (tiny-cuda-nn's `dy_dx` path): per level, the trilinear weights'
    /// derivatives along each axis times the corners' features, times the level's scale. A
    /// coordinate outside [0, 1] is clamped, so its gradient is 0.
    ///
    /// # Shapes
    /// `points`: `[n, 3]`, `grad_out`: `[n, L·F]` → `[n, 3]`.
    pub fn position_gradient(&self, points: &[[f32; 3]], grad_out: &[f32]) -> Vec<[f32; 3]> {
        let (width, f) = (self.output_dim(), self.config.features_per_level);
        assert_eq!(grad_out.len(), points.len() * width, "hash grid position gradient: grad_out is not [n, L·F]");
        let mut out = vec![[0.0f32; 3]; points.len()];
        out.par_chunks_mut(TRANSPOSE_ROWS).enumerate().for_each(|(b, chunk)| {
            for (i, dx) in chunk.iter_mut().enumerate() {
                let r = b * TRANSPOSE_ROWS + i;
                let x = points[r];
                let inside = x.map(|v| (0.0..=1.0).contains(&v));
                for (l, level) in self.levels.iter().enumerate() {
                    let c = corners(level, x);
                    let g = &grad_out[r * width + l * f..r * width + (l + 1) * f];
                    // Per-axis weights again: w[d] = [1 − frac, frac].
                    let w = [0, 1, 2].map(|d| {
                        let pos = x[d].max(0.0).min(1.0) * level.scale + 0.5;
                        let frac = pos - (pos as u32) as f32;
                        [1.0 - frac, frac]
                    });
                    let base = level.offset as usize * f;
                    let mut acc = [0.0f32; 3];
                    for k in 0..8 {
                        let e = base + c.index[k] as usize * f;
                        let s: f32 = self.params[e..e + f].iter().zip(g).map(|(t, g)| t * g).sum();
                        let bits = [k & 1, (k >> 1) & 1, (k >> 2) & 1];
                        for d in 0..3 {
                            let sign = if bits[d] == 1 { 1.0 } else { -1.0 };
                            let others: f32 = (0..3).filter(|&e| e != d).map(|e| w[e][bits[e]]).product();
                            acc[d] += s * sign * others;
                        }
                    }
                    for d in 0..3 {
                        if inside[d] {
                            dx[d] += acc[d] * level.scale;
                        }
                    }
                }
            }
        });
        out
    }
}

fn total_entries(levels: &[LevelLayout]) -> usize {
    levels.last().map_or(0, |l| (l.offset + l.entries) as usize)
}

/// One level for `points`, written level-major: `column` is `[points.len(), F]`.
/// Points looked ahead: their corners are computed and their table rows prefetched this many
/// points before they are read, so the rows of fine levels (random in a table larger than the
/// caches) arrive while earlier points are summed.
const LOOKAHEAD: usize = 8;

/// Ask for the cache line of `slice[i]` (a hint: no effect on results, never faults).
#[inline(always)]
fn prefetch<T>(slice: &[T], i: usize) {
    prefetch_in(slice.as_ptr(), slice.len(), i);
}

/// [`prefetch`] of element `i` of the `len` elements at `base` (for a buffer that is borrowed
/// mutably elsewhere meanwhile: only its address is read here).
#[inline(always)]
fn prefetch_in<T>(base: *const T, len: usize, i: usize) {
    #[cfg(target_arch = "x86_64")]
    if i < len {
        // SAFETY: SSE is part of x86_64; `base + i` is inside the allocation (i < len), and a
        // prefetch only loads its line into the cache.
        unsafe { std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(base.add(i).cast()) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (base, len, i);
}

/// Each point's corners on `level`, `LOOKAHEAD` points ahead of `visit`, whose rows
/// `prefetch_rows` has asked for by then.
#[inline(always)]
fn with_corners_ahead(level: &LevelLayout, points: &[[f32; 3]], prefetch_rows: impl Fn(&Corners), mut visit: impl FnMut(usize, &Corners)) {
    let empty = Corners { index: [0; 8], weight: [0.0; 8] };
    let mut ring = [empty; LOOKAHEAD];
    for (i, &x) in points.iter().enumerate().take(LOOKAHEAD) {
        ring[i] = corners(level, x);
        prefetch_rows(&ring[i]);
    }
    for i in 0..points.len() {
        let slot = i % LOOKAHEAD;
        let c = ring[slot];
        if let Some(&x) = points.get(i + LOOKAHEAD) {
            ring[slot] = corners(level, x);
            prefetch_rows(&ring[slot]);
        }
        visit(i, &c);
    }
}

#[inline(always)]
fn forward_level<const F: usize>(level: &LevelLayout, table: &[f32], points: &[[f32; 3]], column: &mut [f32]) {
    with_corners_ahead(
        level,
        points,
        |c| c.index.iter().for_each(|&e| prefetch(table, e as usize * F)),
        |i, c| {
            let mut acc = [0f32; F];
            for k in 0..8 {
                let e = c.index[k] as usize * F;
                let value: &[f32; F] = table[e..e + F].try_into().expect("F features");
                for f in 0..F {
                    acc[f] += c.weight[k] * value[f];
                }
            }
            column[i * F..(i + 1) * F].copy_from_slice(&acc);
        },
    );
}

#[inline(always)]
fn backward_level<const F: usize>(level: &LevelLayout, points: &[[f32; 3]], grad_out: &[f32], width: usize, l: usize, buffer: &mut LevelGradient) {
    let (values, touched) = ((buffer.values.as_ptr(), buffer.values.len()), (buffer.touched.as_ptr(), buffer.touched.len()));
    with_corners_ahead(
        level,
        points,
        |c| {
            for &e in &c.index {
                prefetch_in(values.0, values.1, e as usize * F);
                prefetch_in(touched.0, touched.1, e as usize >> 6);
            }
        },
        |i, c| {
            let g: [f32; F] = grad_out[i * width + l * F..i * width + (l + 1) * F].try_into().expect("F features");
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
        },
    );
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

    /// Each level's values (`entries × F`, meaningful where touched) and touched bits (one per
    /// entry), for an optimiser that visits the touched entries and clears their bits.
    pub fn levels_mut(&mut self) -> impl IndexedParallelIterator<Item = (&[f32], &mut [u64])> {
        self.levels.par_iter_mut().map(|l| (l.values.as_slice(), l.touched.as_mut_slice()))
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
mod tests;
