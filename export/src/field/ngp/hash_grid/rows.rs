//! The table rows of each point's 8 corners, `[L, N, 8]` int32, one group of levels at a time.
//!
//! Both groups start from the level-major cells `floor [Lg, N, 3]` (float, exact integers) and
//! end with rows of the graph's table ([`super::table`]); corner k has bit d of k as its offset
//! along axis d, as [`nerf_core::field::ngp::hash_grid`] orders them.
//! - **Dense levels**: `x + y·res + z·res²` is the same for all 8 corners up to a per-corner
//!   constant, so one `MatMul` with `[3, 8]` columns of strides gives it 8 wide (exact in
//!   float32: every value is an integer below 2²⁴), `Cast`, plus `[8]` constants (the corner's
//!   offsets and the level's first row). No `Mod`: the padded table holds the wrap.
//! - **Hashed levels**: per axis d a lookup table holds, for each level and cell c, the 8 corner
//!   terms `((c + bit_d(k)) · (p_d mod T)) mod T` already multiplied (the level's first row
//!   j·T added to the x terms); three `Gather`s of 8-wide int32 rows from tables of Σ res rows
//!   (≈ 230 KB each for the default grid: in cache) and the combination:
//!   - [`HashOps::Bitwise`]: two `BitwiseXor`s. Since T = 2ᵏ divides 2³², the terms taken mod T
//!     XOR to the u32 hash mod T, and the first row j·T has no bits below T.
//!   - [`HashOps::Portable`]: no bitwise operator and no int64. The tables hold each term's bits
//!     in chunks of [`CHUNK_BITS`], spread one bit per base-4 digit; the sum of three spread
//!     chunks has the count of ones of each bit position as its digits (≤ 3: no carry), so a
//!     parity table over the sums (16,384 entries per chunk, float32) gives the XOR of the
//!     chunk, already weighted by its place; a 0/1 `MatMul` sums the chunks (exact below 2²⁴),
//!     `Cast`, plus the level's first row.

use super::table::GraphLevel;
use super::{HashOps, int32_tensor, slice};
use crate::ExportError;
use crate::builder::{Builder, int_attribute};
use nerf_core::field::ngp::hash_grid::LevelLayout;
use nerf_core::field::ngp::hash_grid::config::PRIMES;

/// Bits per chunk of the portable XOR: sums of three spread chunks stay below 4⁷ = 16,384.
pub const CHUNK_BITS: u32 = 7;
const SPREAD_RANGE: i64 = 1 << (2 * CHUNK_BITS);
/// Integers float32 holds exactly.
const EXACT_F32: u64 = 1 << 24;

/// Rows `[Ld, N, 8]` of a group of dense levels from their cells `floor [Ld, N, 3]`.
pub(super) fn dense_rows(g: &mut Builder, floor: &str, levels: &[LevelLayout], places: &[GraphLevel]) -> Result<String, ExportError> {
    let lg = levels.len();
    let mut strides = Vec::with_capacity(lg * 3 * 8);
    let mut corners = Vec::with_capacity(lg * 8);
    for (level, place) in levels.iter().zip(places) {
        if place.rows > EXACT_F32 {
            return Err(ExportError::Unsupported(format!(
                "hash grid: a dense level of resolution {} has {} rows, more than float32 indexes exactly (2^24); use a smaller table (log2_table_size) or max_resolution",
                level.resolution, place.rows
            )));
        }
        let stride = |d: usize| (level.resolution as i64).pow(d as u32);
        for d in 0..3 {
            strides.extend(std::iter::repeat_n(stride(d) as f32, 8));
        }
        corners.extend((0..8).map(|k| place.offset as i64 + (0..3).map(|d| ((k >> d) & 1) * stride(d as usize)).sum::<i64>()));
    }
    let strides = g.f32_tensor("grid.dense.strides", &[lg, 3, 8], &strides);
    let local = g.node("MatMul", &[floor, &strides], "grid.dense.local", vec![]);
    let local = g.node("Cast", &[&local], "grid.dense.local_int", vec![int_attribute("to", crate::proto::data_type::INT32 as i64)]);
    let corners = int32_tensor(g, "grid.dense.corners", &[lg as i64, 1, 8], &corners)?;
    Ok(g.node("Add", &[&local, &corners], "grid.dense.rows", vec![]))
}

