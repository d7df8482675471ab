//! The hash-grid encoding and the degree-4 spherical harmonics as standard ONNX operators, so a
//! hash-grid field runs in any ONNX runtime with its table as one initializer.
//!
//! # The encoding, op by op (`points [N, 3]` → `features [N, L·F]`)
//! Laid out for onnxruntime's CPU kernels (measured with its profiler): level-major
//! intermediates so per-level constants broadcast over whole levels, int32 indices, no `Where`,
//! full shapes where a broadcast would be tiny, and products as `MatMul`s.
//! 1. `Sub` the bound's min, `Mul` by its f32 scale, `Clip` to [0, 1]: the unit-cube point,
//!    the same f32 operations as [`GridBound::to_unit`] and the clamp in
//!    [`nerf_core::field::ngp::hash_grid::corners`].
//! 2. `Unsqueeze` to `[1, N, 3]`, `Mul` by the level scales `[L, 1, 1]`, `Add` 0.5: positions
//!    `[L, N, 3]`; `Floor`, `Sub` (fractions), `Cast` to int32 (cells; int64 for grids too wide
//!    for it, [`IndexType`]).
//! 3. Rows, `[L, N, 8]`, for the dense levels (a prefix) and the hashed ones as two groups: per
//!    axis d, corner coordinates `cell_d + bit_d(k)` times the level's stride (dense: 1, res,
//!    res²; hashed: the primes 1, 2654435761, 805459861 taken mod T). Dense: the sum `Mod` the
//!    level's entries; hashed: `BitwiseXor` of the three terms, `BitwiseAnd` T − 1. Since
//!    T = 2ᵏ divides 2³², `(x·p mod 2³²) mod T = (x·(p mod T)) mod T` and XOR commutes with
//!    `mod 2ᵏ`: the u32 hash mod T, with every product below 2³¹. Plus the level's offset;
//!    `Concat` the groups.
//! 4. Weights: per axis a `MatMul` of `[frac, 1 − frac]` with a 0/1 matrix picks `frac_d` or
//!    `1 − frac_d` for each corner (one value plus exact zeros), `[L, N, 8]`; multiplied x·y·z
//!    as tiny-cuda-nn does; repeated for the F features by another 0/1 `MatMul`, `[L, N, 8·F]`.
//! 5. `Gather` the rows of the table `[entries, F]` → `[L, N, 8, F]`, `Reshape` to
//!    `[L, N, 8·F]`, `Mul` by the weights, `MatMul` with a 0/1 matrix `[8·F, F]` (the sum over
//!    corners), `Transpose` to `[N, L, F]`, `Reshape` to `[N, L·F]` (level-major per point, as
//!    the Rust encoding).
//!
//! # GPU consumers
//! `BitwiseXor` and `BitwiseAnd` need opset 18. onnxruntime's CPU provider implements them for
//! int32/int64, but its CUDA provider has no kernels for them: a CUDA session still loads and
//! computes the right values, but places those nodes on the CPU, so every batch copies the
//! `[L, N, 8]` hash terms (int32 for the default grids) to the host and the indices back
//! (≈ 3·N·L·8·4 bytes each way), which costs far more than the lookups themselves. [`HashOps::Arithmetic`] writes the
//! same hash without any bitwise operator: each term's low k = log₂T bits are extracted with
//! `Div` by 2^j and `Mod` 2, the XOR of three bits is their sum `Mod` 2, and the bits are
//! weighted back by 2^j and summed. It runs at opset 17, with only `Div`, `Mod`, `Add`, `Mul`,
//! `ReduceSum`, `Where` on integers, at the price of k× the memory for the index computation
//! (`[N, L, 8, k]`): render in smaller batches. It computes the same values as the
//! bitwise graph in onnxruntime's CPU provider (tested); whether the CUDA provider runs every
//! one of its nodes on the GPU was not checked here (no GPU, and its kernel list not read).

use crate::ExportError;
use crate::builder::{Builder, OPSETS, int_attribute, ints_attribute, model_proto, value_info};
use crate::proto::*;
use nerf_core::field::ngp::hash_grid::{GridBound, HashGrid};
use nerf_core::field::ngp::spherical_harmonics::{SH4_CONSTANTS, SH4_DIM};

