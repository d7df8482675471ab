//! The hash-grid, spherical-harmonics and whole-field lowerings against the Rust evaluations:
//! onnx.checker (full), strict shape inference and onnxruntime (Python,
//! `tests/python/check_hash_grid.py`) on 12,000 random points, within 1e-5 (σ relative to
//! max(1, σ)), for the bitwise lowering, the portable one and a float16 table.

use nerf_core::Rng;
use nerf_core::field::ngp::hash_grid::{GridBound, HashGrid, HashGridConfig};
use nerf_core::field::ngp::spherical_harmonics::sh4_all;
use nerf_core::field::DenseLayer;
use nerf_core::field::ngp::{NgpSpec, PlainNgp};
use nerf_export::field::ngp::hash_grid::table::{TablePrecision, f16_bytes, f16_values};
use nerf_export::field::ngp::hash_grid::{HashOps, compile_encodings};
use nerf_export::field::ngp::compile_ngp;
use prost::Message;
use std::path::Path;
use std::process::Command;

fn python() -> String {
    std::env::var("NERF_PYTHON").unwrap_or_else(|_| "python3".into())
}

/// A grid whose table spans U(−1, 1) (a fresh U(±1e-4) table would make 1e-5 lenient).
fn grid(config: HashGridConfig) -> HashGrid {
    let mut grid = HashGrid::new(config, 5).unwrap();
    let mut rng = Rng::new(6);
    grid.params_mut().iter_mut().for_each(|p| *p = rng.uniform() * 2.0 - 1.0);
    grid
}

/// Write `model` and `reference` to `dir` and run the Python check on them.
fn python_check(model: &nerf_export::proto::ModelProto, reference: serde_json::Value, name: &str, dir: &Path) {
    let path = dir.join(format!("{name}.onnx"));
    std::fs::write(&path, model.encode_to_vec()).unwrap();
    let ref_path = dir.join(format!("{name}.json"));
    std::fs::write(&ref_path, reference.to_string()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/python/check_hash_grid.py");
    let out = Command::new(python())
        .args([script.as_os_str(), path.as_os_str(), ref_path.as_os_str()])
        .output()
        .unwrap_or_else(|e| panic!("cannot run {} ({e}): run scripts/setup.sh and source scripts/env.sh", python()));
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    println!("{text}");
    assert!(out.status.success(), "{text}");
}

/// `n` points a little beyond `bound` on every side (the clamp is part of the check; for a
/// contracted bound, every other point pushed out up to 1000× farther) and unit directions.
fn inputs(bound: &GridBound, n: usize) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let mut rng = Rng::new(7);
    let points = (0..n)
        .map(|i| {
            let p = [0, 1, 2].map(|d| bound.min[d] - 0.1 + (bound.max[d] - bound.min[d] + 0.2) * rng.uniform());
            let far = if bound.contraction.is_some() && i % 2 == 0 { 10f32.powf(3.0 * rng.uniform()) } else { 1.0 };
            p.map(|v| v * far)
        })
        .collect();
    let dirs = (0..n)
        .map(|_| {
            let v = [0; 3].map(|_| rng.uniform() * 2.0 - 1.0);
            let norm = v.iter().map(|c| c * c).sum::<f32>().sqrt();
            v.map(|c| c / norm)
        })
        .collect();
    (points, dirs)
}

fn check_encodings(grid: &HashGrid, bound: &GridBound, ops: HashOps, precision: TablePrecision, opset: i64, n: usize, dir: &Path) {
    let model = compile_encodings(grid, bound, ops, precision, opset).unwrap();
    let (points, dirs) = inputs(bound, n);
    let unit: Vec<[f32; 3]> = points.iter().map(|&p| bound.to_unit(p)).collect();
    let reference = serde_json::json!({
        "inputs": { "points": points, "viewdirs": dirs },
        "outputs": {
            "features": { "values": grid.forward(&unit).chunks(grid.output_dim()).collect::<Vec<_>>(), "min_scale": 0.5 },
            "sh": { "values": sh4_all(&dirs).chunks(16).collect::<Vec<_>>() },
        },
        "tolerance": 1e-5,
        "bitwise": ops == HashOps::Bitwise,
    });
    python_check(&model, reference, &format!("encodings-{ops:?}-{precision:?}"), dir);
}

