//! The compiler's generic parts: opsets, models around graphs, the contract's inputs and
//! outputs, and a builder of nodes and initializers that every field kind's lowering writes
//! its graph with.

use crate::proto::*;
use nerf_bundle::graph::{CONTRACT_INPUTS, CONTRACT_OUTPUTS};
use nerf_bundle::scene::{CAMERA_CONVENTION, SceneDescription};
use nerf_core::field::Role;
pub use nerf_bundle::ngp::read_dense_layers;
use nerf_core::field::DenseLayer;

/// Opsets this compiler writes (`Gemm`, `Unsqueeze`-with-axes-input, `Slice`, `Reshape` are
/// stable across them).
pub const OPSETS: std::ops::RangeInclusive<i64> = 17..=23;
/// The default opset.
pub const DEFAULT_OPSET: i64 = 17;
/// The IR version that goes with an opset of the default domain (onnx's VERSION_TABLE).
pub fn ir_version_for(opset: i64) -> i64 {
    match opset {
        ..=18 => 8,
        19..=20 => 9,
        21..=22 => 10,
        _ => 11,
    }
}

/// A model around `graph` for `opset` (with the IR version to match), carrying `metadata`.
pub fn model_proto(graph: GraphProto, opset: i64, doc: &str, metadata: Vec<(String, String)>) -> ModelProto {
    ModelProto {
        ir_version: ir_version_for(opset),
        opset_import: vec![OperatorSetIdProto { domain: String::new(), version: opset }],
        producer_name: "nerf-rs".into(),
        producer_version: env!("CARGO_PKG_VERSION").into(),
        domain: "rs.nerf".into(),
        model_version: 1,
        doc_string: doc.into(),
        graph: Some(graph),
        metadata_props: metadata.into_iter().map(|(key, value)| StringStringEntryProto { key, value }).collect(),
    }
}

/// The contract's inputs, documented.
pub fn contract_inputs() -> Vec<ValueInfoProto> {
    vec![
        value_info(CONTRACT_INPUTS[0], "World-space sample positions, float32 [N, 3]."),
        value_info(CONTRACT_INPUTS[1], "Unit view directions (the ray direction normalised), float32 [N, 3], one per point."),
    ]
}

/// The contract's outputs; `sigma_doc` says how σ is made non-negative.
pub fn contract_outputs(sigma_doc: &str) -> Vec<ValueInfoProto> {
    vec![value_info(CONTRACT_OUTPUTS[0], "Colour in [0, 1] (sigmoid applied), float32 [N, 3]."), value_info(CONTRACT_OUTPUTS[1], sigma_doc)]
}

/// `name` float32 `[N, columns]`.
pub fn value_info((name, columns): (&str, i64), doc: &str) -> ValueInfoProto {
    float_info(name, &[Dim::Named("N"), Dim::Fixed(columns)], doc)
}

/// One axis of a graph input or output.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dim<'a> {
    /// A size fixed in the graph.
    Fixed(i64),
    /// A size given at run time, by name.
    Named(&'a str),
}

/// `name` float32 of shape `dims`.
pub fn float_info(name: &str, dims: &[Dim], doc: &str) -> ValueInfoProto {
    use tensor_shape_proto::{Dimension, dimension::Value};
    let dim = dims
        .iter()
        .map(|d| Dimension {
            value: Some(match d {
                Dim::Fixed(n) => Value::DimValue(*n),
                Dim::Named(s) => Value::DimParam(s.to_string()),
            }),
        })
        .collect();
    ValueInfoProto {
        name: name.into(),
        r#type: Some(TypeProto {
            value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                elem_type: data_type::FLOAT,
                shape: Some(TensorShapeProto { dim }),
            })),
        }),
        doc_string: doc.into(),
    }
}

/// Accumulates nodes and initializers with unique names: every kind's lowering writes its graph
/// with it, then wraps `nodes` and `initializers` in a `GraphProto` with the contract's
/// [`contract_inputs`] and [`contract_outputs`].
#[derive(Default)]
pub struct Builder {
    /// The nodes, in topological order.
    pub nodes: Vec<NodeProto>,
    /// The constants and weights.
    pub initializers: Vec<TensorProto>,
}

impl Builder {
    /// A node `op(inputs) → output` (the node is named after its output); returns `output`.
    pub fn node(&mut self, op: &str, inputs: &[&str], output: &str, attribute: Vec<AttributeProto>) -> String {
        self.nodes.push(NodeProto {
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![output.to_string()],
            name: output.to_string(),
            op_type: op.to_string(),
            domain: String::new(),
            attribute,
            doc_string: String::new(),
        });
        output.to_string()
    }

    /// A node of one input and no attributes.
    pub fn unary(&mut self, op: &str, input: &str, output: &str) -> String {
        self.node(op, &[input], output, vec![])
    }

    /// `Concat` along the last axis (1).
    pub fn concat(&mut self, inputs: &[&str], output: &str) -> String {
        self.node("Concat", inputs, output, vec![int_attribute("axis", 1)])
    }

