//! burn ↔ onnxruntime parity: the exported graphs compute what the burn networks compute
//! (network level, ≤ 1e-5), and `nerf render` (burn) and `nerf-render` (onnxruntime) render the
//! same images (≥ 60 dB between them) on the generated scene and on lego.

mod common;

use common::{lego_dir, max_difference, nerf, nerf_render, s, tiny_config, trained_run};
use nerf::bench::random_points;
use nerf::field::mlp::NerfMlp;
use nerf::inference::{tensor_vec3, vec3_tensor};
use nerf::train::{TrainOptions, train};
use nerf_core::frames::raw::load_npy;
use nerf_core::render::metrics::psnr;
use nerf_core::field::mlp::{NetworkSpec, PlainNetwork};
use nerf_runtime::OrtNetwork;
use prost::Message;
use std::path::Path;

/// Compile `net`, run both on 12,000 points, return (max |Δrgb|, max |Δσ|, max σ).
fn network_difference(net: &NerfMlp, dir: &Path) -> (f32, f32, f32) {
    let path = dir.join(format!("net-{}.onnx", net.spec().width));
    let model = nerf_export::field::mlp::compile(&net.to_plain(), "coarse", nerf_export::DEFAULT_OPSET, &[]).unwrap();
    std::fs::write(&path, model.encode_to_vec()).unwrap();
    let mut ort = OrtNetwork::load(&path, None).unwrap();
    let (points, dirs) = random_points(12_000, 7);
    let ort_out = ort.run(&points, &dirs).unwrap();
    let device = nerf::backend::cpu();
    let (rgb, sigma) = net.forward(vec3_tensor(&points, &device), vec3_tensor(&dirs, &device));
    let burn_rgb = tensor_vec3(rgb);
    let burn_sigma: Vec<f32> = sigma.into_data().try_to_vec::<f32>().unwrap().iter().map(|s| s.max(0.0)).collect();
    let d_rgb = max_difference("rgb", burn_rgb.as_flattened(), ort_out.rgb.as_flattened(), |_| 1.0);
    let d_sigma = max_difference("σ", &burn_sigma, &ort_out.sigma, |_| 1.0);
    (d_rgb, d_sigma, burn_sigma.iter().copied().fold(0.0, f32::max))
}

#[test]
fn networks_agree_paper_size_and_small() {
    let dir = tempfile::tempdir().unwrap();
    let device = nerf::backend::cpu();
    // The paper network with seeded PyTorch-style weights, its σ head scaled ×100 so that
    // densities reach trained magnitudes (≈ 10; a fresh head gives ≈ 0.01, which would make
    // 1e-5 lenient).
    let mut plain = PlainNetwork::seeded(&NetworkSpec::paper(), 11);
    let sigma = plain.layers.iter_mut().find(|l| l.name == "sigma").unwrap();
    sigma.weight.iter_mut().chain(sigma.bias.iter_mut()).for_each(|w| *w *= 100.0);
    let paper = NerfMlp::from_plain(&plain, &device).unwrap();
    let (d_rgb, d_sigma, max_sigma) = network_difference(&paper, dir.path());
    println!("paper network: max |Δrgb| {d_rgb:.2e}, max |Δσ| {d_sigma:.2e} (σ up to {max_sigma:.3})");
    assert!(d_rgb <= 1e-5 && d_sigma <= 1e-5, "paper network: max |Δrgb| {d_rgb:e}, |Δσ| {d_sigma:e}");
    assert!(max_sigma > 1.0, "σ stays below 1 ({max_sigma}): the comparison would be lenient");
    // A small network after some training (larger densities).
    let (_, run) = trained_run(dir.path());
    let model = nerf::field::load_latest(&nerf::run_dir::RunDir::open(&run).unwrap(), &device).unwrap().model.as_any().downcast_ref::<nerf::field::mlp::NerfModel>().unwrap().clone();
    let (d_rgb, d_sigma, max_sigma) = network_difference(model.fine.as_ref().unwrap(), dir.path());
    println!("small network: max |Δrgb| {d_rgb:.2e}, max |Δσ| {d_sigma:.2e} (σ up to {max_sigma:.3})");
    assert!(d_rgb <= 1e-5 && d_sigma <= 1e-5, "small network: max |Δrgb| {d_rgb:e}, |Δσ| {d_sigma:e}");
    assert!(max_sigma > 0.1, "σ stays below 0.1 ({max_sigma})");
}

/// Render `split` view 0 through `nerf render --npy` (burn) and `nerf-render --npy`
/// (onnxruntime, from the exported bundle): (PSNR between them, largest deviation from white).
fn image_parity(run: &Path, data: &Path, split: &str, downscale: u32, name: &str, dir: &Path) -> (f32, f32) {
    let bundle = dir.join("bundle");
    let (ok, text) = nerf(&["export", "--run", s(run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    let burn_out = dir.join("burn");
    let ds = downscale.to_string();
    let (ok, text) = nerf(&["render", "--run", s(run), "--split", split, "--data", s(data), "--downscale", &ds, "--out", s(&burn_out), "--npy"]);
    assert!(ok, "{text}");
    let ort_out = dir.join("ort");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--split", split, "--data", s(data), "--downscale", &ds, "--limit", "1", "--out", s(&ort_out), "--npy"]);
    assert!(ok, "{text}");
    let (h1, w1, a) = load_npy(&burn_out.join(format!("{name}.npy"))).unwrap();
    let (h2, w2, b) = load_npy(&ort_out.join(format!("{name}.npy"))).unwrap();
    assert_eq!((h1, w1), (h2, w2));
    let rgb = |v: &[f32]| v.chunks_exact(5).map(|p| [p[0], p[1], p[2]]).collect::<Vec<_>>();
    let (a, b) = (rgb(&a), rgb(&b));
    let off_white = a.iter().flatten().map(|v| (1.0 - v).abs()).fold(0.0, f32::max);
    (psnr(&a, &b), off_white)
}

#[test]
fn burn_and_onnxruntime_render_the_same_generated_scene() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, run) = trained_run(dir.path());
    let (db, off_white) = image_parity(&run, &scene, "test", 1, "r_0", dir.path());
    println!("generated scene: burn vs onnxruntime {db:.1} dB");
    assert!(off_white > 0.05, "the image is blank: parity would mean nothing");
    assert!(db >= 60.0, "burn vs onnxruntime: {db:.1} dB");
}

#[test]
fn burn_and_onnxruntime_render_the_same_lego_view() {
    let lego = lego_dir();
    assert!(lego.join("transforms_train.json").is_file(), "{} is missing (CI provides ../shared)", lego.display());
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let mut config = tiny_config();
    config.iters = 30;
    train(&TrainOptions { format: None, data: lego.clone(), run: run.clone(), config, ndc: None, contract: None, downscale: 8, time_budget_min: None, iters: None, progress: false })
        .unwrap();
    let (db, off_white) = image_parity(&run, &lego, "val", 8, "r_0", dir.path());
    println!("lego: burn vs onnxruntime {db:.1} dB");
    assert!(off_white > 0.05, "the image is blank: parity would mean nothing");
    assert!(db >= 60.0, "burn vs onnxruntime on lego: {db:.1} dB");
}
