//! The NeRF MLPs' ONNX lowering: one plain network ([`PlainNetwork`]) into an ONNX model, and
//! its description and weights read back; [`import`] reads nerf-pytorch's trained networks.
//!
//! # The graph contract
//! - Inputs: `points` float32 `[N, 3]` (world positions) and `viewdirs` float32 `[N, 3]` (unit
//!   view directions, one per point); `N` is dynamic (`dim_param` "N"). Networks without view
//!   dependence still take `viewdirs` and ignore it.
//! - Outputs: `rgb` float32 `[N, 3]` in [0, 1] (sigmoid applied) and `sigma` float32 `[N, 1]`
//!   (ReLU applied).
//! - The positional encodings run inside the graph, as in training: for each input,
//!   `[x, sin(2⁰x), cos(2⁰x), …, sin(2^(L−1)x), cos(2^(L−1)x)]` (Unsqueeze → Mul by the
//!   frequencies → Sin, Cos → Concat → Reshape → Concat with x). Dense layers are `Gemm` with
//!   weights `[in, out]`; skip inputs and the view input are `Concat`s, as in the trainer.
//! - Initializers are named `<layer>.weight` / `<layer>.bias` (layer names from
//!   [`NetworkSpec::layer_shapes`]) plus a few encoding constants, each stored once.
//! - `metadata_props` carry the contract; `nerf.network` holds the [`NetworkSpec`] as JSON.

pub mod import;

use crate::ExportError;
use crate::builder::{Builder, OPSETS, contract_inputs, contract_outputs, int_attribute, model_proto, read_dense_layers, scene_metadata};
use crate::proto::*;
use nerf_bundle::graph::metadata;
use nerf_bundle::scene::{EncodingDescription, SceneDescription};
use nerf_core::field::Role;
use nerf_bundle::{bundle_file, read_model};
use std::path::Path;
use crate::field::CompileField;
use nerf_core::field::FieldKind;
use nerf_core::field::mlp::{EncodingSpec, NetworkSpec, PlainMlp, PlainNetwork};

/// Metadata key holding the network description as JSON.
pub const NETWORK_KEY: &str = "nerf.network";

/// Compile `net` into a model named `name`; `metadata` is added to the contract entries.
pub fn compile(net: &PlainNetwork, name: &str, opset: i64, metadata: &[(String, String)]) -> Result<ModelProto, ExportError> {
    if !OPSETS.contains(&opset) {
        return Err(ExportError::Unsupported(format!("opset {opset}: this compiler writes opsets {}–{}", OPSETS.start(), OPSETS.end())));
    }
    net.validate().map_err(ExportError::Network)?;
    let spec = &net.spec;
    for (what, e) in [("position", &spec.position_encoding), ("direction", &spec.direction_encoding)] {
        if e.output_dim() == 0 {
            return Err(ExportError::Network(format!("the {what} encoding has no outputs")));
        }
    }
    let mut g = Builder::default();
    let x = lower_encoding(&mut g, "points", "position_encoding", &spec.position_encoding);
    let mut h = x.clone();
    for (i, layer) in net.layers[..spec.depth].iter().enumerate() {
        h = g.dense(layer, &h, Some("Relu"));
        if spec.skips.contains(&i) {
            h = g.concat(&[&x, &h], &format!("trunk.{i}.skip"));
        }
    }
    let heads = &net.layers[spec.depth..];
    if spec.use_viewdirs {
        let sigma_raw = g.dense(&heads[0], &h, None);
        g.unary("Relu", &sigma_raw, "sigma");
        let feature = g.dense(&heads[1], &h, None);
        let d = lower_encoding(&mut g, "viewdirs", "direction_encoding", &spec.direction_encoding);
        let view_in = g.concat(&[&feature, &d], "view.input");
        let v = g.dense(&heads[2], &view_in, Some("Relu"));
        let rgb_raw = g.dense(&heads[3], &v, None);
        g.unary("Sigmoid", &rgb_raw, "rgb");
    } else {
        let out = g.dense(&heads[0], &h, None);
        let axes = g.i64_constant("slice.axes", &[1]);
        let (s0, s3, s4) = (g.i64_constant("slice.0", &[0]), g.i64_constant("slice.3", &[3]), g.i64_constant("slice.4", &[4]));
        let rgb_raw = g.node("Slice", &[&out, &s0, &s3, &axes], "output.rgb", vec![]);
        let sigma_raw = g.node("Slice", &[&out, &s3, &s4, &axes], "output.sigma", vec![]);
        g.unary("Sigmoid", &rgb_raw, "rgb");
        g.unary("Relu", &sigma_raw, "sigma");
    }

    let mut props = vec![
        ("nerf.contract".to_string(), "inputs points [N,3] float32 world positions, viewdirs [N,3] float32 unit view directions; outputs rgb [N,3] float32 in [0,1] (sigmoid applied), sigma [N,1] float32 (ReLU applied); N is dynamic".to_string()),
        ("nerf.position_encoding".to_string(), encoding_text(&spec.position_encoding)),
        ("nerf.direction_encoding".to_string(), encoding_text(&spec.direction_encoding)),
        (NETWORK_KEY.to_string(), serde_json::to_string(spec).expect("a NetworkSpec serialises")),
    ];
    props.extend(metadata.iter().cloned());
    let graph = GraphProto {
        node: g.nodes,
        name: name.to_string(),
        initializer: g.initializers,
        doc_string: format!(
            "NeRF {name} network: {}×{} MLP (skips after {:?}), positional encodings inside the graph, view-dependent colour: {}.",
            spec.depth, spec.width, spec.skips, spec.use_viewdirs
        ),
        input: contract_inputs(),
        output: contract_outputs("Volume density (ReLU applied), float32 [N, 1]."),
        value_info: vec![],
    };
    Ok(model_proto(graph, opset, "A neural radiance field network compiled by nerf-rs (nerf export).", props))
}

