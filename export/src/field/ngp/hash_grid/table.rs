//! The hash table as a graph stores it (`grid.table`, `[rows, F]`), and back.
//!
//! The row layout and the reading back live in [`nerf_bundle::ngp`] (the renderer reads them
//! too); writing the graph's table is here.

use half::f16;
use nerf_core::field::ngp::hash_grid::HashGrid;
pub use nerf_bundle::ngp::{GraphLevel, LAYOUT, TABLE_KEY, TableFormat, TablePrecision, graph_levels, padded_dense_rows, trained_table};

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
    use nerf_core::field::ngp::hash_grid::HashGridConfig;

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
