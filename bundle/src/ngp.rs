//! Reading a hash-grid field back from its graph (written by `nerf_export::field::ngp`): the
//! metadata keys, the table's format and row layout, and [`read_ngp`]. Here rather than in the
//! compiler because the renderer (`nerf-render`) reads them too, to evaluate the encoding in
//! Rust, and must not link the compiler's dependencies.
//!
//! # The table's rows
//! The trained table ([`HashGrid::params`](nerf_core::field::ngp::hash_grid::HashGrid::params))
//! holds the levels in order, each `entries` rows. The graph's table (`grid.table`, `[rows, F]`)
//! holds the same rows arranged for the lowering:
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

use crate::graph::{float_initializer, metadata};
use crate::proto::{GraphProto, ModelProto};
use nerf_core::field::DenseLayer;
use nerf_core::field::ngp::hash_grid::{GridBound, HashGrid, HashGridConfig, LevelLayout};
use nerf_core::field::ngp::spherical_harmonics::{SH4_DIM, sh4};
use nerf_core::field::ngp::{NgpSpec, PlainNgp};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Metadata key naming the field kind.
pub const FIELD_KEY: &str = "nerf.field";
/// Metadata key holding the [`NgpSpec`] as JSON.
pub const NGP_KEY: &str = "nerf.ngp";
/// Metadata key holding the [`TableFormat`] (JSON).
pub const TABLE_KEY: &str = "nerf.grid_table";
/// The hash-grid features in a graph written by the compiler: `[N, L·F]`, level-major, the
/// input of the density MLP (`nerf-render` cuts the graph here).
pub const FEATURES_TENSOR: &str = "grid.features";
/// The degree-4 harmonics of `viewdirs` in such a graph: `[N, 16]`, part of the colour MLP's
/// input (`nerf-render` cuts the graph here too).
pub const SH_TENSOR: &str = "sh.output";

/// How a lookup table's values are stored in a graph (a hash grid's table; networks' weights
/// always stay float32).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TablePrecision {
    /// float32: the trained values exactly.
    #[default]
    F32,
    /// float16: half the size; values rounded to 11 significant bits, widened to float32
    /// right after the lookup (trained tables hold values of order 1e-4–1, well inside
    /// float16's range).
    F16,
}

/// The table's format, as [`TABLE_KEY`] records it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct TableFormat {
    /// 2: the arrangement of the module doc.
    pub layout: u32,
    /// How values are stored.
    pub precision: TablePrecision,
}

/// The layout of the module doc.
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

/// How a hash-grid graph stores its table (float32 where the format is not recorded).
pub fn table_precision(model: &ModelProto) -> Result<TablePrecision, String> {
    match metadata(model, TABLE_KEY) {
        None => Ok(TablePrecision::F32),
        Some(json) => serde_json::from_str::<TableFormat>(json).map(|f| f.precision).map_err(|e| format!("{TABLE_KEY}: {e}")),
    }
}

/// The dense layers of shapes `(name, in, out)` the compiler stored in `graph`
/// (`<name>.weight` `[in, out]`, `<name>.bias` `[out]`), each size checked.
pub fn read_dense_layers(graph: &GraphProto, shapes: Vec<(String, usize, usize)>) -> Result<Vec<DenseLayer>, String> {
    shapes
        .into_iter()
        .map(|(name, in_dim, out_dim)| {
            Ok(DenseLayer {
                weight: float_initializer(graph, &format!("{name}.weight"), &[in_dim, out_dim])?,
                bias: float_initializer(graph, &format!("{name}.bias"), &[out_dim])?,
                name,
                in_dim,
                out_dim,
            })
        })
        .collect()
}

/// The field a hash-grid graph holds: the spec from its metadata, the table and the layers
/// from its initializers, every size checked against the spec (a truncated or resized table
/// is an error, not a wrong lookup later).
pub fn read_ngp(model: &ModelProto) -> Result<PlainNgp, String> {
    let spec_json = metadata(model, NGP_KEY).ok_or_else(|| format!("no {NGP_KEY} metadata: not a hash-grid graph written by nerf export"))?;
    let spec: NgpSpec = serde_json::from_str(spec_json).map_err(|e| format!("{NGP_KEY}: {e}"))?;
    spec.validate().map_err(|e| format!("{NGP_KEY}: {e}"))?;
    let graph = model.graph.as_ref().ok_or("the model has no graph")?;
    let f = spec.grid.features_per_level;
    // Graphs written before the table format was recorded hold the trained layout in float32.
    let table = match metadata(model, TABLE_KEY) {
        None => float_initializer(graph, "grid.table", &[spec.grid.total_entries().map_err(|e| e.to_string())?, f]),
        Some(json) => {
            let format: TableFormat = serde_json::from_str(json).map_err(|e| format!("{TABLE_KEY}: {e}"))?;
            let levels = spec.grid.layout().map_err(|e| e.to_string())?;
            let rows = graph_levels(&levels).1 as usize;
            float_initializer(graph, "grid.table", &[rows, f]).and_then(|t| trained_table(&spec.grid, format, &t))
        }
    }
    .map_err(|e| format!("hash table: {e}"))?;
    let layers = read_dense_layers(graph, spec.layer_shapes())?;
    let plain = PlainNgp { spec, table, layers };
    plain.validate().map_err(|e| e.to_string())?;
    Ok(plain)
}

