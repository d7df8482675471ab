//! The hash table as a graph stores it (`grid.table`, `[rows, F]`), and back.
//!
//! The trained table ([`HashGrid::params`]) holds the levels in order, each `entries` rows.
//! The graph's table holds the same rows arranged for the lowering:
//! - **hashed levels first**, level j of them at row `j·T`: the offset is a multiple of T, so
//!   it is carried by the x term of the hash (`(j·T + a) ⊕ b ⊕ c = j·T + (a ⊕ b ⊕ c)` for
//!   a, b, c < T = 2ᵏ) and costs no operation;
//! - **dense levels after**, each padded to `res³ + res² + res + 1` rows whose row r holds the
//!   trained row `r mod entries`: a corner at coordinate `res` (the +0.5 offset reaches it)
//!   then needs no `Mod`, the wrap is in the table (≈ res² extra rows per dense level).
//!
//! Stored as float32, or float16 ([`TablePrecision::F16`]: half the bundle, cast to float32
//! after the lookup). The layout and precision are recorded in the model's metadata
//! ([`TABLE_KEY`]); graphs without it (written before) hold the trained layout in float32.

use half::f16;
use nerf_core::field::ngp::hash_grid::{HashGrid, HashGridConfig, LevelLayout};
pub use crate::options::TablePrecision;
use serde::{Deserialize, Serialize};

/// Metadata key holding the [`TableFormat`] (JSON).
pub const TABLE_KEY: &str = "nerf.grid_table";

/// The table's format, as [`TABLE_KEY`] records it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct TableFormat {
    /// 2: the arrangement of the module doc.
    pub layout: u32,
    /// How values are stored.
    pub precision: TablePrecision,
}

/// The layout of this module.
pub const LAYOUT: u32 = 2;

/// One level's place in the graph's table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GraphLevel {
    /// First row.
    pub offset: u64,
    /// Rows (T for a hashed level, the padded count for a dense one).
    pub rows: u64,
}

/// Rows of a dense level in the graph: every `x + y·res + z·res²` for coordinates ≤ res.
pub fn padded_dense_rows(level: &LevelLayout) -> u64 {
    let r = level.resolution as u64;
    r * r * r + r * r + r + 1
}

/// Each level's place in the graph's table (in level order), and the table's rows.
pub fn graph_levels(levels: &[LevelLayout]) -> (Vec<GraphLevel>, u64) {
    let mut places = vec![GraphLevel { offset: 0, rows: 0 }; levels.len()];
    let mut next = 0u64;
    for dense in [false, true] {
        for (place, level) in places.iter_mut().zip(levels).filter(|(_, l)| l.dense == dense) {
            let rows = if dense { padded_dense_rows(level) } else { level.entries as u64 };
            *place = GraphLevel { offset: next, rows };
            next += rows;
        }
    }
    (places, next)
}

/// The graph's table of `grid`, as float32 values `[rows, F]` (before any float16 rounding).
pub fn graph_table(grid: &HashGrid) -> Vec<f32> {
    let f = grid.config().features_per_level;
    let (places, rows) = graph_levels(grid.levels());
    let mut table = vec![0.0f32; rows as usize * f];
    for (level, place) in grid.levels().iter().zip(&places) {
        let trained = &grid.params()[level.offset as usize * f..(level.offset + level.entries) as usize * f];
        let out = &mut table[place.offset as usize * f..(place.offset + place.rows) as usize * f];
        for (r, row) in out.chunks_exact_mut(f).enumerate() {
            let src = r % level.entries as usize;
            row.copy_from_slice(&trained[src * f..(src + 1) * f]);
        }
    }
    table
}