#[test]
fn encodings_graph_matches_the_rust_encodings() {
    let dir = tempfile::tempdir().unwrap();
    // Dense coarse levels, hashed fine ones up to resolution 2048 (large hash products).
    let config = HashGridConfig { levels: 16, features_per_level: 2, log2_table_size: 14, base_resolution: 16, max_resolution: 2048 };
    let g = grid(config);
    assert!(g.levels().iter().any(|l| l.dense) && g.levels().iter().any(|l| !l.dense));
    let bound = GridBound { min: [-1.5, -1.5, -1.0], max: [1.5, 1.5, 2.0], contraction: None };
    check_encodings(&g, &bound, HashOps::Bitwise, TablePrecision::F32, 18, 12_000, dir.path());
    // The bitwise-free lowering, on the same grid and on one with 4 features and 2 chunks of bits.
    check_encodings(&g, &bound, HashOps::Portable, TablePrecision::F32, 17, 12_000, dir.path());
    let small = grid(HashGridConfig { levels: 8, features_per_level: 4, log2_table_size: 12, base_resolution: 8, max_resolution: 512 });
    check_encodings(&small, &bound, HashOps::Portable, TablePrecision::F32, 17, 3_000, dir.path());
    // Contracted (both lowerings): the same f32 contraction as the Rust encoding's.
    let contracted = GridBound::contracted(nerf_core::sample::Contraction::Linf);
    check_encodings(&g, &contracted, HashOps::Bitwise, TablePrecision::F32, 18, 12_000, dir.path());
    check_encodings(&g, &contracted, HashOps::Portable, TablePrecision::F32, 17, 12_000, dir.path());
    // A float16 table computes the Rust encoding of the table rounded to float16.
    let mut rounded = g.clone();
    let values = f16_values(&f16_bytes(rounded.params())).unwrap();
    rounded.params_mut().copy_from_slice(&values);
    check_encodings(&rounded, &bound, HashOps::Bitwise, TablePrecision::F16, 18, 12_000, dir.path());
}

#[test]
fn field_graph_matches_the_plain_field() {
    let dir = tempfile::tempdir().unwrap();
    let spec = NgpSpec {
        grid: HashGridConfig { levels: 16, features_per_level: 2, log2_table_size: 14, base_resolution: 16, max_resolution: 2048 },
        bound: GridBound::cube(1.5),
        density_hidden: 64,
        geometry_features: 15,
        color_hidden: 64,
    };
    // Weights U(±2/√fan_in) (σ's layer ×4) and a U(−1, 1) table: σ = exp(raw) spans orders of
    // magnitude, as after training (a fresh field gives σ ≈ 1).
    let mut rng = Rng::new(9);
    let layers = spec
        .layer_shapes()
        .into_iter()
        .map(|(name, in_dim, out_dim)| {
            let a = if name == "density.1" { 8.0 } else { 2.0 } / (in_dim as f32).sqrt();
            let weight = (0..in_dim * out_dim).map(|_| (rng.uniform() * 2.0 - 1.0) * a).collect();
            DenseLayer { name, in_dim, out_dim, weight, bias: vec![0.0; out_dim] }
        })
        .collect();
    let field = PlainNgp { spec, table: grid(spec.grid).params().to_vec(), layers };
    let model = compile_ngp(&field, "field", 18, HashOps::Bitwise, TablePrecision::F32, &[]).unwrap();
    nerf_bundle::check_contract(&model).unwrap();
    assert!(model.metadata_props.iter().any(|p| p.key == nerf_export::field::ngp::FIELD_KEY && p.value == "ngp"));
    let mut short = field.clone();
    short.table.pop();
    let err = compile_ngp(&short, "field", 18, HashOps::Bitwise, TablePrecision::F32, &[]).unwrap_err().to_string();
    assert!(err.contains("table has"), "{err}");
    let (points, dirs) = inputs(&spec.bound, 12_000);
    let (rgb, sigma) = field.forward(&points, &dirs).unwrap();
    let reference = serde_json::json!({
        "inputs": { "points": points, "viewdirs": dirs },
        "outputs": {
            "rgb": { "values": rgb },
            "sigma": { "values": sigma.iter().map(|s| [*s]).collect::<Vec<_>>(), "relative": true, "min_scale": 5.0 },
        },
        "tolerance": 1e-5,
        "bitwise": true,
    });
    python_check(&model, reference, "field", dir.path());
}