/// How the spatial hash's XOR and `mod T` are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum HashOps {
    /// `BitwiseXor` and `BitwiseAnd` (opset ≥ 18).
    #[default]
    Bitwise,
    /// Bit extraction with `Div`/`Mod`/`Add` (opset ≥ 17, no bitwise operator; k× index memory).
    Arithmetic,
}

impl HashOps {
    /// The lowest opset this lowering needs.
    pub const fn min_opset(self) -> i64 {
        match self {
            HashOps::Bitwise => 18,
            HashOps::Arithmetic => 17,
        }
    }
}

/// Metadata key holding the grid's configuration (JSON).
pub const GRID_KEY: &str = "nerf.hash_grid";
/// Metadata key holding the grid's bound (JSON).
pub const BOUND_KEY: &str = "nerf.grid_bound";

/// Check an opset for a hash-grid graph.
pub fn check_opset(opset: i64, ops: HashOps) -> Result<(), ExportError> {
    if !OPSETS.contains(&opset) || opset < ops.min_opset() {
        return Err(ExportError::Unsupported(format!(
            "opset {opset}: the hash grid with {ops:?} operators needs opset {}–{}",
            ops.min_opset().max(*OPSETS.start()),
            OPSETS.end()
        )));
    }
    Ok(())
}

/// A graph of the two encodings alone: inputs `points`, `viewdirs` `[N, 3]`, outputs
/// `features [N, L·F]` (the hash grid of `points` in `bound`) and `sh [N, 16]` (of `viewdirs`).
/// For parity checks, and for consumers that run the heads elsewhere.
pub fn compile_encodings(grid: &HashGrid, bound: &GridBound, ops: HashOps, opset: i64) -> Result<ModelProto, ExportError> {
    check_opset(opset, ops)?;
    bound.validate().map_err(|e| ExportError::Network(e.to_string()))?;
    let mut g = Builder::default();
    let features = lower_hash_grid(&mut g, "points", grid, bound, ops);
    g.unary("Identity", &features, "features");
    let sh = lower_sh4(&mut g, "viewdirs");
    g.unary("Identity", &sh, "sh");
    let width = grid.output_dim() as i64;
    let graph = GraphProto {
        node: g.nodes,
        name: "encodings".into(),
        initializer: g.initializers,
        doc_string: format!("Hash-grid encoding ({} levels × {} features) of points and degree-4 spherical harmonics of view directions.", grid.config().levels, grid.config().features_per_level),
        input: vec![value_info(("points", 3), "World positions, float32 [N, 3]."), value_info(("viewdirs", 3), "Unit view directions, float32 [N, 3].")],
        output: vec![
            value_info(("features", width), "Hash-grid features, float32 [N, L·F], level-major."),
            value_info(("sh", SH4_DIM as i64), "Spherical harmonics of degree 4, float32 [N, 16]."),
        ],
        value_info: vec![],
    };
    Ok(model(graph, opset, grid, bound))
}

/// The model around `graph`, with the grid and bound in the metadata.
pub(crate) fn model(graph: GraphProto, opset: i64, grid: &HashGrid, bound: &GridBound) -> ModelProto {
    let props = vec![
        (GRID_KEY.to_string(), serde_json::to_string(grid.config()).expect("a config serialises")),
        (BOUND_KEY.to_string(), serde_json::to_string(bound).expect("a bound serialises")),
    ];
    model_proto(graph, opset, "A hash-grid radiance field compiled by nerf-rs.", props)
}

fn tensor(g: &mut Builder, name: &str, dims: &[i64], data_type: i32, raw_data: Vec<u8>) -> String {
    g.initializers.push(TensorProto { dims: dims.to_vec(), data_type, name: name.into(), raw_data, ..Default::default() });
    name.to_string()
}

/// The integer type of the index computation: int32 (half the traffic of int64) wherever every
/// intermediate fits, which holds for the default grids; int64 otherwise.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IndexType {
    /// Every corner term, dense sum and row below 2³¹.
    Int32,
    /// Wider grids.
    Int64,
}