/// The positional encoding of graph input `input` (`[N, 3]` → `[N, e.output_dim()]`).
fn lower_encoding(g: &mut Builder, input: &str, tag: &str, e: &EncodingSpec) -> String {
    if e.n_frequencies == 0 {
        return input.to_string();
    }
    let l = e.n_frequencies;
    let axes = g.i64_constant("axes.1", &[1]);
    let freqs = g.f32_tensor(&format!("{tag}.frequencies"), &[l, 1], &e.frequencies());
    // Reshape [N, L, 6] → [N, 6L]; 0 copies N, so an empty batch works too.
    let shape = g.i64_constant(&format!("{tag}.shape"), &[0, 6 * l as i64]);
    let unsqueezed = g.node("Unsqueeze", &[input, &axes], &format!("{tag}.unsqueeze"), vec![]);
    let scaled = g.node("Mul", &[&unsqueezed, &freqs], &format!("{tag}.scaled"), vec![]);
    let sin = g.unary("Sin", &scaled, &format!("{tag}.sin"));
    let cos = g.unary("Cos", &scaled, &format!("{tag}.cos"));
    let pairs = g.node("Concat", &[&sin, &cos], &format!("{tag}.sincos"), vec![int_attribute("axis", 2)]);
    let periodic = g.node("Reshape", &[&pairs, &shape], &format!("{tag}.periodic"), vec![]);
    if e.include_input { g.concat(&[input, &periodic], &format!("{tag}.output")) } else { periodic }
}

/// An encoding as `scene.json` states it for other implementations.
pub fn encoding_description(e: &EncodingSpec) -> EncodingDescription {
    EncodingDescription { n_frequencies: e.n_frequencies, include_input: e.include_input, frequencies: e.frequencies(), output_dim: e.output_dim() }
}

fn encoding_text(e: &EncodingSpec) -> String {
    format!(
        "[x, sin(2^k x), cos(2^k x) for k < {}] with include_input={}: {} values per 3-vector",
        e.n_frequencies,
        e.include_input,
        e.output_dim()
    )
}

/// The network description and weights of a model written by [`compile`].
pub fn read_network(model: &ModelProto) -> Result<PlainNetwork, String> {
    let spec_json = metadata(model, NETWORK_KEY).ok_or_else(|| format!("no {NETWORK_KEY} metadata: not a graph written by nerf export"))?;
    let spec: NetworkSpec = serde_json::from_str(spec_json).map_err(|e| format!("{NETWORK_KEY}: {e}"))?;
    spec.validate()?;
    let graph = model.graph.as_ref().ok_or("the model has no graph")?;
    let layers = read_dense_layers(graph, spec.layer_shapes())?;
    Ok(PlainNetwork { spec, layers })
}

/// The coarse and fine networks as bundle graphs (`coarse.onnx`, `fine.onnx`); `scene` learns
/// their encodings.
impl CompileField for PlainMlp {
    fn kind(&self) -> &str {
        FieldKind::Mlp.name()
    }

    fn bounded(&self) -> Option<f32> {
        None
    }

