//! The hash-grid encoding and the degree-4 spherical harmonics as standard ONNX operators, so a
//! hash-grid field runs in any ONNX runtime with its table as one initializer.
//!
//! # The encoding, op by op (`points [N, 3]` → `features [N, L·F]`)
//! Laid out for onnxruntime's CPU kernels (measured with its profiler): level-major
//! intermediates so per-level constants broadcast over whole levels, int32 indices, no `Where`
//! and no `Mod`, lookups in small tables instead of arithmetic, products as `MatMul`s.
//! 0. Contracted fields only ([`nerf_core::sample::contraction`]): `Abs`, three `Slice`s and
//!    `Max` (‖x‖∞ `[N, 1]`), `Max` with 1, `Div` 1 by it (r), `Sub` r from 2, `Mul` by r (f),
//!    `Mul` the point by f: the same f32 operations as [`Contraction::apply`].
//! 1. `Sub` the bound's min, `Mul` by its f32 scale, `Clip` to [0, 1]: the unit-cube point,
//!    the same f32 operations as [`GridBound::to_unit`] and the clamp in
//!    [`nerf_core::field::ngp::hash_grid::corners`].
//! 2. `Unsqueeze` to `[1, N, 3]`, `Mul` by the level scales `[L, 1, 1]`, `Add` 0.5: positions
//!    `[L, N, 3]`; `Floor` (cells, as float), `Sub` (fractions).
//! 3. Rows of the table, `[L, N, 8]` int32, for the dense levels (a prefix) and the hashed ones
//!    as two groups ([`rows`]), `Concat`ed.
//! 4. Weights: per axis d a `MatMul` of `[frac, 1 − frac]` with a 0/1 matrix picks `frac_d` or
//!    `1 − frac_d` for each corner (one value plus exact zeros), `[L, N, 8]`; multiplied x·y·z
//!    as tiny-cuda-nn does; repeated for the F features by another 0/1 `MatMul`, `[L, N, 8·F]`.
//! 5. `Gather` the rows of the table ([`table`]: `[rows, F]`; float16 tables `Cast` after the
//!    lookup) → `[L, N, 8, F]`, `Reshape` to `[L, N, 8·F]`, `Mul` by the weights, `MatMul` with a
//!    0/1 matrix `[8·F, F]` (the sum over corners), `Transpose` to `[N, L, F]`, `Reshape` to
//!    `[N, L·F]` (level-major per point, as the Rust encoding).
//!
//! # Lowerings
//! [`HashOps::Bitwise`] (opset ≥ 18) combines the hash with `BitwiseXor`. [`HashOps::Portable`]
//! (opset ≥ 17) uses no bitwise operator and no int64 tensor (only the shapes `Reshape` and
//! `Slice` read are int64, as the standard requires): onnxruntime's CUDA provider and
//! onnxruntime-web's WebGPU have no Bitwise kernels, and a CUDA session would place those nodes
//! on the CPU, copying the `[L, N, 8]` terms to the host and the rows back on every batch.
//! Both compute exactly the rows of the Rust encoding (tested).

use crate::ExportError;
use crate::builder::{Builder, OPSETS, int_attribute, ints_attribute, model_proto, value_info};
use crate::proto::*;
use nerf_core::field::ngp::hash_grid::{GridBound, HashGrid};
use nerf_core::field::ngp::spherical_harmonics::SH4_DIM;
#[cfg(doc)]
use nerf_core::sample::Contraction;

pub mod rows;
mod sh;
pub mod table;

pub(crate) use sh::lower_sh4;
use table::{TableFormat, TablePrecision};

/// How the spatial hash's XOR is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum HashOps {
    /// `BitwiseXor` (opset ≥ 18): the fastest on onnxruntime's CPU provider.
    #[default]
    Bitwise,
    /// No bitwise operator and no int64 (opset ≥ 17): parity tables over spread bit chunks
    /// ([`rows`]), for runtimes without Bitwise kernels (onnxruntime CUDA, WebGPU).
    Portable,
}

impl HashOps {
    /// The lowest opset this lowering needs.
    pub const fn min_opset(self) -> i64 {
        match self {
            HashOps::Bitwise => 18,
            HashOps::Portable => 17,
        }
    }
}

/// Metadata key holding the grid's configuration (JSON).
pub const GRID_KEY: &str = "nerf.hash_grid";
/// Metadata key holding the grid's bound (JSON).
pub const BOUND_KEY: &str = "nerf.grid_bound";
/// Metadata key naming the lowering (`bitwise` or `portable`).
pub const LOWERING_KEY: &str = "nerf.hash_lowering";

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
pub fn compile_encodings(grid: &HashGrid, bound: &GridBound, ops: HashOps, precision: TablePrecision, opset: i64) -> Result<ModelProto, ExportError> {
    check_opset(opset, ops)?;
    bound.validate().map_err(|e| ExportError::Network(e.to_string()))?;
    let mut g = Builder::default();
    let features = lower_hash_grid(&mut g, "points", grid, bound, ops, precision)?;
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
    Ok(model(graph, opset, grid, bound, ops, precision))
}

