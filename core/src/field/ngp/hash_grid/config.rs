//! The hash-grid encoding's configuration and the per-level layout derived from it, as
//! tiny-cuda-nn's `GridEncodingTemplated` computes them.

use crate::error::{Error, Result};
use crate::sample::contraction::{CONTRACTED_HALF_SIZE, Contraction};
use serde::{Deserialize, Serialize};

/// The first three of tiny-cuda-nn's hash primes (`1` keeps x-neighbours in one cache line).
pub const PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];

/// A multiresolution hash encoding (instant-ngp, Müller et al. 2022) of points in the unit
/// cube: L levels of F features, at most T = 2^`log2_table_size` entries per level,
/// resolutions growing geometrically from `base_resolution` to `max_resolution`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HashGridConfig {
    /// Number of levels L (1–32, tiny-cuda-nn's limit).
    pub levels: usize,
    /// Features per level F (1, 2, 4 or 8, as tiny-cuda-nn).
    pub features_per_level: usize,
    /// log2 of the table size T: each level holds at most T entries (3–30).
    pub log2_table_size: u32,
    /// Coarsest resolution N_min (≥ 1).
    pub base_resolution: u32,
    /// Finest resolution N_max (N_min ≤ N_max ≤ 65,536; unused when L = 1).
    pub max_resolution: u32,
}

impl Default for HashGridConfig {
    /// instant-ngp's NeRF grid: L 16, F 2, T 2¹⁹, N_min 16, N_max 2048.
    fn default() -> Self {
        HashGridConfig { levels: 16, features_per_level: 2, log2_table_size: 19, base_resolution: 16, max_resolution: 2048 }
    }
}

/// Where one level lives in the table and how it is indexed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LevelLayout {
    /// `N_min · bˡ − 1`: a coordinate x ∈ [0, 1] maps to `x · scale + 0.5` grid units.
    pub scale: f32,
    /// Vertices per axis, `⌈scale⌉ + 1`.
    pub resolution: u32,
    /// Entries of this level: `min(next_multiple(resolution³, 8), T)`.
    pub entries: u32,
    /// Index of the level's first entry in the whole table.
    pub offset: u32,
    /// `resolution³ ≤ entries`: indexed densely (x + y·res + z·res²), else by the hash.
    pub dense: bool,
}

impl LevelLayout {
    /// The entry (within the level) of grid vertex `c`, as tiny-cuda-nn's `grid_index`: dense
    /// levels `(x + y·res + z·res²) mod entries` (the +0.5 offset can put a corner at `res`,
    /// which wraps), hashed levels `(x·1 ⊕ y·2654435761 ⊕ z·805459861) mod T` in u32.
    #[inline(always)]
    pub fn index(&self, c: [u32; 3]) -> u32 {
        if self.dense {
            let r = self.resolution;
            (c[0].wrapping_add(c[1].wrapping_mul(r)).wrapping_add(c[2].wrapping_mul(r).wrapping_mul(r))) % self.entries
        } else {
            spatial_hash(c) & (self.entries - 1)
        }
    }
}

/// tiny-cuda-nn's coherent prime hash of a grid vertex (before the `mod T`).
#[inline(always)]
pub fn spatial_hash(c: [u32; 3]) -> u32 {
    c[0].wrapping_mul(PRIMES[0]) ^ c[1].wrapping_mul(PRIMES[1]) ^ c[2].wrapping_mul(PRIMES[2])
}

impl HashGridConfig {
    /// The table size T.
    pub fn table_size(&self) -> u32 {
        1 << self.log2_table_size
    }

    /// log2 of a table size given as a count (for configs that name T itself).
    pub fn log2_of_table_size(table_size: u64) -> Result<u32> {
        if !table_size.is_power_of_two() {
            return Err(Error::Argument(format!("hash grid: table size {table_size} is not a power of two")));
        }
        Ok(table_size.trailing_zeros())
    }

