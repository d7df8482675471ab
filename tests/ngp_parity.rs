//! burn ↔ onnxruntime parity for the hash-grid field: the exported graph (hash grid, harmonics
//! and both MLPs inside) computes what [`NgpField`] computes on 12,000 random points, within
//! 1e-5 (σ = exp(raw) relative to max(1, σ)), with σ well above 1 somewhere; and nerf-render's
//! split path (the Rust encoding, the graph's head in onnxruntime) computes what the whole
//! graph computes, on points and on a frame of the shipped bundle.

mod common;

use common::max_difference;
use nerf::bench::random_points;
use nerf::field::ngp::NgpField;
use nerf_core::Rng;
use nerf_core::field::ngp::hash_grid::HashGridConfig;
use nerf_core::field::ngp::NgpSpec;
use nerf_export::field::ngp::hash_grid::HashOps;
use nerf_export::field::ngp::hash_grid::table::TablePrecision;
use nerf_runtime::network::{Encoding, Threading};
use nerf_runtime::{OpenOptions, OrtNetwork, OrtScene};
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

#[test]
fn the_split_path_matches_the_whole_graph() {
    let grid = HashGridConfig { log2_table_size: 17, ..HashGridConfig::default() };
    let (plain, _) = trained_like(grid);
    let (points, dirs) = random_points(12_000, 9);
    // A third of the points outside the box: both clamp them to its faces.
    let points: Vec<[f32; 3]> = points.iter().enumerate().map(|(i, p)| if i % 3 == 0 { p.map(|x| x * 1.4) } else { *p }).collect();
    let dir = tempfile::tempdir().unwrap();
    for (ops, opset, precision) in [(HashOps::Bitwise, 18, TablePrecision::F32), (HashOps::Portable, 17, TablePrecision::F32), (HashOps::Bitwise, 18, TablePrecision::F16)] {
        let path = dir.path().join(format!("{ops:?}{precision:?}.onnx"));
        let model = nerf_export::field::ngp::compile_ngp(&plain, "field", opset, ops, precision, &[]).unwrap();
        std::fs::write(&path, model.encode_to_vec()).unwrap();
        let mut whole = OrtNetwork::load_with(&path, Threading::new(None), Encoding::Graph).unwrap();
        let mut split = OrtNetwork::load_with(&path, Threading::new(None), Encoding::Rust).unwrap();
        assert_eq!((whole.encoding(), split.encoding()), (Encoding::Graph, Encoding::Rust));
        let (a, b) = (whole.run(&points, &dirs).unwrap(), split.run(&points, &dirs).unwrap());
        let d_rgb = max_difference("rgb", a.rgb.as_flattened(), b.rgb.as_flattened(), |_| 1.0);
        let d_sigma = max_difference("σ", &a.sigma, &b.sigma, |x| x.abs().max(1.0));
        println!("split vs whole graph ({ops:?}, {precision:?} table): max |Δrgb| {d_rgb:.2e}, max |Δσ|/max(1, σ) {d_sigma:.2e}");
        assert!(d_rgb <= 1e-5 && d_sigma <= 1e-5, "max |Δrgb| {d_rgb:e}, relative |Δσ| {d_sigma:e}");
        assert!(split.encoding_seconds > 0.0, "the split path did not encode in Rust");
    }
    // A graph whose features are not named (as before the cut existed) runs whole.
    let mut model = nerf_export::field::ngp::compile_ngp(&plain, "field", 18, HashOps::Bitwise, TablePrecision::F32, &[]).unwrap();
    for node in &mut model.graph.as_mut().unwrap().node {
        node.output.iter_mut().chain(node.input.iter_mut()).filter(|t| *t == nerf_bundle::ngp::FEATURES_TENSOR).for_each(|t| *t = "grid.old_features".into());
    }
    let path = dir.path().join("old.onnx");
    std::fs::write(&path, model.encode_to_vec()).unwrap();
    let mut old = OrtNetwork::load_with(&path, Threading::new(None), Encoding::Rust).unwrap();
    assert_eq!(old.encoding(), Encoding::Graph);
    assert_eq!(old.run(&points[..10], &dirs[..10]).unwrap().sigma.len(), 10);
}

#[test]
fn the_shipped_bundle_renders_the_same_frame_split() {
    let bundle = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/lego-ngp");
    let mut frames = Vec::new();
    for whole_graph in [true, false] {
        let mut scene = OrtScene::open(&bundle, &OpenOptions { whole_graph, ..OpenOptions::default() }).unwrap();
        let encoding = scene.field.graphs[0].1.encoding();
        assert_eq!(encoding, if whole_graph { Encoding::Graph } else { Encoding::Rust });
        let camera = scene.camera(Some((100, 100)));
        let pose = scene.orbit_poses().unwrap()[3];
        frames.push(scene.render(&camera, &pose, &mut |_, _| {}).unwrap());
    }
    let db = nerf_core::render::metrics::psnr(&frames[0].rays.rgb, &frames[1].rays.rgb);
    let d = max_difference("rgb", frames[0].rays.rgb.as_flattened(), frames[1].rays.rgb.as_flattened(), |_| 1.0);
    println!("lego-ngp 100×100 frame, split vs whole graph: {db:.1} dB, max |Δrgb| {d:.2e}");
    assert!(db >= 60.0, "{db} dB");
    assert!(frames[0].rays.rgb.as_flattened().iter().any(|&v| v < 0.5), "an empty frame would compare equal");
}

/// A field of `grid` with trained-like magnitudes, and burn's copy of it.
fn trained_like(grid: HashGridConfig) -> (nerf_core::field::ngp::PlainNgp, NgpField) {
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
    (plain, field)
}

fn parity(grid: HashGridConfig, ops: HashOps, opset: i64) {
    let (plain, field) = trained_like(grid);

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
