use super::*;
use crate::field::ngp::hash_grid::config::PRIMES;

fn random_points(n: usize, seed: u64) -> Vec<[f32; 3]> {
    let mut rng = Rng::new(seed);
    (0..n).map(|_| [rng.uniform(), rng.uniform(), rng.uniform()]).collect()
}

fn small_config() -> HashGridConfig {
    // Levels 0–1 dense (res 4, 7), 2–3 hashed (res 11, 18 > ∛512 = 8).
    HashGridConfig { levels: 4, features_per_level: 2, log2_table_size: 9, base_resolution: 4, max_resolution: 17 }
}

/// The encoding from its definition, written independently: f64 weights, u64 hash.
fn reference_forward(grid: &HashGrid, x: [f32; 3]) -> Vec<f64> {
    let f = grid.config.features_per_level;
    let mut out = Vec::new();
    for level in &grid.levels {
        let mut cell = [0u64; 3];
        let mut frac = [0f64; 3];
        for d in 0..3 {
            let pos = (x[d].clamp(0.0, 1.0) * level.scale + 0.5) as f64;
            cell[d] = pos.floor() as u64;
            frac[d] = pos - pos.floor();
        }
        let mut acc = vec![0f64; f];
        for (dx, dy, dz) in (0..8).map(|k| (k & 1, (k >> 1) & 1, (k >> 2) & 1)) {
            let c = [cell[0] + dx, cell[1] + dy, cell[2] + dz];
            let w = [dx, dy, dz].iter().zip(frac).map(|(&b, t)| if b == 1 { t } else { 1.0 - t }).product::<f64>();
            let r = level.resolution as u64;
            let entry = if level.dense {
                (c[0] + c[1] * r + c[2] * r * r) % level.entries as u64
            } else {
                let h = (0..3).map(|d| (c[d] * PRIMES[d] as u64) % (1 << 32)).fold(0, |a, b| a ^ b);
                h % level.entries as u64
            };
            let row = (level.offset as u64 + entry) as usize * f;
            for i in 0..f {
                acc[i] += w * grid.params[row + i] as f64;
            }
        }
        out.extend(acc);
    }
    out
}

#[test]
fn trilinear_case_by_hand() {
    // One dense level, scale 1, resolution 2, 8 entries; entry e holds e, so a corner
    // (cx, cy, cz) holds (cx + 2cy + 4cz) mod 8.
    let config = HashGridConfig { levels: 1, features_per_level: 1, log2_table_size: 3, base_resolution: 2, max_resolution: 2 };
    let grid = HashGrid::from_params(config, (0..8).map(|e| e as f32).collect()).unwrap();
    assert_eq!(grid.levels()[0].resolution, 2);
    // (0.1, 0.2, 0.3) → pos (0.6, 0.7, 0.8) in cell (0, 0, 0): 0.6 + 2·0.7 + 4·0.8 = 5.2.
    // (0.25, 0.5, 0.75) → pos (0.75, 1, 1.25), cell (0, 1, 1), frac (0.75, 0, 0.25): the
    // z + 1 corners sit at z = 2, whose index wraps (−8), so the z part is 0.75·4 + 0.25·0:
    // 0.75 + 2·1 + 3 = 5.75.
    let out = grid.forward(&[[0.1, 0.2, 0.3], [0.25, 0.5, 0.75], [-3.0, 0.2, 7.0]]);
    assert!((out[0] - 5.2).abs() < 1e-5, "{}", out[0]);
    assert!((out[1] - 5.75).abs() < 1e-6, "{}", out[1]);
    // Clamped to (0, 0.2, 1) → pos (0.5, 0.7, 1.5): cell (0, 0, 1), frac (0.5, 0.7, 0.5);
    // z = 1 → 4, z = 2 → wraps to 0: 0.5 + 1.4 + (0.5·4 + 0.5·0) = 3.9.
    assert!((out[2] - 3.9).abs() < 1e-5, "{}", out[2]);
}