/// A hash-grid graph split where the CPU renderers split it (`nerf-render`, the Python
/// package's native module): the core's hash grid and harmonics (the encodings training uses)
/// compute the [`head_graph`]'s inputs, and onnxruntime runs the head. onnxruntime's `Gather`
/// of the table's rows is most of the whole graph's time on a CPU; the Rust encoding reads the
/// same rows at 2–3× the speed.
pub struct SplitNgp {
    /// The hash grid, with the graph's table.
    pub grid: HashGrid,
    /// The world box the grid covers.
    pub bound: GridBound,
}

impl SplitNgp {
    /// `model` split into the graph after the cuts ([`head_graph`]) and its encoder, or None
    /// where it is not a hash-grid field or cannot be cut (graphs written before the
    /// encodings' outputs were named: they run whole).
    pub fn of(model: &ModelProto) -> Result<Option<(ModelProto, Self)>, String> {
        if metadata(model, FIELD_KEY) != Some("ngp") {
            return Ok(None);
        }
        let plain = read_ngp(model)?;
        let grid = HashGrid::from_params(plain.spec.grid, plain.table).map_err(|e| e.to_string())?;
        Ok(head_graph(model, grid.output_dim()).ok().map(|head| (head, SplitNgp { grid, bound: plain.spec.bound })))
    }

    /// The head's inputs for `points` with unit `viewdirs` (alike lengths n): the features
    /// into `features` `[n · L·F]` ([`FEATURES_TENSOR`]), the harmonics into `sh` `[n · 16]`
    /// ([`SH_TENSOR`]); `unit` `[n]` is scratch (the points in the grid's unit cube).
    pub fn encode_into(&self, points: &[[f32; 3]], viewdirs: &[[f32; 3]], unit: &mut [[f32; 3]], features: &mut [f32], sh: &mut [f32]) {
        unit.iter_mut().zip(points).for_each(|(u, &p)| *u = self.bound.to_unit(p));
        self.grid.forward_into(unit, features);
        sh.par_chunks_mut(SH4_DIM * 1024).zip(viewdirs.par_chunks(1024)).for_each(|(sh, dirs)| {
            sh.chunks_exact_mut(SH4_DIM).zip(dirs).for_each(|(row, &d)| row.copy_from_slice(&sh4(d)));
        });
    }
}

/// The part of a hash-grid graph after its encodings: the graph's own nodes that compute `rgb`
/// and `sigma` from [`FEATURES_TENSOR`] (`[N, width]`) and [`SH_TENSOR`] (`[N, 16]`), the
/// graph's inputs in that order, with their initializers (the MLPs, `Exp` and `Sigmoid`). Cut
/// from the bundle's graph rather than compiled again, so it is the head the other consumers
/// run, node for node; an error where the graph has no such cut (written before the
/// encodings' outputs were named).
pub fn head_graph(model: &ModelProto, width: usize) -> Result<ModelProto, String> {
    use crate::proto::{TensorShapeProto, TypeProto, ValueInfoProto, data_type, tensor_shape_proto, type_proto};
    use std::collections::HashSet;
    let graph = model.graph.as_ref().ok_or("the model has no graph")?;
    let cuts = [(FEATURES_TENSOR, width, "Hash-grid features, float32 [N, L·F], level-major."), (SH_TENSOR, nerf_core::field::ngp::spherical_harmonics::SH4_DIM, "Degree-4 spherical harmonics of the view directions, float32 [N, 16].")];
    for (cut, _, _) in cuts {
        if !graph.node.iter().any(|n| n.output.iter().any(|o| o == cut)) {
            return Err(format!("no node computes {cut}"));
        }
    }
    let is_cut = |t: &str| cuts.iter().any(|(c, _, _)| *c == t);
    // Walk back from the outputs, stopping at the cuts.
    let mut needed: HashSet<&str> = graph.output.iter().map(|o| o.name.as_str()).collect();
    let mut keep = vec![false; graph.node.len()];
    for (k, node) in graph.node.iter().enumerate().rev() {
        if node.output.iter().any(|o| needed.contains(o.as_str())) {
            keep[k] = true;
            needed.extend(node.input.iter().map(String::as_str).filter(|i| !i.is_empty() && !is_cut(i)));
        }
    }
    if let Some(input) = graph.input.iter().find(|i| needed.contains(i.name.as_str())) {
        return Err(format!("the outputs depend on {} other than through {FEATURES_TENSOR} and {SH_TENSOR}", input.name));
    }
    use tensor_shape_proto::{Dimension, dimension::Value};
    let input = |(name, width, doc): (&str, usize, &str)| ValueInfoProto {
        name: name.into(),
        r#type: Some(TypeProto {
            value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                elem_type: data_type::FLOAT,
                shape: Some(TensorShapeProto { dim: vec![Dimension { value: Some(Value::DimParam("N".into())) }, Dimension { value: Some(Value::DimValue(width as i64)) }] }),
            })),
        }),
        doc_string: doc.into(),
    };
    let head = GraphProto {
        node: graph.node.iter().zip(&keep).filter(|(_, k)| **k).map(|(n, _)| n.clone()).collect(),
        name: format!("{}.head", graph.name),
        initializer: graph.initializer.iter().filter(|t| needed.contains(t.name.as_str())).cloned().collect(),
        doc_string: format!("The part of {} after its encodings.", graph.name),
        input: cuts.map(input).to_vec(),
        output: graph.output.clone(),
        value_info: vec![],
    };
    Ok(ModelProto {
        ir_version: model.ir_version,
        opset_import: model.opset_import.clone(),
        producer_name: model.producer_name.clone(),
        producer_version: model.producer_version.clone(),
        domain: model.domain.clone(),
        model_version: model.model_version,
        doc_string: String::new(),
        graph: Some(head),
        metadata_props: vec![],
    })
}
