//! Compiling a hash-grid field ([`PlainNgp`]) into one ONNX graph with the NeRF graph contract
//! (`points`, `viewdirs` `[N, 3]` in; `rgb [N, 3]`, `sigma [N, 1]` out), so the renderers load it
//! like any other network:
//!
//! `points` → hash grid ([`crate::hash_grid`], table as one initializer) → `Gemm` → `Relu` →
//! `Gemm` → first column `Exp` = `sigma`; the other columns `Concat` the harmonics of
//! `viewdirs` → `Gemm` → `Relu` → `Gemm` → `Relu` → `Gemm` → `Sigmoid` = `rgb`.
//! The MLPs are bias-free; their `Gemm`s add zero biases (exact).

use crate::ExportError;
pub mod hash_grid;

use crate::builder::{Builder, contract_inputs, contract_outputs, scene_metadata};
use nerf_bundle::scene::SceneDescription;
use crate::field::CompileField;
use nerf_core::field::{FieldKind, Role};
use hash_grid::table::TablePrecision;
use hash_grid::{HashOps, check_opset, lower_hash_grid, lower_sh4, model, slice};
use crate::proto::*;
use nerf_core::field::ngp::hash_grid::HashGrid;
use nerf_core::field::ngp::PlainNgp;

pub use nerf_bundle::ngp::{FIELD_KEY, NGP_KEY};

/// Compile `field` into a model named `name`; `metadata` is added to the contract entries.
pub fn compile_ngp(field: &PlainNgp, name: &str, opset: i64, ops: HashOps, precision: TablePrecision, metadata: &[(String, String)]) -> Result<ModelProto, ExportError> {
    check_opset(opset, ops)?;
    field.validate().map_err(|e| ExportError::Network(e.to_string()))?;
    let spec = &field.spec;
    let grid = HashGrid::from_params(spec.grid, field.table.clone()).map_err(|e| ExportError::Network(e.to_string()))?;
    let mut g = Builder::default();
    let features = lower_hash_grid(&mut g, "points", &grid, &spec.bound, ops, precision)?;
    let [d0, d1, c0, c1, c2] = [0, 1, 2, 3, 4].map(|i| &field.layers[i]);
    let h = g.dense(d0, &features, Some("Relu"));
    let out = g.dense(d1, &h, None);
    let raw_sigma = slice(&mut g, &out, (0, 1), 1, "density.raw_sigma");
    g.unary("Exp", &raw_sigma, "sigma");
    let geometry = slice(&mut g, &out, (1, 1 + spec.geometry_features as i64), 1, "density.geometry");
    let sh = lower_sh4(&mut g, "viewdirs");
    let color_in = g.concat(&[&geometry, &sh], "color.input");
    let c = g.dense(c0, &color_in, Some("Relu"));
    let c = g.dense(c1, &c, Some("Relu"));
    let rgb_raw = g.dense(c2, &c, None);
    g.unary("Sigmoid", &rgb_raw, "rgb");

    let graph = GraphProto {
        node: g.nodes,
        name: name.to_string(),
        initializer: g.initializers,
        doc_string: format!(
            "Hash-grid radiance field {name}: {} levels × {} features (T = 2^{}), density MLP {}→{}→{}, colour MLP {}→{}→{}→3; σ = exp.",
            spec.grid.levels,
            spec.grid.features_per_level,
            spec.grid.log2_table_size,
            spec.grid.output_dim(),
            spec.density_hidden,
            1 + spec.geometry_features,
            spec.geometry_features + 16,
            spec.color_hidden,
            spec.color_hidden
        ),
        input: contract_inputs(),
        output: contract_outputs("Volume density (exp applied, ≥ 0), float32 [N, 1]."),
        value_info: vec![],
    };
    let mut model = model(graph, opset, &grid, &spec.bound, ops, precision);
    let mut props = vec![
        ("nerf.contract".to_string(), "inputs points [N,3] float32 world positions, viewdirs [N,3] float32 unit view directions; outputs rgb [N,3] float32 in [0,1] (sigmoid applied), sigma [N,1] float32 (exp applied); N is dynamic".to_string()),
        (FIELD_KEY.to_string(), "ngp".to_string()),
        (NGP_KEY.to_string(), serde_json::to_string(spec).expect("a spec serialises")),
    ];
    props.extend(metadata.iter().cloned());
    model.metadata_props.extend(props.into_iter().map(|(key, value)| StringStringEntryProto { key, value }));
    Ok(model)
}

/// The opset used when none is asked for: the lowest with BitwiseXor (17 lowers the hash
/// without bitwise operators).
pub const DEFAULT_OPSET: i64 = HashOps::Bitwise.min_opset();

/// The field as a bundle's one graph (`field.onnx`): the bitwise lowering at opset ≥ 18, the
/// portable one when asked for or at 17; `scene` learns it has no fine stage.
impl CompileField for PlainNgp {
    fn kind(&self) -> &str {
        FieldKind::Ngp.name()
    }

    fn bounded(&self) -> Option<f32> {
        Some(self.spec.bound.enclosing_half_size())
    }

    fn contraction(&self) -> Option<nerf_core::sample::Contraction> {
        self.spec.bound.contraction
    }

    fn default_opset(&self) -> i64 {
        DEFAULT_OPSET
    }

    fn compile(&self, scene: &mut SceneDescription, options: &crate::CompileOptions) -> Result<Vec<(Role, ModelProto)>, ExportError> {
        scene.sampling.n_fine = 0;
        let opset = options.opset_or(DEFAULT_OPSET);
        let ops = if options.portable || opset < HashOps::Bitwise.min_opset() { HashOps::Portable } else { HashOps::Bitwise };
        Ok(vec![(Role::Field, compile_ngp(self, "field", opset, ops, options.tables, &scene_metadata(scene, Role::Field))?)])
    }
}

pub use nerf_bundle::ngp::read_ngp;
