//! The graph contract every field graph of a bundle follows, and reading graphs back: decoding
//! (no tensor data outside the file, initializers of the four types the graphs use), the
//! contract's inputs and outputs, initializers whose sizes match their shapes, metadata.
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

/// Decode the bytes of the graph file `path`, refusing what [`check_tensors`] refuses.
pub fn decode_model(path: &Path, bytes: &[u8]) -> nerf_core::Result<ModelProto> {
    let invalid = |e: prost::DecodeError| nerf_core::Error::invalid(path, format!("not a valid ONNX file (truncated?): {e}"));
    let model = ModelProto::decode(bytes).map_err(invalid)?;
    check_tensors(&scan::Model::decode(bytes).map_err(invalid)?).map_err(|e| nerf_core::Error::invalid(path, e))?;
    Ok(model)
}

/// The types an initializer may have: the ones the graphs use.
pub const INITIALIZER_TYPES: [(i32, &str); 4] =
    [(data_type::FLOAT, "float32"), (data_type::INT32, "int32"), (data_type::INT64, "int64"), (data_type::FLOAT16, "float16")];

/// Every tensor of a model, wherever it sits (initializers, sparse initializers, node attributes,
/// subgraphs, functions), holds its data in the file: with ONNX external data onnxruntime would
/// read a file the graph names, from wherever the path leads. Every initializer has one of the
/// [`INITIALIZER_TYPES`]. (`python/nerf_bundle/_onnx.py` makes the same checks.)
fn check_tensors(model: &scan::Model) -> Result<(), String> {
    use scan::*;
    fn tensor(t: &Tensor, what: &str, initializer: bool) -> Result<(), String> {
        if !t.external_data.is_empty() || t.data_location == data_location::EXTERNAL {
            return Err(format!("{what} {:?}: its data is stored outside the graph file (ONNX external data), which bundles do not use: a bundle's graphs hold their weights", t.name));
        }
        if initializer && !INITIALIZER_TYPES.iter().any(|(ty, _)| *ty == t.data_type) {
            let types: Vec<String> = INITIALIZER_TYPES.iter().map(|(ty, name)| format!("{ty} ({name})")).collect();
            return Err(format!("{what} {:?}: element type {}; initializers must be one of {}", t.name, t.data_type, types.join(", ")));
        }
        Ok(())
    }
    fn sparse(s: &Sparse, what: &str, initializer: bool) -> Result<(), String> {
        s.values.iter().chain(&s.indices).try_for_each(|t| tensor(t, what, initializer))
    }
    fn attribute(a: &Attribute) -> Result<(), String> {
        a.t.iter().chain(&a.tensors).try_for_each(|t| tensor(t, "attribute tensor", false))?;
        a.sparse_tensor.iter().chain(&a.sparse_tensors).try_for_each(|s| sparse(s, "attribute tensor", false))?;
        a.g.as_deref().into_iter().chain(&a.graphs).try_for_each(graph)
    }
    fn graph(g: &Graph) -> Result<(), String> {
        g.initializer.iter().try_for_each(|t| tensor(t, "initializer", true))?;
        g.sparse_initializer.iter().try_for_each(|s| sparse(s, "sparse initializer", true))?;
        g.node.iter().flat_map(|n| &n.attribute).try_for_each(attribute)
    }
    model.graph.iter().try_for_each(graph)?;
    model.functions.iter().try_for_each(|f| f.node.iter().flat_map(|n| &n.attribute).chain(&f.attribute_proto).try_for_each(attribute))
}

/// The parts of an ONNX model a tensor may sit in, and of a tensor what [`check_tensors`]
/// looks at; decoding skips everything else (the weights' bytes included).
mod scan {
    use crate::proto::StringStringEntryProto;
    use prost::Message;

    #[derive(Clone, PartialEq, Message)]
    pub struct Model {
        #[prost(message, optional, tag = "7")]
        pub graph: Option<Graph>,
        #[prost(message, repeated, tag = "25")]
        pub functions: Vec<Function>,
    }

    #[derive(Clone, PartialEq, Message)]
    pub struct Function {
        #[prost(message, repeated, tag = "7")]
        pub node: Vec<Node>,
        #[prost(message, repeated, tag = "11")]
        pub attribute_proto: Vec<Attribute>,
    }

