use super::*;
use crate::field::ngp::NgpField;
use burn::optim::{AdamConfig, GradientsParams};
use nerf_core::Rng;
use nerf_core::field::ngp::hash_grid::{GridBound, HashGridConfig};

/// Narrow widths (a fast test) that still differ from each other, so a swapped stride shows.
fn spec() -> NgpSpec {
    NgpSpec {
        grid: HashGridConfig { levels: 6, features_per_level: 2, log2_table_size: 10, base_resolution: 4, max_resolution: 32 },
        bound: GridBound::cube(1.0),
        density_hidden: 24,
        geometry_features: 7,
        color_hidden: 20,
    }
}

/// Grid features, harmonics and output gradients for `rows` rows; features large enough that
/// the ReLUs are mixed and σ's pre-activations spread.
fn inputs(spec: &NgpSpec, rows: usize, seed: u64) -> (Vec<f32>, Vec<f32>, Vec<[f32; 3]>, Vec<f32>) {
    let mut rng = Rng::new(seed);
    let mut u = |scale: f32| (rng.uniform() * 2.0 - 1.0) * scale;
    let features = (0..rows * spec.grid.output_dim()).map(|_| u(3.0)).collect();
    let sh = (0..rows * SH4_DIM).map(|_| u(1.0)).collect();
    let grad_rgb = (0..rows).map(|_| [u(1.0), u(1.0), u(1.0)]).collect();
    let grad_sigma = (0..rows).map(|_| u(0.1)).collect();
    (features, sh, grad_rgb, grad_sigma)
}

fn field(spec: &NgpSpec, device: &Device) -> NgpField {
    NgpField::new(*spec, 7, device).unwrap()
}

fn close(a: f32, b: f32, tol: f32) -> bool {
    (a - b).abs() <= tol * (1.0 + a.abs().max(b.abs()))
}

#[test]
fn forward_matches_burn() {
    let spec = spec();
    let device = crate::backend::cpu();
    let field = field(&spec, &device);
    let fused = FusedMlps::from_mlps(&spec, &field.mlps);
    // 300 rows: two full blocks and a partial one.
    let (features, sh, _, _) = inputs(&spec, 300, 1);
    let (rgb, sigma) = fused.forward(&features, &sh);
    let f = Tensor::<2>::from_data(TensorData::new(features.clone(), [300, spec.grid.output_dim()]), &device);
    let s = Tensor::<2>::from_data(TensorData::new(sh.clone(), [300, SH4_DIM]), &device);
    let (want_rgb, want_sigma) = field.mlps.forward(f, s);
    let want_rgb = crate::inference::tensor_vec3(want_rgb);
    let want_sigma = want_sigma.into_data().try_to_vec::<f32>().unwrap();
    assert!(sigma.iter().any(|&s| s > 2.0) && sigma.iter().any(|&s| s < 0.5), "σ spread: {:?}", &sigma[..8]);
    for r in 0..300 {
        assert!(close(sigma[r], want_sigma[r], 1e-5), "σ row {r}: {} vs {}", sigma[r], want_sigma[r]);
        for c in 0..3 {
            assert!(close(rgb[r][c], want_rgb[r][c], 1e-5), "rgb row {r}: {:?} vs {:?}", rgb[r], want_rgb[r]);
        }
    }
    for (r, (d, s)) in fused.density(&features).iter().zip(&sigma).enumerate() {
        assert!(close(*d, *s, 1e-6), "the density MLP alone, row {r}: {d} vs {s}");
    }
    assert_eq!(fused.forward_train(&features, &sh, None).0, (rgb, sigma), "with or without the activations kept, the same outputs");
    assert_eq!(fused.forward(&[], &[]), (vec![], vec![]));
}

/// Σ rgb·g_rgb + σ·g_σ in f64: the surrogate whose gradient the backward pass computes.
fn surrogate(fused: &FusedMlps, features: &[f32], sh: &[f32], grad_rgb: &[[f32; 3]], grad_sigma: &[f32]) -> f64 {
    let (rgb, sigma) = fused.forward(features, sh);
    let mut total = 0.0f64;
    for r in 0..rgb.len() {
        total += (0..3).map(|c| rgb[r][c] as f64 * grad_rgb[r][c] as f64).sum::<f64>() + sigma[r] as f64 * grad_sigma[r] as f64;
    }
    total
}