    /// Check every field; the error names the field and its allowed range.
    pub fn validate(&self) -> Result<()> {
        let bad = |msg: String| Err(Error::Argument(format!("hash grid: {msg}")));
        if !(1..=32).contains(&self.levels) {
            return bad(format!("levels = {}, must be 1–32", self.levels));
        }
        if ![1, 2, 4, 8].contains(&self.features_per_level) {
            return bad(format!("features_per_level = {}, must be 1, 2, 4 or 8", self.features_per_level));
        }
        if !(3..=30).contains(&self.log2_table_size) {
            return bad(format!("log2_table_size = {}, must be 3–30 (T = 8 … 2³⁰)", self.log2_table_size));
        }
        if self.base_resolution == 0 {
            return bad("base_resolution = 0, must be at least 1".into());
        }
        if self.max_resolution < self.base_resolution {
            return bad(format!("max_resolution {} is below base_resolution {}", self.max_resolution, self.base_resolution));
        }
        if self.max_resolution > 1 << 16 {
            return bad(format!("max_resolution = {}, must be at most 65536 (f32 positions resolve no finer)", self.max_resolution));
        }
        Ok(())
    }

    /// Per-level growth b = exp((ln N_max − ln N_min)/(L − 1)) (1 for a single level).
    pub fn growth(&self) -> f64 {
        if self.levels <= 1 {
            return 1.0;
        }
        ((self.max_resolution as f64).ln() - (self.base_resolution as f64).ln()).exp().powf(1.0 / (self.levels - 1) as f64)
    }

    /// Output width L·F.
    pub fn output_dim(&self) -> usize {
        self.levels * self.features_per_level
    }

    /// Every level's scale, resolution, size and offset (validates first).
    pub fn layout(&self) -> Result<Vec<LevelLayout>> {
        self.validate()?;
        let log2_b = self.growth().log2();
        let t = self.table_size() as u64;
        let mut offset = 0u64;
        let mut levels = Vec::with_capacity(self.levels);
        for l in 0..self.levels {
            let scale = ((l as f64 * log2_b).exp2() * self.base_resolution as f64 - 1.0) as f32;
            let resolution = scale.ceil() as u32 + 1;
            let dense_size = (resolution as u64).pow(3);
            let entries = dense_size.next_multiple_of(8).min(t);
            levels.push(LevelLayout { scale, resolution, entries: entries as u32, offset: offset as u32, dense: dense_size <= entries });
            offset += entries;
        }
        if offset > u32::MAX as u64 {
            return Err(Error::Argument(format!("hash grid: {offset} entries in all, more than a u32 indexes")));
        }
        Ok(levels)
    }

    /// Total entries over all levels (the table holds this × F floats).
    pub fn total_entries(&self) -> Result<usize> {
        Ok(self.layout()?.last().map_or(0, |l| (l.offset + l.entries) as usize))
    }
}

/// The axis-aligned box a grid covers: world points map into the unit cube by
/// `(p − min) · scale`, `scale = 1/(max − min)` per axis (rounded to f32 once, and the exported
/// graph multiplies by the same f32, so both see the same unit-cube point). With a
/// [`Contraction`], points are contracted first and the box is the contracted world's cube
/// [`GridBound::contracted`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridBound {
    /// The corner mapped to (0, 0, 0).
    pub min: [f32; 3],
    /// The corner mapped to (1, 1, 1).
    pub max: [f32; 3],
    /// Contract world points before mapping them (unbounded captures). Absent: none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contraction: Option<Contraction>,
}

impl GridBound {
    /// The cube `[−half, half]³` (the Blender scenes use half = 1.5).
    pub fn cube(half: f32) -> Self {
        GridBound { min: [-half; 3], max: [half; 3], contraction: None }
    }

    /// The whole world, contracted into `[−2, 2]³`.
    pub fn contracted(contraction: Contraction) -> Self {
        GridBound { contraction: Some(contraction), ..Self::cube(CONTRACTED_HALF_SIZE) }
    }

    /// Half the side of the smallest origin-centred cube holding the box.
    pub fn enclosing_half_size(&self) -> f32 {
        (0..3).map(|k| self.max[k].abs().max(self.min[k].abs())).fold(0.0f32, f32::max)
    }

    /// Check the box is finite and not flat (and, contracted, the contracted world's cube).
    pub fn validate(&self) -> Result<()> {
        for d in 0..3 {
            if !(self.min[d].is_finite() && self.max[d].is_finite() && self.max[d] > self.min[d]) {
                return Err(Error::Argument(format!("grid bound: axis {d} spans [{}, {}], needs finite min < max", self.min[d], self.max[d])));
            }
        }
        if let Some(c) = self.contraction
            && *self != Self::contracted(c)
        {
            return Err(Error::Argument(format!("grid bound: a contracted grid covers [-2, 2]^3, not {:?}..{:?}", self.min, self.max)));
        }
        Ok(())
    }

