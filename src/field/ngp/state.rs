//! A hash grid's training state in one file (`grid.bin` in checkpoints): the table and its
//! sparse Adam moments and step counts.
//!
//! # File format (little-endian)
//! | bytes | content |
//! |---|---|
//! | 8 | magic `NERFHGS1` |
//! | 20 | `u32` L, F, log₂T, N_min, N_max |
//! | 8 | `u64` n, the table's parameter count (`total_entries · F`) |
//! | 4n each | `f32` table, `f32` first moments, `f32` second moments, `u32` step counts |

use super::adam::{SparseAdam, SparseAdamConfig};
use nerf_core::field::ngp::hash_grid::{HashGrid, HashGridConfig};
use nerf_core::error::{Error, Result};
use std::path::Path;

/// The table and its Adam state in a checkpoint directory.
pub const GRID_FILE: &str = "grid.bin";

/// The hash grid and its Adam state saved in `checkpoint` ([`GRID_FILE`]).
pub fn load_grid(checkpoint: &crate::run_dir::Checkpoint, config: &HashGridConfig, adam: SparseAdamConfig) -> crate::error::Result<(HashGrid, SparseAdam)> {
    let path = checkpoint.dir.join(GRID_FILE);
    let bytes = crate::run_dir::read(&path)?;
    Ok(state_from_bytes(&bytes, config, adam, &path)?)
}

const MAGIC: &[u8; 8] = b"NERFHGS1";
const HEADER_BYTES: usize = 36;

/// Serialise `grid` and its optimiser.
pub fn state_to_bytes(grid: &HashGrid, adam: &SparseAdam) -> Vec<u8> {
    let c = grid.config();
    let (first, second, steps) = adam.state();
    let n = grid.params().len();
    let mut out = Vec::with_capacity(HEADER_BYTES + 16 * n);
    out.extend_from_slice(MAGIC);
    for v in [c.levels as u32, c.features_per_level as u32, c.log2_table_size, c.base_resolution, c.max_resolution] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&(n as u64).to_le_bytes());
    for v in grid.params().iter().chain(first).chain(second) {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in steps {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Parse [`state_to_bytes`]' output for a grid of `config` (checked against the header before
/// anything table-sized is allocated); `path` only names the source in errors.
pub fn state_from_bytes(bytes: &[u8], config: &HashGridConfig, adam: SparseAdamConfig, path: &Path) -> Result<(HashGrid, SparseAdam)> {
    let bad = |problem: String| Error::invalid(path, problem);
    if bytes.len() < HEADER_BYTES || &bytes[..8] != MAGIC {
        return Err(bad("not a hash-grid state (missing NERFHGS1 header)".into()));
    }
    let word = |k: usize| u32::from_le_bytes(bytes[8 + 4 * k..12 + 4 * k].try_into().expect("4 bytes"));
    let header = [word(0), word(1), word(2), word(3), word(4)];
    let want = [config.levels as u32, config.features_per_level as u32, config.log2_table_size, config.base_resolution, config.max_resolution];
    if header != want {
        return Err(bad(format!("grid (L, F, log₂T, N_min, N_max) = {header:?}, the run's config says {want:?}")));
    }
    let n = u64::from_le_bytes(bytes[28..36].try_into().expect("8 bytes"));
    let expected = (config.total_entries()? * config.features_per_level) as u64;
    if n != expected {
        return Err(bad(format!("{n} table parameters, the grid needs {expected}")));
    }
    if bytes.len() as u64 != HEADER_BYTES as u64 + 16 * n {
        return Err(bad(format!("{} bytes, expected {} (truncated?)", bytes.len(), HEADER_BYTES as u64 + 16 * n)));
    }
    let n = n as usize;
    let words = |k: usize| bytes[HEADER_BYTES + 4 * n * k..HEADER_BYTES + 4 * n * (k + 1)].chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]);
    let floats = |k: usize| words(k).map(f32::from_le_bytes).collect::<Vec<f32>>();
    let grid = HashGrid::from_params(*config, floats(0))?;
    let steps = words(3).map(u32::from_le_bytes).collect();
    let adam = SparseAdam::from_state(adam, &grid, floats(1), floats(2), steps)?;
    Ok((grid, adam))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::field::ngp::hash_grid::HashGridGradient;

    #[test]
    fn round_trip_and_truncation() {
        let config = HashGridConfig { levels: 4, features_per_level: 2, log2_table_size: 10, base_resolution: 4, max_resolution: 32 };
        let mut grid = HashGrid::new(config, 3).unwrap();
        let mut adam = SparseAdam::new(SparseAdamConfig::default(), &grid);
        let mut grad = HashGridGradient::new(&grid);
        let points = [[0.2, 0.4, 0.6], [0.9, 0.1, 0.5]];
        grid.backward(&points, &vec![1.0; 2 * grid.output_dim()], &mut grad);
        adam.step(&mut grid, &mut grad);
        let bytes = state_to_bytes(&grid, &adam);
        let (g2, a2) = state_from_bytes(&bytes, &config, SparseAdamConfig::default(), Path::new("grid.bin")).unwrap();
        assert_eq!(g2.params(), grid.params());
        assert_eq!(a2.state(), adam.state());
        let err = state_from_bytes(&bytes[..bytes.len() - 4], &config, SparseAdamConfig::default(), Path::new("grid.bin")).unwrap_err().to_string();
        assert!(err.contains("grid.bin") && err.contains("truncated"), "{err}");
        let other = HashGridConfig { log2_table_size: 11, ..config };
        let err = state_from_bytes(&bytes, &other, SparseAdamConfig::default(), Path::new("grid.bin")).unwrap_err().to_string();
        assert!(err.contains("config"), "{err}");
    }
}