#[test]
fn backward_matches_finite_differences() {
    let spec = spec();
    let device = crate::backend::cpu();
    let fused = FusedMlps::from_mlps(&spec, &field(&spec, &device).mlps);
    let rows = 5;
    let (features, sh, grad_rgb, grad_sigma) = inputs(&spec, rows, 2);
    let (_, saved) = fused.forward_train(&features, &sh, None);
    let mut grad_sh = vec![f32::NAN; rows * SH4_DIM];
    let (grads, grad_features) = fused.backward(&features, &sh, None, &saved, &grad_rgb, &grad_sigma, Some(&mut grad_sh));
    assert_eq!(fused.backward(&features, &sh, None, &saved, &grad_rgb, &grad_sigma, None), (grads.clone(), grad_features.clone()), "asking for the harmonics' gradient changes nothing else");
    let eps = 1e-2f32;
    let mut rng = Rng::new(3);
    let mut checked = 0;
    for layer in 0..5 {
        for _ in 0..12 {
            let i = rng.below(fused.weights[layer].len());
            let at = |delta: f32| {
                let mut moved = fused.clone();
                moved.weights[layer][i] += delta;
                surrogate(&moved, &features, &sh, &grad_rgb, &grad_sigma)
            };
            let numeric = ((at(eps) - at(-eps)) / (2.0 * eps as f64)) as f32;
            assert!(close(grads.weights[layer][i], numeric, 2e-2), "layer {layer} weight {i}: {} vs {numeric}", grads.weights[layer][i]);
            checked += (numeric.abs() > 1e-3) as usize;
        }
    }
    for _ in 0..24 {
        let i = rng.below(features.len());
        let at = |delta: f32| {
            let mut moved = features.clone();
            moved[i] += delta;
            surrogate(&fused, &moved, &sh, &grad_rgb, &grad_sigma)
        };
        let numeric = ((at(eps) - at(-eps)) / (2.0 * eps as f64)) as f32;
        assert!(close(grad_features[i], numeric, 2e-2), "feature {i}: {} vs {numeric}", grad_features[i]);
        checked += (numeric.abs() > 1e-3) as usize;
    }
    for i in 0..sh.len() {
        let at = |delta: f32| {
            let mut moved = sh.clone();
            moved[i] += delta;
            surrogate(&fused, &features, &moved, &grad_rgb, &grad_sigma)
        };
        let numeric = ((at(eps) - at(-eps)) / (2.0 * eps as f64)) as f32;
        assert!(close(grad_sh[i], numeric, 2e-2), "harmonic {i}: {} vs {numeric}", grad_sh[i]);
        checked += (numeric.abs() > 1e-3) as usize;
    }
    assert!(checked > 80, "only {checked} of the checked gradients are away from zero");
}