impl IndexType {
    /// The narrowest type that holds `grid`'s intermediates: corner coordinates up to the
    /// resolution times a stride (res, res² or a prime mod T, all < T), their dense sums, and
    /// the rows of the whole table.
    pub fn for_grid(grid: &HashGrid) -> Self {
        let widest = grid
            .levels()
            .iter()
            .map(|v| {
                let c = v.resolution as u64 + 1;
                let stride = if v.dense { c * c } else { v.entries as u64 };
                c * stride + c * c + c + (v.offset + v.entries) as u64
            })
            .max()
            .unwrap_or(0);
        if widest < 1 << 31 { IndexType::Int32 } else { IndexType::Int64 }
    }

    fn data_type(self) -> i32 {
        match self {
            IndexType::Int32 => data_type::INT32,
            IndexType::Int64 => data_type::INT64,
        }
    }

    /// An initializer of this type (`values` fit: they are strides, masks and offsets).
    fn tensor(self, g: &mut Builder, name: &str, dims: &[i64], values: &[i64]) -> String {
        let raw = match self {
            IndexType::Int32 => values.iter().flat_map(|&v| i32::try_from(v).expect("checked by for_grid").to_le_bytes()).collect(),
            IndexType::Int64 => values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        };
        tensor(g, name, dims, self.data_type(), raw)
    }
}

fn f32_scalar(g: &mut Builder, name: &str, value: f32) -> String {
    g.f32_tensor(name, &[], &[value])
}

/// Indices `[start, end)` of `input` along `axis`.
pub(crate) fn slice(g: &mut Builder, input: &str, (start, end): (i64, i64), axis: i64, output: &str) -> String {
    let s = g.i64_constant(&format!("index.{start}"), &[start]);
    let e = g.i64_constant(&format!("index.{end}"), &[end]);
    let a = g.i64_constant(&format!("index.{axis}"), &[axis]);
    g.node("Slice", &[input, &s, &e, &a], output, vec![])
}

