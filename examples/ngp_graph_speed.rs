//! Points per second of a default-size hash-grid field graph in onnxruntime, and its parity
//! with the Rust encoding + burn MLPs on the same points.
//!
//! `cargo run --release --example ngp_graph_speed [opset] [points]` (defaults 18, 65536; opset
//! 17 is the bitwise-free lowering). A U(−1, 1) table, so every lookup matters; 2 intra-op
//! threads; best of 3 after one warm-up call. `NGP_GRAPH=<file>` also keeps the graph (for
//! onnxruntime's profiler). Compare figures from one run: the machine may be shared.

use nerf::bench::{best_of, random_points};
use nerf::field::ngp::NgpField;
use nerf_bundle::scene::SceneDescription;
use nerf_core::field::ngp::NgpSpec;
use nerf_core::{Intrinsics, PinholeCamera, Rng, SamplingConfig};
use nerf_export::CompileField;
use nerf_runtime::OrtNetwork;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let opset: i64 = args.first().map(|a| a.parse()).transpose()?.unwrap_or(18);
    let n: usize = args.get(1).map(|a| a.parse()).transpose()?.unwrap_or(1 << 16);
    let device = nerf::backend::cpu();
    let mut field = NgpField::new(NgpSpec::default(), 7, &device)?;
    let mut rng = Rng::new(3);
    field.grid.params_mut().iter_mut().for_each(|p| *p = rng.uniform() * 2.0 - 1.0);
    let camera = PinholeCamera::from(Intrinsics { width: 4, height: 4, focal: 4.0 });
    let sampling = SamplingConfig { near: 2.0, far: 6.0, n_coarse: 64, n_fine: 0, lindisp: false, ndc: None };
    let mut scene = SceneDescription::new(&camera, &sampling, true, 256);
    let graphs = field.to_plain().compile(&mut scene, &nerf_export::CompileOptions { opset: Some(opset), ..Default::default() })?;
    let dir = tempfile::tempdir()?;
    let path = dir.path().join("field.onnx");
    std::fs::write(&path, prost::Message::encode_to_vec(&graphs[0].1))?;
    if let Some(keep) = std::env::var_os("NGP_GRAPH") {
        std::fs::copy(&path, keep)?;
    }
    let (points, dirs) = random_points(n, 5);
    let mut net = OrtNetwork::load(&path, Some(2))?;
    let seconds = best_of(3, || net.run(&points, &dirs).map(|_| ()))?;
    let out = net.run(&points, &dirs)?;
    let (rgb, sigma) = field.forward(&points, &dirs);
    let d_rgb = rgb.iter().flatten().zip(out.rgb.iter().flatten()).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    let d_sigma = sigma.iter().zip(&out.sigma).map(|(a, b)| (a - b).abs() / a.abs().max(1.0)).fold(0.0f32, f32::max);
    println!("opset {opset}: {n} points in {seconds:.3} s = {:.0} points/s; max |Δrgb| {d_rgb:.1e}, max |Δσ|/max(1, σ) {d_sigma:.1e}", n as f64 / seconds);
    Ok(())
}
