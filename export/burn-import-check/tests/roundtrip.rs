//! The committed bundle's graphs, imported by burn-import at build time, compute what our burn
//! model computes with the same weights (read back from the graphs' initializers).

use burn::tensor::activation::relu;
use burn::tensor::{Tensor, TensorData};
use nerf::field::mlp::NerfMlp;
use nerf_core::Rng;
use std::path::Path;

const POINTS: usize = 12_000;

fn max_abs_diff(a: Tensor<2>, b: Tensor<2>) -> f32 {
    let (a, b) = (a.into_data().try_to_vec::<f32>().unwrap(), b.into_data().try_to_vec::<f32>().unwrap());
    assert_eq!(a.len(), b.len());
    a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

#[test]
fn imported_graphs_match_our_burn_model() {
    let device = burn::tensor::Device::flex();
    let bundle = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/spheres");
    let mut rng = Rng::new(9);
    // Points across the scene cube (and a little beyond), unit directions.
    let points: Vec<f32> = (0..3 * POINTS).map(|_| rng.uniform() * 4.0 - 2.0).collect();
    let dirs: Vec<f32> = (0..POINTS)
        .flat_map(|_| {
            let v = [0; 3].map(|_: i32| rng.uniform() * 2.0 - 1.0);
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-3);
            v.map(|x| x / n)
        })
        .collect();
    let tensor = |v: &[f32]| Tensor::<2>::from_data(TensorData::new(v.to_vec(), [POINTS, 3]), &device);

    for file in ["coarse.onnx", "fine.onnx"] {
        let plain = nerf_export::field::mlp::read_bundle_network(&bundle, file).unwrap();
        let ours = NerfMlp::from_plain(&plain, &device).unwrap();
        let (rgb, raw_sigma) = ours.forward(tensor(&points), tensor(&dirs));
        let sigma = relu(raw_sigma).reshape([POINTS, 1]);
        let (imported_rgb, imported_sigma) = match file {
            "coarse.onnx" => nerf_burn_import_check::coarse::Model::default().forward(tensor(&points), tensor(&dirs)),
            _ => nerf_burn_import_check::fine::Model::default().forward(tensor(&points), tensor(&dirs)),
        };
        assert_eq!(imported_sigma.dims(), [POINTS, 1]);
        let sigma_max = sigma.clone().max().into_scalar::<f32>();
        let (d_rgb, d_sigma) = (max_abs_diff(rgb, imported_rgb), max_abs_diff(sigma, imported_sigma));
        println!("{file}: max |Δrgb| = {d_rgb:.2e}, max |Δσ| = {d_sigma:.2e} over {POINTS} points");
        assert!(d_rgb <= 1e-5 && d_sigma <= 1e-5, "{file}: rgb differs by {d_rgb}, sigma by {d_sigma}");
        // The densities must not all be zero, or the σ comparison would prove little.
        assert!(sigma_max > 1.0, "{file}: no density anywhere (max σ {sigma_max})");
    }
}