/// The hash-grid encoding of world points `input [N, 3]` → `[N, L·F]` (module doc).
pub(crate) fn lower_hash_grid(g: &mut Builder, input: &str, grid: &HashGrid, bound: &GridBound, ops: HashOps) -> String {
    let levels = grid.levels();
    let l = levels.len() as i64;
    let f = grid.config().features_per_level as i64;
    // 1. Unit cube.
    let min = g.f32_tensor("grid.bound_min", &[3], &bound.min);
    let scale = g.f32_tensor("grid.bound_scale", &[3], &bound.scale());
    let shifted = g.node("Sub", &[input, &min], "grid.shifted", vec![]);
    let unit = g.node("Mul", &[&shifted, &scale], "grid.unit", vec![]);
    let zero = f32_scalar(g, "grid.zero", 0.0);
    let one = f32_scalar(g, "grid.one", 1.0);
    let clipped = g.node("Clip", &[&unit, &zero, &one], "grid.clipped", vec![]);
    // 2. Positions, cells, fractions per level, level-major [L, N, 3]: every per-level constant
    //    then broadcasts over a whole level's points at once.
    let axes0 = g.i64_constant("axes.0", &[0]);
    let u = g.node("Unsqueeze", &[&clipped, &axes0], "grid.unsqueezed", vec![]);
    let scales: Vec<f32> = levels.iter().map(|v| v.scale).collect();
    let scales = g.f32_tensor("grid.level_scales", &[levels.len(), 1, 1], &scales);
    let scaled = g.node("Mul", &[&u, &scales], "grid.scaled", vec![]);
    let half = f32_scalar(g, "grid.half", 0.5);
    let pos = g.node("Add", &[&scaled, &half], "grid.pos", vec![]);
    let floor = g.unary("Floor", &pos, "grid.floor");
    let frac = g.node("Sub", &[&pos, &floor], "grid.frac", vec![]);
    let one_minus = g.node("Sub", &[&one, &frac], "grid.one_minus_frac", vec![]);
    let index = IndexType::for_grid(grid);
    let cell = g.node("Cast", &[&floor], "grid.cell", vec![int_attribute("to", index.data_type() as i64)]);
    // 3. Rows of the table, [L, N, 8]: dense levels (a prefix: resolutions grow with the level)
    //    and hashed ones as two groups, each computing only its own index.
    let bits: Vec<String> = (0..3).map(|d| index.tensor(g, &format!("grid.corner_bits{d}"), &[8], &(0..8).map(|k| (k >> d) & 1).collect::<Vec<i64>>())).collect();
    let n_dense = levels.iter().take_while(|v| v.dense).count();
    let groups: Vec<(usize, usize)> = [(0, n_dense), (n_dense, levels.len())].into_iter().filter(|(a, b)| a < b).collect();
    let mut group_rows = Vec::new();
    for &(start, end) in &groups {
        let group = &levels[start..end];
        let dense = group[0].dense;
        let tag = if dense { "grid.dense" } else { "grid.hashed" };
        let cell = if groups.len() == 1 { cell.clone() } else { slice(g, &cell, (start as i64, end as i64), 0, &format!("{tag}.cell")) };
        let per_level = |v: &dyn Fn(&nerf_core::field::ngp::hash_grid::LevelLayout) -> i64| group.iter().map(v).collect::<Vec<i64>>();
        let lg = group.len() as i64;
        let mut terms = Vec::new();
        for d in 0..3i64 {
            let c = slice(g, &cell, (d, d + 1), 2, &format!("{tag}.cell{d}"));
            let coord = g.node("Add", &[&c, &bits[d as usize]], &format!("{tag}.corner{d}"), vec![]);
            terms.push(if d == 0 {
                coord // stride 1 for dense and hashed levels alike
            } else {
                // Dense: res^d. Hashed: the prime taken mod T (T = 2ᵏ divides 2³², so the hash's
                // low k bits are unchanged, and the products stay below 2³¹, see [`IndexType`]).
                let stride = per_level(&|v| {
                    if dense { (v.resolution as i64).pow(d as u32) } else { (nerf_core::field::ngp::hash_grid::config::PRIMES[d as usize] % v.entries) as i64 }
                });
                let stride = index.tensor(g, &format!("{tag}.stride{d}"), &[lg, 1, 1], &stride);
                g.node("Mul", &[&coord, &stride], &format!("{tag}.term{d}"), vec![])
            });
        }
        let local = if dense {
            let sum01 = g.node("Add", &[&terms[0], &terms[1]], &format!("{tag}.sum01"), vec![]);
            let sum = g.node("Add", &[&sum01, &terms[2]], &format!("{tag}.sum"), vec![]);
            let entries = index.tensor(g, &format!("{tag}.entries"), &[lg, 1, 1], &per_level(&|v| v.entries as i64));
            g.node("Mod", &[&sum, &entries], &format!("{tag}.index"), vec![])
        } else {
            match ops {
                HashOps::Bitwise => {
                    let x01 = g.node("BitwiseXor", &[&terms[0], &terms[1]], &format!("{tag}.xor01"), vec![]);
                    let x = g.node("BitwiseXor", &[&x01, &terms[2]], &format!("{tag}.xor"), vec![]);
                    let mask = index.tensor(g, &format!("{tag}.mask"), &[lg, 1, 1], &per_level(&|v| v.entries as i64 - 1));
                    g.node("BitwiseAnd", &[&x, &mask], &format!("{tag}.index"), vec![])
                }
                HashOps::Arithmetic => xor_low_bits(g, &terms, grid.config().log2_table_size, index),
            }
        };
        let offsets = index.tensor(g, &format!("{tag}.offsets"), &[lg, 1, 1], &per_level(&|v| v.offset as i64));
        group_rows.push(g.node("Add", &[&local, &offsets], &format!("{tag}.rows"), vec![]));
    }
    let rows = if group_rows.len() == 1 {
        group_rows.pop().expect("one group")
    } else {
        g.node("Concat", &[&group_rows[0], &group_rows[1]], "grid.rows", vec![int_attribute("axis", 0)])
    };
    // 4. Trilinear weights, [L, N, 8].
    // Each axis's weight for each corner, frac_d where the corner's bit d is set, else 1 − frac_d,
    // as a MatMul of [frac, 1 − frac] with a 0/1 selection matrix [6, 8] per axis (each output sums
    // one value and five exact zeros: the same values as selecting, without Where).
    let both = g.node("Concat", &[&frac, &one_minus], "grid.frac_both", vec![int_attribute("axis", 2)]);
    let fu = f as usize;
    let weights: Vec<String> = (0..3usize)
        .map(|d| {
            let mut select = vec![0.0f32; 6 * 8];
            for k in 0..8usize {
                let row = if (k >> d) & 1 == 1 { d } else { 3 + d };
                select[row * 8 + k] = 1.0;
            }
            let select = g.f32_tensor(&format!("grid.corner_select{d}"), &[6, 8], &select);
            g.node("MatMul", &[&both, &select], &format!("grid.weight{d}"), vec![])
        })
        .collect();
    let wxy = g.node("Mul", &[&weights[0], &weights[1]], "grid.weight01", vec![]);
    let weight8 = g.node("Mul", &[&wxy, &weights[2]], "grid.weight8", vec![]);
    // Each corner's weight repeated for its F features ([L, N, 8·F], a 0/1 MatMul: exact), so
    // the weighting below multiplies full shapes.
    let mut repeat = vec![0.0f32; 8 * 8 * fu];
    for k in 0..8 {
        for j in 0..fu {
            repeat[k * 8 * fu + k * fu + j] = 1.0;
        }
    }
    let repeat = g.f32_tensor("grid.weight_repeat", &[8, 8 * fu], &repeat);
    let weight = g.node("MatMul", &[&weight8, &repeat], "grid.weight", vec![]);
    // 5. Lookup, weighting, sum over corners.
    let total = grid.params().len() / f as usize;
    let table = g.f32_tensor("grid.table", &[total, f as usize], grid.params());
    let values = g.node("Gather", &[&table, &rows], "grid.values", vec![int_attribute("axis", 0)]);
    // [L, N, 8, F] → [L, N, 8·F], weighted, then summed over the corners per feature by a
    // MatMul with a 0/1 matrix [8·F, F].
    let flat_shape = g.i64_constant("grid.values_flat_shape", &[l, -1, 8 * f]);
    let flat = g.node("Reshape", &[&values, &flat_shape], "grid.values_flat", vec![]);
    let weighted = g.node("Mul", &[&flat, &weight], "grid.weighted", vec![]);
    let mut sum = vec![0.0f32; 8 * fu * fu];
    for k in 0..8 {
        for j in 0..fu {
            sum[(k * fu + j) * fu + j] = 1.0;
        }
    }
    let sum = g.f32_tensor("grid.corner_sum", &[8 * fu, fu], &sum);
    let summed = g.node("MatMul", &[&weighted, &sum], "grid.summed", vec![]);
    // [L, N, F] → [N, L, F] → [N, L·F], level-major per point as the Rust encoding.
    let point_major = g.node("Transpose", &[&summed], "grid.point_major", vec![ints_attribute("perm", &[1, 0, 2])]);
    let shape = g.i64_constant("grid.output_shape", &[0, l * f]);
    g.node("Reshape", &[&point_major, &shape], "grid.features", vec![])
}

