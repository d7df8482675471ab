//! burn ↔ onnxruntime parity for the hash-grid field: the exported graph (hash grid, harmonics
//! and both MLPs inside) computes what [`NgpField`] computes on 12,000 random points, within
//! 1e-5 (σ = exp(raw) relative to max(1, σ)), with σ well above 1 somewhere.

mod common;

use common::max_difference;
use nerf::bench::random_points;
use nerf::field::ngp::NgpField;
use nerf_core::Rng;
use nerf_core::field::ngp::hash_grid::HashGridConfig;
use nerf_core::field::ngp::NgpSpec;
use nerf_export::field::ngp::hash_grid::HashOps;
use nerf_export::field::ngp::hash_grid::table::TablePrecision;
use nerf_runtime::OrtNetwork;
use prost::Message;

#[test]
fn ngp_field_graph_matches_burn() {
    let grid = HashGridConfig { log2_table_size: 17, ..HashGridConfig::default() };
    parity(grid, HashOps::Bitwise, 18);
    parity(grid, HashOps::Portable, 17);
}

#[test]
fn a_wide_grid_matches_burn() {
    // Products up to 4097 · (2²² − 1) > 2³¹ in the hash: the lookup tables hold them mod T.
    let grid = HashGridConfig { levels: 4, log2_table_size: 22, max_resolution: 4096, ..HashGridConfig::default() };
    parity(grid, HashOps::Bitwise, 18);
    parity(grid, HashOps::Portable, 17);
}

fn parity(grid: HashGridConfig, ops: HashOps, opset: i64) {
    let device = nerf::backend::cpu();
    device.seed(21);
    let spec = NgpSpec { grid, ..NgpSpec::default() };
    let field = NgpField::new(spec, 3, &device).unwrap();
    // Trained-like magnitudes: a U(−1, 1) table, weights U(±2/√fan_in) and σ's layer ×4, so
    // that σ = exp(raw) spans orders of magnitude (a fresh field gives σ ≈ 1 everywhere).
    let mut plain = field.to_plain();
    let mut rng = Rng::new(4);
    plain.table.iter_mut().for_each(|p| *p = rng.uniform() * 2.0 - 1.0);
    for layer in &mut plain.layers {
        let a = if layer.name == "density.1" { 8.0 } else { 2.0 } / (layer.in_dim as f32).sqrt();
        layer.weight.iter_mut().for_each(|w| *w = (rng.uniform() * 2.0 - 1.0) * a);
    }
    let field = NgpField::from_plain(&plain, &device).unwrap();

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("field.onnx");
    let model = nerf_export::field::ngp::compile_ngp(&plain, "field", opset, ops, TablePrecision::F32, &[]).unwrap();
    std::fs::write(&path, model.encode_to_vec()).unwrap();
    let mut ort = OrtNetwork::load(&path, None).unwrap();
    let (points, dirs) = random_points(12_000, 8);
    let ort_out = ort.run(&points, &dirs).unwrap();
    let (burn_rgb, burn_sigma) = field.forward(&points, &dirs);
    let d_rgb = max_difference("rgb", burn_rgb.as_flattened(), ort_out.rgb.as_flattened(), |_| 1.0);
    let d_sigma = max_difference("σ", &burn_sigma, &ort_out.sigma, |a| a.abs().max(1.0));
    let max_sigma = burn_sigma.iter().copied().fold(0.0, f32::max);
    println!("ngp field ({ops:?}): max |Δrgb| {d_rgb:.2e}, max |Δσ|/max(1, σ) {d_sigma:.2e} (σ up to {max_sigma:.1})");
    assert!(d_rgb <= 1e-5 && d_sigma <= 1e-5, "max |Δrgb| {d_rgb:e}, relative |Δσ| {d_sigma:e}");
    assert!(max_sigma > 10.0, "σ stays below 10 ({max_sigma}): the comparison would be lenient");
}