/// The model around `graph`, with the grid, bound, lowering and table format in the metadata.
pub(crate) fn model(graph: GraphProto, opset: i64, grid: &HashGrid, bound: &GridBound, ops: HashOps, precision: TablePrecision) -> ModelProto {
    let format = TableFormat { layout: table::LAYOUT, precision };
    let props = vec![
        (GRID_KEY.to_string(), serde_json::to_string(grid.config()).expect("a config serialises")),
        (BOUND_KEY.to_string(), serde_json::to_string(bound).expect("a bound serialises")),
        (LOWERING_KEY.to_string(), format!("{ops:?}").to_lowercase()),
        (table::TABLE_KEY.to_string(), serde_json::to_string(&format).expect("a format serialises")),
    ];
    model_proto(graph, opset, "A hash-grid radiance field compiled by nerf-rs.", props)
}

/// An int32 initializer, or an error naming it if a value does not fit.
pub(crate) fn int32_tensor(g: &mut Builder, name: &str, dims: &[i64], values: &[i64]) -> Result<String, ExportError> {
    let mut raw = Vec::with_capacity(values.len() * 4);
    for &v in values {
        let v = i32::try_from(v).map_err(|_| ExportError::Unsupported(format!("hash grid: {name} holds {v}, beyond int32: the grid is too large for one graph")))?;
        raw.extend_from_slice(&v.to_le_bytes());
    }
    g.initializers.push(TensorProto { dims: dims.to_vec(), data_type: data_type::INT32, name: name.into(), raw_data: raw, ..Default::default() });
    Ok(name.to_string())
}

pub(crate) fn f32_scalar(g: &mut Builder, name: &str, value: f32) -> String {
    g.f32_tensor(name, &[], &[value])
}

/// The L∞ contraction of `input [N, 3]` (step 0 of the module doc).
fn lower_linf_contraction(g: &mut Builder, input: &str) -> String {
    let abs = g.unary("Abs", input, "contract.abs");
    let columns: Vec<String> = (0..3).map(|a| slice(g, &abs, (a, a + 1), 1, &format!("contract.abs{a}"))).collect();
    let norm = g.node("Max", &[&columns[0], &columns[1], &columns[2]], "contract.norm", vec![]);
    let one = f32_scalar(g, "contract.one", 1.0);
    let two = f32_scalar(g, "contract.two", 2.0);
    let m = g.binary("Max", &norm, &one, "contract.at_least_one");
    let r = g.binary("Div", &one, &m, "contract.inverse");
    let two_minus = g.binary("Sub", &two, &r, "contract.two_minus");
    let f = g.binary("Mul", &two_minus, &r, "contract.factor");
    g.binary("Mul", input, &f, "contract.points")
}

/// Indices `[start, end)` of `input` along `axis`.
pub(crate) fn slice(g: &mut Builder, input: &str, (start, end): (i64, i64), axis: i64, output: &str) -> String {
    let s = g.i64_constant(&format!("index.{start}"), &[start]);
    let e = g.i64_constant(&format!("index.{end}"), &[end]);
    let a = g.i64_constant(&format!("index.{axis}"), &[axis]);
    g.node("Slice", &[input, &s, &e, &a], output, vec![])
}

/// The 0/1 matrix `[8·F, F]` that sums corner-major rows `[8·F]` over the 8 corners per feature.
pub fn corner_sum(f: usize) -> Vec<f32> {
    let mut sum = vec![0.0f32; 8 * f * f];
    for k in 0..8 {
        for j in 0..f {
            sum[(k * f + j) * f + j] = 1.0;
        }
    }
    sum
}