/// The trained table from a graph's table in `format`, or why it does not fit `config`.
pub fn trained_table(config: &HashGridConfig, format: TableFormat, graph: &[f32]) -> Result<Vec<f32>, String> {
    if format.layout != LAYOUT {
        return Err(format!("{TABLE_KEY}: table layout {} is not known (this build reads layout {LAYOUT})", format.layout));
    }
    let levels = config.layout().map_err(|e| e.to_string())?;
    let f = config.features_per_level;
    let (places, rows) = graph_levels(&levels);
    if graph.len() as u64 != rows * f as u64 {
        return Err(format!("the table has {} values, the grid's layout needs {rows} rows × {f}", graph.len()));
    }
    let mut table = Vec::with_capacity(config.total_entries().map_err(|e| e.to_string())? * f);
    for (level, place) in levels.iter().zip(&places) {
        table.extend_from_slice(&graph[place.offset as usize * f..(place.offset as usize + level.entries as usize) * f]);
    }
    Ok(table)
}

/// float32 values as float16 bytes (round to nearest even).
pub fn f16_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|&v| f16::from_f32(v).to_le_bytes()).collect()
}

/// float16 bytes as float32 values, or `None` for an odd byte count.
pub fn f16_values(bytes: &[u8]) -> Option<Vec<f32>> {
    (bytes.len() % 2 == 0).then(|| bytes.chunks_exact(2).map(|b| f16::from_le_bytes([b[0], b[1]]).to_f32()).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> HashGrid {
        // Scales 3, 4.6, 6.9, 10 → resolutions 4, 6, 8, 11; T = 2⁸: 64 and 216 rows dense,
        // 512 and 1331 > 256 hashed.
        let config = HashGridConfig { levels: 4, features_per_level: 2, log2_table_size: 8, base_resolution: 4, max_resolution: 11 };
        let mut g = HashGrid::new(config, 1).unwrap();
        g.params_mut().iter_mut().enumerate().for_each(|(i, p)| *p = i as f32);
        g
    }

    #[test]
    fn hashed_levels_come_first_at_multiples_of_t_and_dense_ones_are_padded_with_their_wrap() {
        let g = grid();
        let res: Vec<u32> = g.levels().iter().map(|l| l.resolution).collect();
        let dense: Vec<bool> = g.levels().iter().map(|l| l.dense).collect();
        assert_eq!((res, dense), (vec![4, 6, 8, 11], vec![true, true, false, false]));
        let (places, rows) = graph_levels(g.levels());
        // Hashed levels 2 and 3 at rows 0 and 256; dense level 0 (4³ + 4² + 4 + 1 = 85 rows)
        // at 512, level 1 (216 + 36 + 6 + 1 = 259 rows) at 597.
        assert_eq!(places[2], GraphLevel { offset: 0, rows: 256 });
        assert_eq!(places[3], GraphLevel { offset: 256, rows: 256 });
        assert_eq!(places[0], GraphLevel { offset: 512, rows: 85 });
        assert_eq!(places[1], GraphLevel { offset: 597, rows: 259 });
        assert_eq!(rows, 856);
        let table = graph_table(&g);
        assert_eq!(table.len(), 856 * 2);
        // The params hold their own indices: graph row 512 + 70 is level 0's trained row
        // 70 mod 64 = 6, i.e. param 2·6; graph row 256 + 3 is level 3's row 3.
        let f = 2;
        assert_eq!(table[(512 + 70) * f], 12.0);
        assert_eq!(table[(256 + 3) * f + 1], ((g.levels()[3].offset as usize + 3) * f + 1) as f32);
        // And back.
        let format = TableFormat { layout: LAYOUT, precision: TablePrecision::F32 };
        assert_eq!(trained_table(g.config(), format, &table).unwrap(), g.params());
        let err = trained_table(g.config(), format, &table[1..]).unwrap_err();
        assert!(err.contains("values"), "{err}");
        let err = trained_table(g.config(), TableFormat { layout: 3, ..format }, &table).unwrap_err();
        assert!(err.contains("layout 3"), "{err}");
    }

    #[test]
    fn float16_round_trips_within_its_precision() {
        let v = [0.0, 1e-4, -0.37, 1.0, 65504.0];
        let back = f16_values(&f16_bytes(&v)).unwrap();
        for (a, b) in v.iter().zip(&back) {
            assert!((a - b).abs() <= a.abs() * 1e-3, "{a} → {b}");
        }
        assert!(f16_values(&[0, 1, 2]).is_none());
    }
}