#[test]
fn forward_matches_the_reference() {
    for features in [1, 2, 4, 8] {
        let config = HashGridConfig { features_per_level: features, ..small_config() };
        let mut grid = HashGrid::new(config, 3).unwrap();
        let mut rng = Rng::new(9);
        grid.params_mut().iter_mut().for_each(|p| *p = rng.uniform() * 2.0 - 1.0);
        let mut points = random_points(50, 4);
        points.push([1.0, 1.0, 1.0]);
        points.push([0.0, 0.0, 0.0]);
        points.push([1.5, -0.5, 0.5]);
        let out = grid.forward(&points);
        assert_eq!(out.len(), points.len() * 4 * features);
        for (row, &x) in out.chunks_exact(4 * features).zip(&points) {
            for (a, b) in row.iter().zip(reference_forward(&grid, x)) {
                assert!((*a as f64 - b).abs() < 1e-5, "F {features}, {x:?}: {a} vs {b}");
            }
        }
    }
}

#[test]
fn corners_agree_with_the_layout_index() {
    let mut levels = HashGridConfig::default().layout().unwrap();
    levels.extend(small_config().layout().unwrap());
    levels.extend(HashGridConfig { base_resolution: 1, max_resolution: 3, levels: 3, ..small_config() }.layout().unwrap());
    let mut points = random_points(200, 11);
    points.extend([[1.0, 1.0, 1.0], [0.0, 1.0, 0.0], [0.999_999, 0.5, 1.0]]);
    for level in &levels {
        for &x in &points {
            let c = corners(level, x);
            let cell = x.map(|v| (v * level.scale + 0.5).floor() as u32);
            for k in 0..8 {
                let corner = [0, 1, 2].map(|d| cell[d] + ((k >> d) & 1) as u32);
                assert_eq!(c.index[k], level.index(corner), "level {level:?}, {x:?}, corner {k}");
            }
            assert!((c.weight.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        }
    }
}

#[test]
fn levels_are_both_dense_and_hashed_in_the_small_config() {
    let grid = HashGrid::new(small_config(), 0).unwrap();
    let kinds: Vec<bool> = grid.levels().iter().map(|l| l.dense).collect();
    assert_eq!(kinds, [true, true, false, false]);
    assert!(grid.params().iter().all(|p| p.abs() <= 1e-4));
    assert_ne!(grid.params()[0], grid.params()[1]);
    assert_eq!(HashGrid::new(small_config(), 0).unwrap(), grid, "seeded");
    let err = HashGrid::from_params(small_config(), vec![0.0; 5]).unwrap_err().to_string();
    assert!(err.contains("5 parameters"), "{err}");
}

/// loss = ½ Σ r ⊙ y², so ∂loss/∂y = r ⊙ y.
fn loss(grid: &HashGrid, points: &[[f32; 3]], r: &[f32]) -> f64 {
    grid.forward(points).iter().zip(r).map(|(&y, &r)| 0.5 * r as f64 * (y as f64).powi(2)).sum()
}

#[test]
fn backward_matches_finite_differences() {
    let mut grid = HashGrid::new(small_config(), 1).unwrap();
    let mut rng = Rng::new(2);
    grid.params_mut().iter_mut().for_each(|p| *p = rng.uniform() * 2.0 - 1.0);
    let points = random_points(40, 5);
    let r: Vec<f32> = (0..points.len() * grid.output_dim()).map(|_| rng.uniform() * 2.0 - 1.0).collect();
    let y = grid.forward(&points);
    let grad_out: Vec<f32> = y.iter().zip(&r).map(|(y, r)| y * r).collect();
    let mut grad = HashGridGradient::new(&grid);
    grid.backward(&points, &grad_out, &mut grad);
    let dense = grad.to_dense();
    assert!(grad.touched_entries() > 0 && grad.touched_entries() < dense.len() / 2, "some entries, not all");
    let h = 1e-2f32;
    let mut checked_nonzero = 0;
    for k in (0..dense.len()).step_by(7) {
        let old = grid.params()[k];
        grid.params_mut()[k] = old + h;
        let plus = loss(&grid, &points, &r);
        grid.params_mut()[k] = old - h;
        let minus = loss(&grid, &points, &r);
        grid.params_mut()[k] = old;
        let fd = (plus - minus) / (2.0 * h as f64);
        assert!((fd - dense[k] as f64).abs() <= 1e-3 * (1.0 + fd.abs()), "entry {k}: backward {} vs finite difference {fd}", dense[k]);
        checked_nonzero += usize::from(fd.abs() > 1e-3);
    }
    assert!(checked_nonzero > 10, "only {checked_nonzero} non-zero gradients checked");
}

#[test]
fn backward_is_the_adjoint_of_forward() {
    // ⟨g, forward(θ)⟩ = ⟨backward(g), θ⟩ for every table θ (the encoding is linear in θ).
    let mut grid = HashGrid::new(HashGridConfig { features_per_level: 4, ..small_config() }, 1).unwrap();
    let mut rng = Rng::new(8);
    grid.params_mut().iter_mut().for_each(|p| *p = rng.uniform() * 2.0 - 1.0);
    let points = random_points(300, 6);
    let g: Vec<f32> = (0..points.len() * grid.output_dim()).map(|_| rng.uniform() - 0.5).collect();
    let lhs: f64 = grid.forward(&points).iter().zip(&g).map(|(&a, &b)| a as f64 * b as f64).sum();
    let mut grad = HashGridGradient::new(&grid);
    grid.backward(&points, &g, &mut grad);
    let rhs: f64 = grad.to_dense().iter().zip(grid.params()).map(|(&a, &b)| a as f64 * b as f64).sum();
    assert!((lhs - rhs).abs() < 1e-4 * lhs.abs().max(1.0), "{lhs} vs {rhs}");
}

#[test]
fn gradient_is_deterministic_across_threads_and_passes() {
    let grid = HashGrid::new(HashGridConfig { log2_table_size: 12, ..HashGridConfig::default() }, 1).unwrap();
    let points = random_points(5000, 7);
    let mut rng = Rng::new(3);
    let g: Vec<f32> = (0..points.len() * grid.output_dim()).map(|_| rng.uniform() - 0.5).collect();
    let run = |threads: usize, passes: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let mut grad = HashGridGradient::new(&grid);
            // Stale values from an earlier step must not leak in: fill, clear, then accumulate.
            grid.backward(&points, &g, &mut grad);
            grad.clear();
            let per = points.len() / passes;
            let w = grid.output_dim();
            for p in 0..passes {
                grid.backward(&points[p * per..(p + 1) * per], &g[p * per * w..(p + 1) * per * w], &mut grad);
            }
            grad.to_dense()
        })
    };
    let one = run(1, 1);
    assert!(one.iter().any(|&v| v != 0.0));
    assert_eq!(run(2, 1), one, "2 threads");
    assert_eq!(run(2, 4), one, "4 consecutive passes");
    assert_eq!(run(2, 1), run(2, 1), "repeatable");
}

