//! The graph contract every field graph of a bundle follows, and reading graphs back: decoding,
//! the contract's inputs and outputs, initializers whose sizes match their shapes, metadata.
//!
//! # The contract
//! - Inputs: `points` float32 `[N, 3]` (world positions) and `viewdirs` float32 `[N, 3]` (unit
//!   view directions, one per point); `N` is dynamic.
//! - Outputs: `rgb` float32 `[N, 3]` in [0, 1] and `sigma` float32 `[N, 1]` (≥ 0).
//! - `metadata_props` carry the contract (`nerf.contract`), the kind (`nerf.field`) and the
//!   field's shape as JSON (the kind's own key).

use crate::proto::*;
use nerf_core::io::limits;
use prost::Message;
use std::path::Path;

/// Largest graph file read: protobuf messages stop at 2 GiB.
pub const MAX_GRAPH_BYTES: u64 = 2 << 30;

/// The graph inputs, with their second dimension: `[N, 3]` each.
pub const CONTRACT_INPUTS: [(&str, i64); 2] = [("points", 3), ("viewdirs", 3)];
/// The graph outputs, with their second dimension: `rgb [N, 3]`, `sigma [N, 1]`.
pub const CONTRACT_OUTPUTS: [(&str, i64); 2] = [("rgb", 3), ("sigma", 1)];

/// Check that `model`'s graph has exactly the contract's inputs and outputs: float32, rank 2,
/// the first dimension dynamic or any size, the second as in [`CONTRACT_INPUTS`] /
/// [`CONTRACT_OUTPUTS`]. Graphs from other tools pass if they follow it.
pub fn check_contract(model: &ModelProto) -> Result<(), String> {
    use tensor_shape_proto::dimension::Value;
    let graph = model.graph.as_ref().ok_or("the model has no graph")?;
    let side = |what: &str, values: &[ValueInfoProto], expected: &[(&str, i64)]| -> Result<(), String> {
        let names: Vec<&str> = values.iter().map(|v| v.name.as_str()).collect();
        let want: Vec<&str> = expected.iter().map(|(n, _)| *n).collect();
        let mut sorted = names.clone();
        sorted.sort();
        let mut want_sorted = want.clone();
        want_sorted.sort();
        if sorted != want_sorted {
            return Err(format!("graph {what}s are {names:?}, the contract needs {want:?}"));
        }
        for (name, cols) in expected {
            let v = values.iter().find(|v| v.name == *name).expect("names checked");
            let Some(type_proto::Value::TensorType(t)) = v.r#type.as_ref().and_then(|t| t.value.as_ref()) else {
                return Err(format!("{what} {name}: not a tensor"));
            };
            if t.elem_type != data_type::FLOAT {
                return Err(format!("{what} {name}: element type {}, the contract needs float32 ({})", t.elem_type, data_type::FLOAT));
            }
            let dims: Vec<Option<i64>> = t
                .shape
                .as_ref()
                .map(|s| s.dim.iter().map(|d| match d.value { Some(Value::DimValue(v)) => Some(v), _ => None }).collect())
                .unwrap_or_default();
            if dims.len() != 2 || dims[1].is_some_and(|c| c != *cols) {
                let shown: Vec<String> = dims.iter().map(|d| d.map_or("?".into(), |v| v.to_string())).collect();
                return Err(format!("{what} {name}: shape [{}], the contract needs [N, {cols}]", shown.join(", ")));
            }
        }
        Ok(())
    };
    side("input", &graph.input, &CONTRACT_INPUTS)?;
    side("output", &graph.output, &CONTRACT_OUTPUTS)
}

/// Decode an ONNX file (a regular file of at most [`MAX_GRAPH_BYTES`]).
pub fn read_model(path: &Path) -> nerf_core::Result<ModelProto> {
    let bytes = limits::read_bounded(path, MAX_GRAPH_BYTES)?;
    decode_model(path, &bytes)
}

/// Decode the bytes of the graph file `path`.
pub fn decode_model(path: &Path, bytes: &[u8]) -> nerf_core::Result<ModelProto> {
    ModelProto::decode(bytes).map_err(|e| nerf_core::Error::invalid(path, format!("not a valid ONNX file (truncated?): {e}")))
}

/// The value of metadata entry `key`, if the model has one.
pub fn metadata<'a>(model: &'a ModelProto, key: &str) -> Option<&'a str> {
    model.metadata_props.iter().find(|p| p.key == key).map(|p| p.value.as_str())
}

/// Check that every initializer of a numeric type holds exactly as many values as its shape
/// says, so a truncated or resized table is refused by name before a runtime indexes into it.
pub fn check_initializers(model: &ModelProto) -> Result<(), String> {
    let graph = model.graph.as_ref().ok_or("the model has no graph")?;
    graph.initializer.iter().try_for_each(check_size)
}

/// The float initializer `name` of `graph` (float32, or float16 widened to float32), checked to
/// have exactly `dims` (raw or typed data).
pub fn float_initializer(graph: &GraphProto, name: &str, dims: &[usize]) -> Result<Vec<f32>, String> {
    let t = graph.initializer.iter().find(|t| t.name == name).ok_or_else(|| format!("initializer {name} is missing"))?;
    let want: Vec<i64> = dims.iter().map(|&d| d as i64).collect();
    if t.dims != want || !matches!(t.data_type, data_type::FLOAT | data_type::FLOAT16) {
        return Err(format!("initializer {name}: dims {:?} type {}, expected {want:?} float", t.dims, t.data_type));
    }
    check_size(t)?;
    let f16 = |bits: u16| half::f16::from_bits(bits).to_f32();
    Ok(match (t.data_type, t.raw_data.is_empty()) {
        (data_type::FLOAT, true) => t.float_data.clone(),
        (data_type::FLOAT, false) => t.raw_data.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect(),
        // Typed float16 values sit in int32_data, one per entry (the low 16 bits).
        (_, true) => t.int32_data.iter().map(|&v| f16(v as u16)).collect(),
        (_, false) => t.raw_data.chunks_exact(2).map(|c| f16(u16::from_le_bytes([c[0], c[1]]))).collect(),
    })
}

/// A tensor's data (raw bytes or typed values) holds exactly the values its dims say, for the
/// types the graphs use (float32, float16, int32, int64); others are not checked.
fn check_size(t: &TensorProto) -> Result<(), String> {
    let (bytes_per_value, typed) = match t.data_type {
        data_type::FLOAT => (4, t.float_data.len()),
        data_type::FLOAT16 | data_type::INT32 => (if t.data_type == data_type::INT32 { 4 } else { 2 }, t.int32_data.len()),
        data_type::INT64 => (8, t.int64_data.len()),
        _ => return Ok(()),
    };
    let name = &t.name;
    let n = t.dims.iter().try_fold(1usize, |n, &d| usize::try_from(d).ok().and_then(|d| n.checked_mul(d)));
    let n = n.ok_or_else(|| format!("initializer {name}: dims {:?} are negative or too large", t.dims))?;
    match (t.raw_data.len(), typed) {
        (0, values) if values == n => Ok(()),
        (0, values) => Err(format!("initializer {name}: {values} values, expected {n} (truncated?)")),
        (bytes, _) if bytes == bytes_per_value * n => Ok(()),
        (bytes, _) => Err(format!("initializer {name}: {bytes} bytes, expected {} (truncated?)", bytes_per_value * n)),
    }
}