    /// `1/(max − min)` per axis.
    pub fn scale(&self) -> [f32; 3] {
        [0, 1, 2].map(|d| 1.0 / (self.max[d] - self.min[d]))
    }

    /// `p` in unit-cube coordinates (contracted first where the bound says; not clamped: the
    /// encoding clamps).
    #[inline]
    pub fn to_unit(&self, p: [f32; 3]) -> [f32; 3] {
        let p = match self.contraction {
            Some(c) => c.apply(p),
            None => p,
        };
        let s = self.scale();
        [0, 1, 2].map(|d| (p[d] - self.min[d]) * s[d])
    }

    /// The gradient with respect to the world point `p` of a loss whose gradient with respect
    /// to [`to_unit`](Self::to_unit)`(p)` is `g`.
    pub fn to_unit_backward(&self, p: [f32; 3], g: [f32; 3]) -> [f32; 3] {
        let s = self.scale();
        let g = [0, 1, 2].map(|d| g[d] * s[d]);
        match self.contraction {
            Some(c) => c.backward(p, g),
            None => g,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hash_matches_hand_computed_values() {
        // (1, 2, 3): 1 ⊕ (2·2654435761 mod 2³²) ⊕ (3·805459861 mod 2³²)
        //          = 1 ⊕ 1013904226 ⊕ 2416379583 (5308871522 − 2³² = 1013904226; 2416379583 < 2³²)
        //          = 1013904227 ⊕ 2416379583 = 0x3C6E_F363 ⊕ 0x9007_06BF = 0xAC69_F5DC = 2892625372.
        assert_eq!(2u32.wrapping_mul(PRIMES[1]), 1_013_904_226);
        assert_eq!(3u32.wrapping_mul(PRIMES[2]), 2_416_379_583);
        assert_eq!(spatial_hash([1, 2, 3]), 2_892_625_372);
        assert_eq!(spatial_hash([0, 0, 0]), 0);
        assert_eq!(spatial_hash([7, 0, 0]), 7, "x enters unmultiplied");
        assert_eq!(spatial_hash([0, 1, 0]), 2_654_435_761);
        let hashed = LevelLayout { scale: 127.0, resolution: 128, entries: 1 << 19, offset: 0, dense: false };
        assert_eq!(hashed.index([1, 2, 3]), 128_476, "2892625372 mod 2¹⁹");
        assert_eq!(2_892_625_372u32 % (1 << 19), 2_892_625_372u32 & ((1 << 19) - 1));
    }

    #[test]
    fn dense_index_matches_hand_computed_values() {
        // res 17: (3, 5, 7) → 3 + 5·17 + 7·289 = 2111; entries 4920 (17³ = 4913 → next ×8).
        let dense = LevelLayout { scale: 15.0, resolution: 17, entries: 4920, offset: 0, dense: true };
        assert_eq!(dense.index([3, 5, 7]), 2111);
        // res 16, 4096 entries: a corner at x = res (the +0.5 offset reaches it) wraps:
        // 16 + 15·16 + 15·256 = 4096 → 0.
        let exact = LevelLayout { scale: 15.0, resolution: 16, entries: 4096, offset: 0, dense: true };
        assert_eq!(exact.index([16, 15, 15]), 0);
        assert_eq!(exact.index([15, 15, 15]), 4095);
    }

    #[test]
    fn layout_follows_tiny_cuda_nn() {
        let config = HashGridConfig::default();
        let layout = config.layout().unwrap();
        // b = (2048/16)^(1/15) = 2^(7/15).
        assert!((config.growth() - 2f64.powf(7.0 / 15.0)).abs() < 1e-12);
        // Level 0: scale 15, res 16, 4096 entries dense; level 1: 16·2^(7/15) − 1 = 21.1…, res 23,
        // 23³ = 12167 → 12168 entries, dense.
        assert_eq!((layout[0].scale, layout[0].resolution, layout[0].entries, layout[0].dense), (15.0, 16, 4096, true));
        assert!((layout[1].scale - (16.0 * 2f32.powf(7.0 / 15.0) - 1.0)).abs() < 1e-4);
        assert_eq!((layout[1].resolution, layout[1].entries, layout[1].offset), (23, 12168, 4096));
        // The finest: scale 2047, hashed, T entries.
        let last = layout[15];
        assert!((last.scale - 2047.0).abs() < 1e-2, "{}", last.scale);
        assert_eq!((last.resolution, last.entries, last.dense), (2048, 1 << 19, false));
        // Dense exactly while res³ fits in T: 80³ = 512000 ≤ 2¹⁹ = 524288 < 81³.
        for l in &layout {
            assert_eq!(l.dense, (l.resolution as u64).pow(3) <= 1 << 19);
        }
        assert_eq!(config.output_dim(), 32);
        let total = config.total_entries().unwrap();
        assert_eq!(total, layout.iter().map(|l| l.entries as usize).sum::<usize>());
    }

    #[test]
    fn bad_configs_are_named() {
        let ok = HashGridConfig::default();
        let err = |c: HashGridConfig| c.validate().unwrap_err().to_string();
        assert!(err(HashGridConfig { levels: 0, ..ok }).contains("levels = 0"));
        assert!(err(HashGridConfig { features_per_level: 3, ..ok }).contains("features_per_level = 3"));
        assert!(err(HashGridConfig { log2_table_size: 40, ..ok }).contains("log2_table_size = 40"));
        assert!(err(HashGridConfig { max_resolution: 8, ..ok }).contains("max_resolution 8 is below base_resolution 16"));
        assert!(err(HashGridConfig { base_resolution: 0, ..ok }).contains("base_resolution = 0"));
        let t = HashGridConfig::log2_of_table_size(3 << 17).unwrap_err().to_string();
        assert!(t.contains("393216 is not a power of two"), "{t}");
        assert_eq!(HashGridConfig::log2_of_table_size(1 << 17).unwrap(), 17);
        assert!(ok.layout().is_ok());
        assert!(HashGridConfig { levels: 0, ..ok }.layout().is_err());
    }

    #[test]
    fn bound_maps_its_corners_to_the_unit_cube() {
        let b = GridBound { min: [-1.5, 0.0, 2.0], max: [1.5, 1.0, 6.0], contraction: None };
        b.validate().unwrap();
        assert_eq!(b.to_unit([-1.5, 0.0, 2.0]), [0.0, 0.0, 0.0]);
        assert_eq!(b.to_unit([0.0, 0.25, 4.0]), [0.5, 0.25, 0.5]);
        assert!((b.to_unit([1.5, 1.0, 6.0])[0] - 1.0).abs() < 1e-6);
        let flat = GridBound { min: [0.0; 3], max: [1.0, 0.0, 1.0], contraction: None }.validate().unwrap_err().to_string();
        assert!(flat.contains("axis 1"), "{flat}");
        // Contracted: (2, −1, 0.5) → (1.5, −0.75, 0.375) → ((c + 2)/4) = (0.875, 0.3125, 0.59375).
        let c = GridBound::contracted(Contraction::Linf);
        c.validate().unwrap();
        assert_eq!(c.to_unit([2.0, -1.0, 0.5]), [0.875, 0.3125, 0.59375]);
        assert_eq!(c.to_unit([0.5, 0.0, -1.0]), [0.625, 0.5, 0.25], "the inner cube is not moved");
        let wrong = GridBound { contraction: Some(Contraction::Linf), ..GridBound::cube(1.5) }.validate().unwrap_err().to_string();
        assert!(wrong.contains("contracted grid covers [-2, 2]^3"), "{wrong}");
        // Files without the key read as uncontracted, and uncontracted ones are written without it.
        let old: GridBound = serde_json::from_str(r#"{"min":[-1,-1,-1],"max":[1,1,1]}"#).unwrap();
        assert_eq!(old, GridBound::cube(1.0));
        assert!(!serde_json::to_string(&old).unwrap().contains("contraction"));
        assert_eq!(serde_json::from_str::<GridBound>(&serde_json::to_string(&c).unwrap()).unwrap(), c);
    }

    #[test]
    fn config_round_trips_and_rejects_unknown_fields() {
        let c = HashGridConfig { levels: 8, features_per_level: 4, log2_table_size: 17, ..Default::default() };
        let json = serde_json::to_string(&c).unwrap();
        assert_eq!(serde_json::from_str::<HashGridConfig>(&json).unwrap(), c);
        assert!(serde_json::from_str::<HashGridConfig>(&json.replace("levels", "n_levels")).is_err());
    }
}