/// `(t₀ ⊕ t₁ ⊕ t₂) mod 2^k` for non-negative integer `[N, L, 8]` terms, without bitwise operators:
/// bit j of each term is `(t / 2^j) mod 2`, the XOR of three bits is their sum mod 2.
fn xor_low_bits(g: &mut Builder, terms: &[String], k: u32, index: IndexType) -> String {
    let powers: Vec<i64> = (0..k).map(|j| 1i64 << j).collect();
    let powers = index.tensor(g, "grid.bit_values", &[k as i64], &powers);
    let two = index.tensor(g, "grid.two", &[], &[2]);
    let axes3 = g.i64_constant("axes.3", &[3]);
    let mut bit_sum: Option<String> = None;
    for (d, t) in terms.iter().enumerate() {
        let tu = g.node("Unsqueeze", &[t, &axes3], &format!("grid.term{d}_unsqueezed"), vec![]);
        let shifted = g.node("Div", &[&tu, &powers], &format!("grid.term{d}_shifted"), vec![]);
        let bits = g.node("Mod", &[&shifted, &two], &format!("grid.term{d}_bits"), vec![]);
        bit_sum = Some(match bit_sum {
            None => bits,
            Some(s) => g.node("Add", &[&s, &bits], &format!("grid.bit_sum{d}"), vec![]),
        });
    }
    let xor_bits = g.node("Mod", &[&bit_sum.expect("three terms"), &two], "grid.xor_bits", vec![]);
    let valued = g.node("Mul", &[&xor_bits, &powers], "grid.xor_valued", vec![]);
    g.node("ReduceSum", &[&valued, &axes3], "grid.hash_index", vec![int_attribute("keepdims", 0)])
}