    /// A named constant, stored once however often it is used.
    pub fn i64_constant(&mut self, name: &str, values: &[i64]) -> String {
        if !self.initializers.iter().any(|t| t.name == name) {
            self.initializers.push(TensorProto {
                dims: vec![values.len() as i64],
                data_type: data_type::INT64,
                name: name.into(),
                raw_data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
                ..Default::default()
            });
        }
        name.to_string()
    }

    /// A float32 initializer of shape `dims`.
    pub fn f32_tensor(&mut self, name: &str, dims: &[usize], values: &[f32]) -> String {
        self.initializers.push(TensorProto {
            dims: dims.iter().map(|&d| d as i64).collect(),
            data_type: data_type::FLOAT,
            name: name.into(),
            raw_data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
            ..Default::default()
        });
        name.to_string()
    }

    /// A float32 scalar constant, stored once however often it is used.
    pub fn f32_scalar(&mut self, name: &str, value: f32) -> String {
        if !self.initializers.iter().any(|t| t.name == name) {
            self.f32_tensor(name, &[], &[value]);
        }
        name.to_string()
    }

    /// A node of two inputs and no attributes (`Add`, `Mul`, `Div`, …).
    pub fn binary(&mut self, op: &str, a: &str, b: &str, output: &str) -> String {
        self.node(op, &[a, b], output, vec![])
    }

    /// A 2-D `Conv` of `input` `[N, C, H, W]` with the initializer `weight` `[out, C, kernel,
    /// kernel]` (OIHW) and optionally `bias` `[out]`, at `stride` with symmetric zero `pad`.
    pub fn conv2d(&mut self, input: &str, weight: &str, bias: Option<&str>, (kernel, stride, pad): (i64, i64, i64), output: &str) -> String {
        let mut inputs = vec![input, weight];
        inputs.extend(bias);
        let attributes = vec![
            ints_attribute("kernel_shape", &[kernel, kernel]),
            ints_attribute("strides", &[stride, stride]),
            ints_attribute("pads", &[pad, pad, pad, pad]),
        ];
        self.node("Conv", &inputs, output, attributes)
    }

    /// `MaxPool` over `kernel × kernel` windows at `stride`, no padding, sizes rounded down.
    pub fn max_pool(&mut self, input: &str, output: &str, kernel: i64, stride: i64) -> String {
        let attributes = vec![ints_attribute("kernel_shape", &[kernel, kernel]), ints_attribute("strides", &[stride, stride])];
        self.node("MaxPool", &[input], output, attributes)
    }

    /// `ReduceSum` over `axes`, keeping them as size 1 (axes as an input: opset ≥ 13).
    pub fn reduce_sum_keep(&mut self, input: &str, axes: &[i64], output: &str) -> String {
        let name = format!("axes_{}", axes.iter().map(|a| a.to_string()).collect::<Vec<_>>().join("_"));
        let axes = self.i64_constant(&name, axes);
        self.node("ReduceSum", &[input, &axes], output, vec![int_attribute("keepdims", 1)])
    }

    /// `Gemm(input, W, b)` (then `activation`), W stored `[in, out]`.
    pub fn dense(&mut self, layer: &DenseLayer, input: &str, activation: Option<&str>) -> String {
        let w = self.f32_tensor(&format!("{}.weight", layer.name), &[layer.in_dim, layer.out_dim], &layer.weight);
        let b = self.f32_tensor(&format!("{}.bias", layer.name), &[layer.out_dim], &layer.bias);
        let linear = self.node("Gemm", &[input, &w, &b], &format!("{}.linear", layer.name), vec![]);
        match activation {
            Some(op) => self.unary(op, &linear, &format!("{}.{}", layer.name, op.to_lowercase())),
            None => linear,
        }
    }
}

/// An attribute holding a list of integers.
pub fn ints_attribute(name: &str, values: &[i64]) -> AttributeProto {
    AttributeProto { name: name.into(), r#type: attribute_type::INTS, ints: values.to_vec(), ..Default::default() }
}

/// An integer attribute.
pub fn int_attribute(name: &str, value: i64) -> AttributeProto {
    AttributeProto { name: name.into(), r#type: attribute_type::INT, i: value, ..Default::default() }
}

/// The contract metadata every graph of a scene carries.
pub fn scene_metadata(scene: &SceneDescription, role: Role) -> Vec<(String, String)> {
    let s = &scene.sampling;
    let mut metadata = vec![
        ("nerf.stage".into(), role.name().into()),
        ("nerf.near".into(), s.near.to_string()),
        ("nerf.far".into(), s.far.to_string()),
        ("nerf.n_coarse".into(), s.n_coarse.to_string()),
        ("nerf.n_fine".into(), s.n_fine.to_string()),
        ("nerf.lindisp".into(), s.lindisp.to_string()),
        ("nerf.white_background".into(), scene.white_background.to_string()),
        ("nerf.camera".into(), CAMERA_CONVENTION.into()),
    ];
    if let Some(n) = &s.ndc {
        let ndc = format!("width {} height {} fx {} fy {} near {}", n.width, n.height, n.fx, n.fy, n.near);
        metadata.push(("nerf.ndc".into(), ndc));
    }
    metadata
}