    fn compile(&self, scene: &mut SceneDescription, options: &crate::CompileOptions) -> Result<Vec<(Role, ModelProto)>, ExportError> {
        let PlainMlp { coarse, fine } = self;
        let opset = options.opset_or(self.default_opset());
        if (scene.sampling.n_fine > 0) != fine.is_some() {
            return Err(ExportError::Network("sampling.n_fine and the networks disagree about a fine network".into()));
        }
        scene.position_encoding = Some(encoding_description(&coarse.spec.position_encoding));
        scene.direction_encoding = Some(encoding_description(&coarse.spec.direction_encoding));
        let mut graphs = vec![(Role::Coarse, compile(coarse, "coarse", opset, &scene_metadata(scene, Role::Coarse))?)];
        if let Some(fine) = fine {
            graphs.push((Role::Fine, compile(fine, "fine", opset, &scene_metadata(scene, Role::Fine))?));
        }
        Ok(graphs)
    }
}

/// The plain network stored in a bundle's graph file `file` (`coarse.onnx`, `fine.onnx`).
pub fn read_bundle_network(dir: &Path, file: &str) -> nerf_core::Result<PlainNetwork> {
    let path = bundle_file(dir, file, "graphs")?;
    read_network(&read_model(&path)?).map_err(|e| nerf_core::Error::invalid(&path, e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::builder::DEFAULT_OPSET;
    use nerf_bundle::check_contract;
    use prost::Message;

    fn random_network(use_viewdirs: bool) -> PlainNetwork {
        let spec = NetworkSpec {
            depth: 3,
            width: 8,
            skips: vec![1],
            position_encoding: EncodingSpec { n_frequencies: 2, include_input: true },
            direction_encoding: EncodingSpec { n_frequencies: 1, include_input: false },
            use_viewdirs,
        };
        PlainNetwork::seeded(&spec, 4)
    }

    #[test]
    fn compiled_models_decode_to_the_same_network() {
        for use_viewdirs in [true, false] {
            let net = random_network(use_viewdirs);
            let model = compile(&net, "coarse", DEFAULT_OPSET, &[("nerf.stage".into(), "coarse".into())]).unwrap();
            let bytes = model.encode_to_vec();
            let decoded = ModelProto::decode(bytes.as_slice()).unwrap();
            assert_eq!(decoded, model);
            assert_eq!(read_network(&decoded).unwrap(), net);
            let graph = decoded.graph.unwrap();
            let names: Vec<&str> = graph.input.iter().chain(&graph.output).map(|v| v.name.as_str()).collect();
            assert_eq!(names, ["points", "viewdirs", "rgb", "sigma"]);
            let mut init: Vec<&str> = graph.initializer.iter().map(|t| t.name.as_str()).collect();
            init.sort();
            let before = init.len();
            init.dedup();
            assert_eq!(init.len(), before, "no initializer is stored twice");
            assert!(graph.node.iter().any(|n| n.op_type == "Sin") && graph.node.iter().any(|n| n.op_type == "Cos"));
            assert!(decoded.metadata_props.iter().any(|p| p.key == "nerf.stage"));
            check_contract(&model).unwrap();
        }
    }

    #[test]
    fn contract_violations_are_named() {
        let model = compile(&random_network(true), "coarse", DEFAULT_OPSET, &[]).unwrap();
        let mut renamed = model.clone();
        renamed.graph.as_mut().unwrap().input[1].name = "dirs".into();
        let err = check_contract(&renamed).unwrap_err();
        assert!(err.contains("inputs") && err.contains("dirs") && err.contains("viewdirs"), "{err}");
        let mut wide = model.clone();
        let sigma = &mut wide.graph.as_mut().unwrap().output[1];
        let Some(type_proto::Value::TensorType(t)) = sigma.r#type.as_mut().unwrap().value.as_mut() else { panic!() };
        t.shape.as_mut().unwrap().dim[1].value = Some(tensor_shape_proto::dimension::Value::DimValue(2));
        let err = check_contract(&wide).unwrap_err();
        assert!(err.contains("output sigma") && err.contains("[N, 1]"), "{err}");
        let mut typed = model;
        let points = &mut typed.graph.as_mut().unwrap().input[0];
        let Some(type_proto::Value::TensorType(t)) = points.r#type.as_mut().unwrap().value.as_mut() else { panic!() };
        t.elem_type = data_type::INT64;
        let err = check_contract(&typed).unwrap_err();
        assert!(err.contains("input points") && err.contains("float32"), "{err}");
    }

    #[test]
    fn opsets_and_ir_versions() {
        let net = random_network(true);
        assert_eq!(compile(&net, "x", 17, &[]).unwrap().ir_version, 8);
        assert_eq!(compile(&net, "x", 21, &[]).unwrap().ir_version, 10);
        let err = compile(&net, "x", 13, &[]).unwrap_err().to_string();
        assert!(err.contains("opset 13"), "{err}");
        let mut broken = net.clone();
        broken.layers[2].bias.pop();
        assert!(matches!(compile(&broken, "x", 17, &[]), Err(ExportError::Network(_))));
    }
}