/// The hash-grid encoding of world points `input [N, 3]` → `[N, L·F]` (module doc).
pub(crate) fn lower_hash_grid(g: &mut Builder, input: &str, grid: &HashGrid, bound: &GridBound, ops: HashOps, precision: TablePrecision) -> Result<String, ExportError> {
    let levels = grid.levels();
    let l = levels.len() as i64;
    let f = grid.config().features_per_level as i64;
    let fu = f as usize;
    // 0. Contraction.
    let contracted = match bound.contraction {
        Some(nerf_core::sample::Contraction::Linf) => Some(lower_linf_contraction(g, input)),
        None => None,
    };
    let input = contracted.as_deref().unwrap_or(input);
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
    // 3. Rows of the table, [L, N, 8]: dense levels (a prefix: resolutions grow with the level)
    //    and hashed ones as two groups, each computing only its own rows.
    let (places, table_rows) = table::graph_levels(levels);
    let n_dense = levels.iter().take_while(|v| v.dense).count();
    let groups: Vec<(usize, usize)> = [(0, n_dense), (n_dense, levels.len())].into_iter().filter(|(a, b)| a < b).collect();
    let mut group_rows = Vec::new();
    for &(start, end) in &groups {
        let dense = levels[start].dense;
        let tag = if dense { "grid.dense" } else { "grid.hashed" };
        let floor = if groups.len() == 1 { floor.clone() } else { slice(g, &floor, (start as i64, end as i64), 0, &format!("{tag}.floor")) };
        group_rows.push(if dense {
            rows::dense_rows(g, &floor, &levels[start..end], &places[start..end])?
        } else {
            rows::hashed_rows(g, &floor, &levels[start..end], &places[start..end], ops, grid.config().log2_table_size)?
        });
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
    let values = table::graph_table(grid);
    let table = match precision {
        TablePrecision::F32 => g.f32_tensor("grid.table", &[table_rows as usize, fu], &values),
        TablePrecision::F16 => {
            let raw_data = table::f16_bytes(&values);
            g.initializers.push(TensorProto { dims: vec![table_rows as i64, f], data_type: data_type::FLOAT16, name: "grid.table".into(), raw_data, ..Default::default() });
            "grid.table".to_string()
        }
    };
    let values = g.node("Gather", &[&table, &rows], "grid.values", vec![int_attribute("axis", 0)]);
    let values = match precision {
        TablePrecision::F32 => values,
        TablePrecision::F16 => g.node("Cast", &[&values], "grid.values_f32", vec![int_attribute("to", data_type::FLOAT as i64)]),
    };
    // [L, N, 8, F] → [L, N, 8·F], weighted, then summed over the corners per feature by a
    // MatMul with a 0/1 matrix [8·F, F].
    let flat_shape = g.i64_constant("grid.values_flat_shape", &[l, -1, 8 * f]);
    let flat = g.node("Reshape", &[&values, &flat_shape], "grid.values_flat", vec![]);
    let weighted = g.node("Mul", &[&flat, &weight], "grid.weighted", vec![]);
    let sum = g.f32_tensor("grid.corner_sum", &[8 * fu, fu], &corner_sum(fu));
    let summed = g.node("MatMul", &[&weighted, &sum], "grid.summed", vec![]);
    // [L, N, F] → [N, L, F] → [N, L·F], level-major per point as the Rust encoding.
    let point_major = g.node("Transpose", &[&summed], "grid.point_major", vec![ints_attribute("perm", &[1, 0, 2])]);
    let shape = g.i64_constant("grid.output_shape", &[0, l * f]);
    Ok(g.node("Reshape", &[&point_major, &shape], nerf_bundle::ngp::FEATURES_TENSOR, vec![]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::field::ngp::hash_grid::HashGridConfig;

    fn grid() -> HashGrid {
        HashGrid::new(HashGridConfig { levels: 4, features_per_level: 2, log2_table_size: 9, base_resolution: 4, max_resolution: 17 }, 1).unwrap()
    }

    #[test]
    fn graph_names_opsets_and_the_portable_graph_has_no_bitwise_and_no_int64_data() {
        let g = grid();
        let f32 = TablePrecision::F32;
        let model = compile_encodings(&g, &GridBound::cube(1.5), HashOps::Bitwise, f32, 18).unwrap();
        let graph = model.graph.as_ref().unwrap();
        let names: Vec<&str> = graph.input.iter().chain(&graph.output).map(|v| v.name.as_str()).collect();
        assert_eq!(names, ["points", "viewdirs", "features", "sh"]);
        let ops: Vec<&str> = graph.node.iter().map(|n| n.op_type.as_str()).collect();
        assert!(ops.contains(&"BitwiseXor") && ops.contains(&"Gather") && !ops.contains(&"Mod") && !ops.contains(&"Where"));
        let mut init: Vec<&str> = graph.initializer.iter().map(|t| t.name.as_str()).collect();
        init.sort();
        let n = init.len();
        init.dedup();
        assert_eq!(init.len(), n, "no initializer twice");
        let table = graph.initializer.iter().find(|t| t.name == "grid.table").unwrap();
        assert_eq!(table.dims, [table::graph_levels(g.levels()).1 as i64, 2]);
        assert_eq!(table.data_type, data_type::FLOAT);
        assert!(model.metadata_props.iter().any(|p| p.key == GRID_KEY));
        let portable = compile_encodings(&g, &GridBound::cube(1.5), HashOps::Portable, TablePrecision::F16, 17).unwrap();
        let graph = portable.graph.unwrap();
        assert!(!graph.node.iter().any(|n| n.op_type.starts_with("Bitwise")));
        // int64 only in the shape and axis constants of Slice, Unsqueeze and Reshape.
        for t in graph.initializer.iter().filter(|t| t.data_type == data_type::INT64) {
            assert!(t.dims.len() == 1 && t.dims[0] <= 3, "{} is int64 data", t.name);
        }
        assert!(graph.node.iter().filter(|n| n.op_type == "Cast").all(|n| n.attribute[0].i != data_type::INT64 as i64));
        assert_eq!(graph.initializer.iter().find(|t| t.name == "grid.table").unwrap().data_type, data_type::FLOAT16);
        let err = compile_encodings(&g, &GridBound::cube(1.5), HashOps::Bitwise, f32, 17).unwrap_err().to_string();
        assert!(err.contains("opset 17") && err.contains("18"), "{err}");
        let err = compile_encodings(&g, &GridBound::cube(0.0), HashOps::Bitwise, f32, 18).unwrap_err().to_string();
        assert!(err.contains("axis 0"), "{err}");
    }
}