/// The 16 spherical harmonics of unit directions `input [N, 3]` → `[N, 16]`, the operations of
/// [`nerf_core::field::ngp::spherical_harmonics::sh4`] in the same order.
pub(crate) fn lower_sh4(g: &mut Builder, input: &str) -> String {
    let [x, y, z] = [0, 1, 2].map(|d| slice(g, input, (d, d + 1), 1, &format!("sh.{}", ["x", "y", "z"][d as usize])));
    let c: Vec<String> = SH4_CONSTANTS.iter().enumerate().map(|(i, &v)| f32_scalar(g, &format!("sh.c{i}"), v)).collect();
    let neg: Vec<String> = [1, 2].iter().map(|&i| f32_scalar(g, &format!("sh.neg_c{i}"), -SH4_CONSTANTS[i])).collect();
    let k = |g: &mut Builder, v: f32, name: &str| f32_scalar(g, name, v);
    let (m3, one, five, three) = (k(g, -3.0, "sh.minus3"), k(g, 1.0, "sh.one"), k(g, 5.0, "sh.five"), k(g, 3.0, "sh.three"));
    let mul = |g: &mut Builder, a: &str, b: &str, out: &str| g.node("Mul", &[a, b], &format!("sh.{out}"), vec![]);
    let xy = mul(g, &x, &y, "xy");
    let yz = mul(g, &y, &z, "yz");
    let xz = mul(g, &x, &z, "xz");
    let x2 = mul(g, &x, &x, "x2");
    let y2 = mul(g, &y, &y, "y2");
    let z2 = mul(g, &z, &z, "z2");
    // Band 0: the constant, one per row.
    let shape = g.node("Shape", &[&x], "sh.row_shape", vec![]);
    let c0 = g.node("Expand", &[&c[0], &shape], "sh.0", vec![]);
    let o1 = mul(g, &neg[0], &y, "1");
    let o2 = mul(g, &c[1], &z, "2");
    let o3 = mul(g, &neg[0], &x, "3");
    let o4 = mul(g, &c[2], &xy, "4");
    let o5 = mul(g, &neg[1], &yz, "5");
    let c3z2 = mul(g, &c[3], &z2, "c3z2");
    let o6 = g.node("Sub", &[&c3z2, &c[4]], "sh.6", vec![]);
    let o7 = mul(g, &neg[1], &xz, "7");
    let c5x2 = mul(g, &c[5], &x2, "c5x2");
    let c5y2 = mul(g, &c[5], &y2, "c5y2");
    let o8 = g.node("Sub", &[&c5x2, &c5y2], "sh.8", vec![]);
    // −3x² + y², 1 − 5z², 5z² − 3, x² − y², −x² + 3y².
    let m3x2 = mul(g, &m3, &x2, "m3x2");
    let p9 = g.node("Add", &[&m3x2, &y2], "sh.p9", vec![]);
    let five_z2 = mul(g, &five, &z2, "five_z2");
    let p11 = g.node("Sub", &[&one, &five_z2], "sh.p11", vec![]);
    let p12 = g.node("Sub", &[&five_z2, &three], "sh.p12", vec![]);
    let p14 = g.node("Sub", &[&x2, &y2], "sh.p14", vec![]);
    let neg_x2 = g.unary("Neg", &x2, "sh.neg_x2");
    let three_y2 = mul(g, &three, &y2, "three_y2");
    let p15 = g.node("Add", &[&neg_x2, &three_y2], "sh.p15", vec![]);
    let cxp = |g: &mut Builder, ci: usize, v: &str, p: &str, out: &str| {
        let cv = g.node("Mul", &[&c[ci], v], &format!("sh.c{ci}_{out}"), vec![]);
        g.node("Mul", &[&cv, p], &format!("sh.{out}"), vec![])
    };
    let o9 = cxp(g, 6, &y, &p9, "9");
    let o10 = cxp(g, 7, &xy, &z, "10");
    let o11 = cxp(g, 8, &y, &p11, "11");
    let o12 = cxp(g, 9, &z, &p12, "12");
    let o13 = cxp(g, 8, &x, &p11, "13");
    let o14 = cxp(g, 10, &z, &p14, "14");
    let o15 = cxp(g, 6, &x, &p15, "15");
    let all = [&c0, &o1, &o2, &o3, &o4, &o5, &o6, &o7, &o8, &o9, &o10, &o11, &o12, &o13, &o14, &o15];
    let all: Vec<&str> = all.iter().map(|s| s.as_str()).collect();
    g.concat(&all, "sh.output")
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::field::ngp::hash_grid::HashGridConfig;

    #[test]
    fn index_type_is_int32_for_the_default_grid_and_widens_when_products_could_overflow() {
        let default = HashGrid::new(HashGridConfig::default(), 1).unwrap();
        assert_eq!(IndexType::for_grid(&default), IndexType::Int32);
        // T = 2²² with coordinates up to 4097: 4097 · (2²² − 1) > 2³¹.
        let wide = HashGridConfig { levels: 2, log2_table_size: 22, max_resolution: 4096, ..HashGridConfig::default() };
        assert_eq!(IndexType::for_grid(&HashGrid::new(wide, 1).unwrap()), IndexType::Int64);
    }

    fn grid() -> HashGrid {
        HashGrid::new(HashGridConfig { levels: 4, features_per_level: 2, log2_table_size: 9, base_resolution: 4, max_resolution: 17 }, 1).unwrap()
    }

    #[test]
    fn graph_names_and_opsets() {
        let g = grid();
        let model = compile_encodings(&g, &GridBound::cube(1.5), HashOps::Bitwise, 18).unwrap();
        let graph = model.graph.as_ref().unwrap();
        let names: Vec<&str> = graph.input.iter().chain(&graph.output).map(|v| v.name.as_str()).collect();
        assert_eq!(names, ["points", "viewdirs", "features", "sh"]);
        let ops: Vec<&str> = graph.node.iter().map(|n| n.op_type.as_str()).collect();
        assert!(ops.contains(&"BitwiseXor") && ops.contains(&"BitwiseAnd") && ops.contains(&"Gather"));
        let mut init: Vec<&str> = graph.initializer.iter().map(|t| t.name.as_str()).collect();
        init.sort();
        let n = init.len();
        init.dedup();
        assert_eq!(init.len(), n, "no initializer twice");
        let table = graph.initializer.iter().find(|t| t.name == "grid.table").unwrap();
        assert_eq!(table.dims, [(g.params().len() / 2) as i64, 2]);
        assert!(model.metadata_props.iter().any(|p| p.key == GRID_KEY));
        let arithmetic = compile_encodings(&g, &GridBound::cube(1.5), HashOps::Arithmetic, 17).unwrap();
        assert!(!arithmetic.graph.unwrap().node.iter().any(|n| n.op_type.starts_with("Bitwise")));
        let err = compile_encodings(&g, &GridBound::cube(1.5), HashOps::Bitwise, 17).unwrap_err().to_string();
        assert!(err.contains("opset 17") && err.contains("18"), "{err}");
        let err = compile_encodings(&g, &GridBound::cube(0.0), HashOps::Bitwise, 18).unwrap_err().to_string();
        assert!(err.contains("axis 0"), "{err}");
    }
}