    #[derive(Clone, PartialEq, Message)]
    pub struct Graph {
        #[prost(message, repeated, tag = "1")]
        pub node: Vec<Node>,
        #[prost(message, repeated, tag = "5")]
        pub initializer: Vec<Tensor>,
        #[prost(message, repeated, tag = "15")]
        pub sparse_initializer: Vec<Sparse>,
    }

    #[derive(Clone, PartialEq, Message)]
    pub struct Node {
        #[prost(message, repeated, tag = "5")]
        pub attribute: Vec<Attribute>,
    }

    #[derive(Clone, PartialEq, Message)]
    pub struct Attribute {
        #[prost(message, optional, tag = "5")]
        pub t: Option<Tensor>,
        #[prost(message, optional, boxed, tag = "6")]
        pub g: Option<Box<Graph>>,
        #[prost(message, repeated, tag = "10")]
        pub tensors: Vec<Tensor>,
        #[prost(message, repeated, tag = "11")]
        pub graphs: Vec<Graph>,
        #[prost(message, optional, tag = "22")]
        pub sparse_tensor: Option<Sparse>,
        #[prost(message, repeated, tag = "23")]
        pub sparse_tensors: Vec<Sparse>,
    }

    #[derive(Clone, PartialEq, Message)]
    pub struct Sparse {
        #[prost(message, optional, tag = "1")]
        pub values: Option<Tensor>,
        #[prost(message, optional, tag = "2")]
        pub indices: Option<Tensor>,
    }

    #[derive(Clone, PartialEq, Message)]
    pub struct Tensor {
        #[prost(int32, tag = "2")]
        pub data_type: i32,
        #[prost(string, tag = "8")]
        pub name: String,
        #[prost(message, repeated, tag = "13")]
        pub external_data: Vec<StringStringEntryProto>,
        #[prost(int32, tag = "14")]
        pub data_location: i32,
    }
}

/// The value of metadata entry `key`, if the model has one.
pub fn metadata<'a>(model: &'a ModelProto, key: &str) -> Option<&'a str> {
    model.metadata_props.iter().find(|p| p.key == key).map(|p| p.value.as_str())
}

/// Check that every initializer holds exactly as many values as its shape says, in one of the
/// [`INITIALIZER_TYPES`], so a truncated or resized table is refused by name before a runtime
/// indexes into it.
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