#[test]
fn backward_and_adam_step_match_burn_autodiff() {
    let spec = spec();
    let device = crate::backend::cpu_autodiff();
    let field = field(&spec, &device);
    let fused = FusedMlps::from_mlps(&spec, &field.mlps);
    let rows = 700;
    let (features, sh, grad_rgb, grad_sigma) = inputs(&spec, rows, 4);
    let (_, saved) = fused.forward_train(&features, &sh, None);
    let (grads, grad_features) = fused.backward(&features, &sh, None, &saved, &grad_rgb, &grad_sigma, None);

    let f = Tensor::<2>::from_data(TensorData::new(features.clone(), [rows, spec.grid.output_dim()]), &device).require_grad();
    let s = Tensor::<2>::from_data(TensorData::new(sh.clone(), [rows, SH4_DIM]), &device);
    let (rgb, sigma) = field.mlps.forward(f.clone(), s);
    let g_rgb = Tensor::<2>::from_data(TensorData::new(grad_rgb.as_flattened().to_vec(), [rows, 3]), &device);
    let g_sigma = Tensor::<1>::from_data(TensorData::new(grad_sigma.clone(), [rows]), &device);
    let mut burn_grads = ((rgb * g_rgb).sum() + (sigma * g_sigma).sum()).backward();
    let want_features = f.grad_remove(&mut burn_grads).unwrap().into_data().try_to_vec::<f32>().unwrap();
    for (i, (g, w)) in grad_features.iter().zip(&want_features).enumerate() {
        assert!(close(*g, *w, 1e-4), "feature gradient {i}: {g} vs {w}");
    }
    let burn_params = GradientsParams::from_grads(burn_grads, &field.mlps);
    for (layer, (id, _)) in field.mlps.weight_ids().into_iter().enumerate() {
        let want = burn_params.get::<2>(id).unwrap().into_data().try_to_vec::<f32>().unwrap();
        let scale = want.iter().fold(0.0f32, |m, w| m.max(w.abs()));
        for (i, (g, w)) in grads.weights[layer].iter().zip(&want).enumerate() {
            assert!((g - w).abs() <= 1e-4 * scale, "layer {layer} weight {i}: {g} vs {w}");
        }
    }

    // One Adam step each way lands on the same weights: the fused gradients are keyed and
    // placed as burn's optimizer expects.
    let adam = || AdamConfig::new().with_beta_2(0.99).with_epsilon(1e-15).init();
    let stepped_burn = adam().step(1e-2, field.mlps.clone(), burn_params);
    let stepped_fused = adam().step(1e-2, field.mlps.clone(), grads.to_params(&field.mlps, &crate::backend::cpu()));
    let before = field.mlps.weights();
    for (layer, (a, b)) in stepped_fused.weights().iter().zip(stepped_burn.weights()).enumerate() {
        let moved = a.iter().zip(&before[layer]).filter(|(x, y)| x != y).count();
        assert!(moved > a.len() / 2, "layer {layer}: only {moved} weights moved");
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-5, "layer {layer}: {x} vs {y}");
        }
    }
}

#[test]
fn backward_does_not_depend_on_the_thread_count() {
    let spec = spec();
    let fused = FusedMlps::from_mlps(&spec, &field(&spec, &crate::backend::cpu()).mlps);
    // More rows than GRADIENT_RUNS · BLOCK_ROWS, so runs hold several blocks.
    let rows = GRADIENT_RUNS * BLOCK_ROWS * 2 + 77;
    let (features, sh, grad_rgb, grad_sigma) = inputs(&spec, rows, 5);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let ((rgb, sigma), saved) = fused.forward_train(&features, &sh, None);
            let mut grad_sh = vec![0.0; rows * SH4_DIM];
            let grads = fused.backward(&features, &sh, None, &saved, &grad_rgb, &grad_sigma, Some(&mut grad_sh));
            (rgb, sigma, grads, grad_sh)
        })
    };
    let one = run(1);
    assert_eq!(one, run(3));
    // A row's harmonics gradient is its own: rows from the second run of blocks on, passed
    // alone, get the same values (the runs' slices line up).
    let (r0, r1) = (rows / 2 + 5, rows / 2 + 205);
    let f = spec.grid.output_dim();
    let (features, sh) = (&features[r0 * f..r1 * f], &sh[r0 * SH4_DIM..r1 * SH4_DIM]);
    let (_, saved) = fused.forward_train(features, sh, None);
    let mut grad_sh = vec![0.0; (r1 - r0) * SH4_DIM];
    fused.backward(features, sh, None, &saved, &grad_rgb[r0..r1], &grad_sigma[r0..r1], Some(&mut grad_sh));
    assert_eq!(grad_sh, one.3[r0 * SH4_DIM..r1 * SH4_DIM]);
}

/// Three codes for `rows` rows, each row its own pick.
fn random_codes(spec: &NgpSpec, rows: usize, seed: u64) -> (Vec<f32>, Vec<u32>) {
    let mut rng = Rng::new(seed);
    let codes = (0..3 * spec.color_hidden).map(|_| rng.uniform() * 2.0 - 1.0).collect();
    let code_of_row = (0..rows).map(|_| rng.below(3) as u32).collect();
    (codes, code_of_row)
}