#[test]
fn the_position_gradient_matches_finite_differences_of_the_reference() {
    let mut grid = HashGrid::new(small_config(), 6).unwrap();
    // Table values of order 1, so the gradient is far from rounding.
    let mut rng = Rng::new(7);
    grid.params_mut().iter_mut().for_each(|v| *v = rng.uniform() * 2.0 - 1.0);
    let width = grid.output_dim();
    let mut points = random_points(40, 8);
    // A point outside the cube on one axis: that axis is clamped, its gradient 0.
    points.push([1.3, 0.4, 0.6]);
    let grad_out: Vec<f32> = (0..points.len() * width).map(|_| rng.uniform() * 2.0 - 1.0).collect();
    let got = grid.position_gradient(&points, &grad_out);
    let mut skipped = 0;
    for (i, &x) in points.iter().enumerate() {
        let g = &grad_out[i * width..(i + 1) * width];
        let loss = |x: [f32; 3]| reference_forward(&grid, x).iter().zip(g).map(|(y, &g)| y * g as f64).sum::<f64>();
        for d in 0..3 {
            // A step small enough to stay inside the finest cell (1/17 of the cube), in f32.
            let eps = 2e-4f32;
            let (mut hi, mut lo) = (x, x);
            hi[d] += eps;
            lo[d] -= eps;
            // The encoding is linear inside a cell only: a step across a cell face on any level
            // is not a derivative.
            let cell = |v: f32, l: &LevelLayout| (v.clamp(0.0, 1.0) * l.scale + 0.5) as u32;
            if grid.levels.iter().any(|l| cell(hi[d], l) != cell(lo[d], l)) {
                skipped += 1;
                continue;
            }
            let numeric = (loss(hi) - loss(lo)) / (hi[d] - lo[d]) as f64;
            assert!((got[i][d] as f64 - numeric).abs() < 2e-2 * (1.0 + numeric.abs()), "point {i} {x:?} axis {d}: {} vs {numeric}", got[i][d]);
        }
    }
    assert!(skipped < 10, "{skipped} of 123 steps crossed a cell face");
    assert_eq!(got[40][0], 0.0, "a clamped coordinate has no gradient");
    assert!(got.iter().take(40).all(|g| g.iter().all(|v| v.abs() > 0.0)));
}