/// A tensor's data (raw bytes or typed values) holds exactly the values its dims say, in one of
/// the [`INITIALIZER_TYPES`].
fn check_size(t: &TensorProto) -> Result<(), String> {
    let name = &t.name;
    let (bytes_per_value, typed) = match t.data_type {
        data_type::FLOAT => (4, t.float_data.len()),
        data_type::FLOAT16 | data_type::INT32 => (if t.data_type == data_type::INT32 { 4 } else { 2 }, t.int32_data.len()),
        data_type::INT64 => (8, t.int64_data.len()),
        other => return Err(format!("initializer {name:?}: element type {other}, not float32, float16, int32 or int64")),
    };
    let n = t.dims.iter().try_fold(1usize, |n, &d| usize::try_from(d).ok().and_then(|d| n.checked_mul(d)));
    let n = n.ok_or_else(|| format!("initializer {name}: dims {:?} are negative or too large", t.dims))?;
    match (t.raw_data.len(), typed) {
        (0, values) if values == n => Ok(()),
        (0, values) => Err(format!("initializer {name}: {values} values, expected {n} (truncated?)")),
        (bytes, _) if bytes == bytes_per_value * n => Ok(()),
        (bytes, _) => Err(format!("initializer {name}: {bytes} bytes, expected {} (truncated?)", bytes_per_value * n)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tensor(name: &str) -> scan::Tensor {
        scan::Tensor { data_type: data_type::FLOAT, name: name.into(), external_data: vec![], data_location: 0 }
    }

    fn external(name: &str) -> scan::Tensor {
        let entry = |key: &str, value: &str| StringStringEntryProto { key: key.into(), value: value.into() };
        scan::Tensor { external_data: vec![entry("location", "../../etc/passwd"), entry("length", "16")], data_location: data_location::EXTERNAL, ..tensor(name) }
    }

    fn graph(initializer: Vec<scan::Tensor>, attribute: Vec<scan::Attribute>) -> scan::Graph {
        scan::Graph { node: vec![scan::Node { attribute }], initializer, sparse_initializer: vec![] }
    }

    /// `model` encoded and decoded as a graph file: the error, or "ok".
    fn decoded(model: scan::Model) -> String {
        let bytes = model.encode_to_vec();
        assert!(ModelProto::decode(bytes.as_slice()).is_ok(), "the full decoder skips what it does not model");
        decode_model(Path::new("b/field.onnx"), &bytes).map_or_else(|e| e.to_string(), |_| "ok".into())
    }

    fn model(graph: scan::Graph) -> scan::Model {
        scan::Model { graph: Some(graph), functions: vec![] }
    }

    #[test]
    fn external_data_is_refused_wherever_a_tensor_sits() {
        assert_eq!(decoded(model(graph(vec![tensor("w")], vec![]))), "ok");
        let e = decoded(model(graph(vec![tensor("w"), external("grid.table")], vec![])));
        assert!(e.starts_with("b/field.onnx: initializer \"grid.table\": its data is stored outside the graph file (ONNX external data)"), "{e}");
        // The location flag alone, or entries alone.
        let e = decoded(model(graph(vec![scan::Tensor { data_location: data_location::EXTERNAL, ..tensor("w") }], vec![])));
        assert!(e.contains("initializer \"w\": its data is stored outside"), "{e}");
        let e = decoded(model(graph(vec![scan::Tensor { data_location: 0, ..external("w") }], vec![])));
        assert!(e.contains("initializer \"w\": its data is stored outside"), "{e}");
        // A Constant node's value, a subgraph's initializer, a sparse initializer's values, a function's node.
        let constant = scan::Attribute { t: Some(external("c")), ..Default::default() };
        let e = decoded(model(graph(vec![], vec![constant.clone()])));
        assert!(e.contains("attribute tensor \"c\": its data is stored outside"), "{e}");
        let branch = scan::Attribute { g: Some(Box::new(graph(vec![external("inner")], vec![]))), ..Default::default() };
        let e = decoded(model(graph(vec![], vec![branch])));
        assert!(e.contains("initializer \"inner\": its data is stored outside"), "{e}");
        let nested = scan::Attribute { graphs: vec![graph(vec![], vec![constant.clone()])], ..Default::default() };
        assert!(decoded(model(graph(vec![], vec![nested]))).contains("attribute tensor \"c\""));
        let sparse = scan::Graph { sparse_initializer: vec![scan::Sparse { values: Some(external("s")), indices: None }], ..graph(vec![], vec![]) };
        assert!(decoded(model(sparse)).contains("initializer \"s\": its data is stored outside"));
        let function = scan::Function { node: vec![scan::Node { attribute: vec![constant] }], attribute_proto: vec![] };
        let e = decoded(scan::Model { graph: None, functions: vec![function] });
        assert!(e.contains("attribute tensor \"c\""), "{e}");
    }

    #[test]
    fn initializers_of_other_types_are_refused() {
        for (ty, _) in INITIALIZER_TYPES {
            assert_eq!(decoded(model(graph(vec![scan::Tensor { data_type: ty, ..tensor("w") }], vec![]))), "ok");
        }
        let e = decoded(model(graph(vec![scan::Tensor { data_type: data_type::DOUBLE, ..tensor("w") }], vec![])));
        assert_eq!(e, "b/field.onnx: initializer \"w\": element type 11; initializers must be one of 1 (float32), 6 (int32), 7 (int64), 10 (float16)");
        // A constant's type is its node's business (a Constant may hold a bool).
        let constant = scan::Attribute { t: Some(scan::Tensor { data_type: data_type::BOOL, ..tensor("c") }), ..Default::default() };
        assert_eq!(decoded(model(graph(vec![], vec![constant]))), "ok");
        // Built in memory (not decoded), the size check refuses them too.
        let t = TensorProto { data_type: data_type::DOUBLE, dims: vec![2], raw_data: vec![0; 16], name: "w".into(), ..Default::default() };
        let e = check_size(&t).unwrap_err();
        assert_eq!(e, "initializer \"w\": element type 11, not float32, float16, int32 or int64");
    }
}