#[test]
fn codes_add_to_color_0_as_a_bias_would() {
    let spec = spec();
    let fused = FusedMlps::from_mlps(&spec, &field(&spec, &crate::backend::cpu()).mlps);
    let rows = 300;
    let (features, sh, _, _) = inputs(&spec, rows, 6);
    let (codes, code_of_row) = random_codes(&spec, rows, 7);
    let (rgb, sigma) = fused.forward_train(&features, &sh, Some(RowCodes { codes: &codes, code_of_row: &code_of_row })).0;
    let plain = fused.forward(&features, &sh);
    assert_eq!(sigma, plain.1, "codes leave σ alone");
    let moved = rgb.iter().zip(&plain.0).filter(|(a, b)| a != b).count();
    assert!(moved > rows * 9 / 10, "codes change the colours: {moved} of {rows}");
    // Each row as the same MLPs with its code as color.0's bias.
    let c = spec.color_hidden;
    for k in 0..3 {
        let biased = fused.clone().with_color_bias(codes[k * c..(k + 1) * c].to_vec());
        let (want, _) = biased.forward(&features, &sh);
        for r in (0..rows).filter(|&r| code_of_row[r] == k as u32) {
            assert_eq!(rgb[r], want[r], "row {r}, code {k}");
        }
    }
}

#[test]
fn the_codes_gradient_matches_finite_differences_and_the_thread_count_does_not_matter() {
    let spec = spec();
    let fused = FusedMlps::from_mlps(&spec, &field(&spec, &crate::backend::cpu()).mlps);
    let rows = 7;
    let (features, sh, grad_rgb, grad_sigma) = inputs(&spec, rows, 8);
    let (codes, code_of_row) = random_codes(&spec, rows, 9);
    let surrogate = |codes: &[f32]| {
        let (rgb, _) = fused.forward_train(&features, &sh, Some(RowCodes { codes, code_of_row: &code_of_row })).0;
        rgb.iter().zip(&grad_rgb).map(|(c, g)| (0..3).map(|k| c[k] as f64 * g[k] as f64).sum::<f64>()).sum::<f64>()
    };
    let row_codes = RowCodes { codes: &codes, code_of_row: &code_of_row };
    let (_, saved) = fused.forward_train(&features, &sh, Some(row_codes));
    let (grads, _) = fused.backward(&features, &sh, Some(row_codes), &saved, &grad_rgb, &grad_sigma, None);
    assert_eq!(grads.codes.len(), codes.len());
    let eps = 1e-2f32;
    let mut checked = 0;
    for i in 0..codes.len() {
        let at = |delta: f32| {
            let mut moved = codes.clone();
            moved[i] += delta;
            surrogate(&moved)
        };
        let numeric = ((at(eps) - at(-eps)) / (2.0 * eps as f64)) as f32;
        assert!(close(grads.codes[i], numeric, 2e-2), "code value {i}: {} vs {numeric}", grads.codes[i]);
        checked += (numeric.abs() > 1e-3) as usize;
    }
    assert!(checked > codes.len() / 3, "only {checked} of the codes' gradients are away from zero");
    // Without codes the pass has no codes' gradient.
    assert!(fused.backward(&features, &sh, None, &saved, &grad_rgb, &grad_sigma, None).0.codes.is_empty());

    let rows = GRADIENT_RUNS * BLOCK_ROWS * 2 + 77;
    let (features, sh, grad_rgb, grad_sigma) = inputs(&spec, rows, 10);
    let (codes, code_of_row) = random_codes(&spec, rows, 11);
    let row_codes = Some(RowCodes { codes: &codes, code_of_row: &code_of_row });
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
            let ((rgb, sigma), saved) = fused.forward_train(&features, &sh, row_codes);
            (rgb, sigma, fused.backward(&features, &sh, row_codes, &saved, &grad_rgb, &grad_sigma, None))
        })
    };
    assert_eq!(run(1), run(3));
}