/// Rows `[Lh, N, 8]` of a group of hashed levels from their cells `floor [Lh, N, 3]`.
pub(super) fn hashed_rows(g: &mut Builder, floor: &str, levels: &[LevelLayout], places: &[GraphLevel], ops: HashOps, log2_t: u32) -> Result<String, ExportError> {
    let lg = levels.len() as i64;
    let t = 1i64 << log2_t;
    // Each level's first row in the axis tables: cells run over 0..res.
    let bases: Vec<i64> = levels.iter().scan(0i64, |next, l| Some(std::mem::replace(next, *next + l.resolution as i64))).collect();
    let rows_per_axis: i64 = levels.iter().map(|l| l.resolution as i64).sum();
    if rows_per_axis as u64 >= EXACT_F32 {
        return Err(ExportError::Unsupported(format!("hash grid: {rows_per_axis} cells per axis over the hashed levels, more than float32 indexes exactly")));
    }
    let base = g.f32_tensor("grid.hashed.cell_base", &[levels.len(), 1, 1], &bases.iter().map(|&b| b as f32).collect::<Vec<_>>());
    let cell = g.node("Add", &[floor, &base], "grid.hashed.cell_rows_f", vec![]);
    let cell = g.node("Cast", &[&cell], "grid.hashed.cell_rows", vec![int_attribute("to", crate::proto::data_type::INT32 as i64)]);
    // The corner term of cell c and bit b on axis d, mod T.
    let term = |d: usize, c: i64, b: i64| ((c + b) * (PRIMES[d] as i64 % t)) % t;
    let chunks = log2_t.div_ceil(CHUNK_BITS) as i64;
    let width = match ops {
        HashOps::Bitwise => 8,
        HashOps::Portable => 8 * chunks,
    };
    if ops == HashOps::Portable && (t as u64 > EXACT_F32 || places.iter().any(|p| p.offset + p.rows > i32::MAX as u64)) {
        return Err(ExportError::Unsupported(format!("hash grid: the portable lowering needs T ≤ 2^24 (this grid has 2^{log2_t})")));
    }
    let mut gathered = Vec::new();
    for d in 0..3usize {
        let mut table = Vec::with_capacity((rows_per_axis * width) as usize);
        for (level, place) in levels.iter().zip(places) {
            for c in 0..level.resolution as i64 {
                for k in 0..8i64 {
                    let value = term(d, c, (k >> d) & 1);
                    match ops {
                        HashOps::Bitwise => table.push(value + if d == 0 { place.offset as i64 } else { 0 }),
                        HashOps::Portable => table.extend((0..chunks).map(|i| spread((value >> (i * CHUNK_BITS as i64)) & ((1 << CHUNK_BITS) - 1)) + if d == 0 { i * SPREAD_RANGE } else { 0 })),
                    }
                }
            }
        }
        let table = int32_tensor(g, &format!("grid.hashed.axis{d}"), &[rows_per_axis, width], &table)?;
        let c = slice(g, &cell, (d as i64, d as i64 + 1), 2, &format!("grid.hashed.cell{d}"));
        gathered.push(g.node("Gather", &[&table, &c], &format!("grid.hashed.terms{d}"), vec![int_attribute("axis", 0)]));
    }
    let shape = g.i64_constant(&format!("grid.hashed.shape{width}"), &[lg, -1, width]);
    match ops {
        HashOps::Bitwise => {
            let x = g.node("BitwiseXor", &[&gathered[0], &gathered[1]], "grid.hashed.xor01", vec![]);
            let x = g.node("BitwiseXor", &[&x, &gathered[2]], "grid.hashed.xor", vec![]);
            Ok(g.node("Reshape", &[&x, &shape], "grid.hashed.rows", vec![]))
        }
        HashOps::Portable => {
            let s = g.node("Add", &[&gathered[0], &gathered[1]], "grid.hashed.spread01", vec![]);
            let s = g.node("Add", &[&s, &gathered[2]], "grid.hashed.spread", vec![]);
            let parity: Vec<f32> = (0..chunks).flat_map(|i| (0..SPREAD_RANGE).map(move |v| (odd_digits(v) << (i * CHUNK_BITS as i64)) as f32)).collect();
            let parity = g.f32_tensor("grid.hashed.parity", &[parity.len()], &parity);
            let xored = g.node("Gather", &[&parity, &s], "grid.hashed.xor_chunks", vec![int_attribute("axis", 0)]);
            let xored = g.node("Reshape", &[&xored, &shape], "grid.hashed.xor_chunks_flat", vec![]);
            let mut sum = vec![0.0f32; (8 * chunks * 8) as usize];
            for k in 0..8 {
                for i in 0..chunks {
                    sum[((k * chunks + i) * 8 + k) as usize] = 1.0;
                }
            }
            let sum = g.f32_tensor("grid.hashed.chunk_sum", &[(8 * chunks) as usize, 8], &sum);
            let local = g.node("MatMul", &[&xored, &sum], "grid.hashed.local_f", vec![]);
            let local = g.node("Cast", &[&local], "grid.hashed.local", vec![int_attribute("to", crate::proto::data_type::INT32 as i64)]);
            let offsets = int32_tensor(g, "grid.hashed.offsets", &[lg, 1, 1], &places.iter().map(|p| p.offset as i64).collect::<Vec<_>>())?;
            Ok(g.node("Add", &[&local, &offsets], "grid.hashed.rows", vec![]))
        }
    }
}

/// The bits of `v` (< 2^CHUNK_BITS) one per base-4 digit.
fn spread(v: i64) -> i64 {
    (0..CHUNK_BITS as i64).map(|b| ((v >> b) & 1) << (2 * b)).sum()
}

/// The parities of `v`'s base-4 digits as bits: the XOR of the chunks whose spreads sum to `v`.
fn odd_digits(v: i64) -> i64 {
    (0..CHUNK_BITS as i64).map(|b| (((v >> (2 * b)) & 3) & 1) << b).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_chunks_sum_to_digits_whose_parities_are_the_xor() {
        for (a, b, c) in [(0b1010101, 0b0110011, 0b1111111), (0, 0, 0), (127, 0, 1), (5, 9, 100)] {
            let sum = spread(a) + spread(b) + spread(c);
            assert!(sum < SPREAD_RANGE);
            assert_eq!(odd_digits(sum), a ^ b ^ c, "{a} {b} {c}");
        }
        // By hand: spread(0b101) = 4⁰ + 4² = 17; 17 + 17 + spread(1) = 35 = 2·16 + 0·4 + 3:
        // digits 3, 0, 2 → parities 1, 0, 0.
        assert_eq!(spread(0b101), 17);
        assert_eq!(odd_digits(35), 1);
    }
}
