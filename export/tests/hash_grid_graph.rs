//! The hash-grid and spherical-harmonics lowering against the Rust encodings: onnx.checker
//! (full), strict shape inference and onnxruntime (Python, `tests/python/check_hash_grid.py`)
//! on 12,000 random points, within 1e-5, for the bitwise lowering and the bitwise-free one.

use nerf_core::Rng;
use nerf_core::hash_grid::{GridBound, HashGrid, HashGridConfig};
use nerf_core::spherical_harmonics::sh4_all;
use nerf_export::hash_grid::{HashOps, compile_encodings};
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

fn check(grid: &HashGrid, bound: &GridBound, ops: HashOps, opset: i64, n: usize, dir: &Path) {
    let model = compile_encodings(grid, bound, ops, opset).unwrap();
    let path = dir.join(format!("encodings-{ops:?}.onnx"));
    std::fs::write(&path, model.encode_to_vec()).unwrap();
    // Points a little beyond the bound on every side (the clamp is part of the check).
    let mut rng = Rng::new(7);
    let points: Vec<[f32; 3]> = (0..n).map(|_| [0, 1, 2].map(|d| bound.min[d] - 0.1 + (bound.max[d] - bound.min[d] + 0.2) * rng.uniform())).collect();
    let dirs: Vec<[f32; 3]> = (0..n)
        .map(|_| {
            let v = [0; 3].map(|_| rng.uniform() * 2.0 - 1.0);
            let norm = v.iter().map(|c| c * c).sum::<f32>().sqrt();
            v.map(|c| c / norm)
        })
        .collect();
    let unit: Vec<[f32; 3]> = points.iter().map(|&p| bound.to_unit(p)).collect();
    let reference = serde_json::json!({
        "width": grid.output_dim(),
        "bitwise": ops == HashOps::Bitwise,
        "tolerance": 1e-5,
        "points": points,
        "viewdirs": dirs,
        "features": grid.forward(&unit),
        "sh": sh4_all(&dirs),
    });
    let ref_path = dir.join(format!("reference-{ops:?}.json"));
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

#[test]
fn encodings_graph_matches_the_rust_encodings() {
    let dir = tempfile::tempdir().unwrap();
    // Dense coarse levels, hashed fine ones up to resolution 2048 (large hash products).
    let config = HashGridConfig { levels: 16, features_per_level: 2, log2_table_size: 14, base_resolution: 16, max_resolution: 2048 };
    let g = grid(config);
    assert!(g.levels().iter().any(|l| l.dense) && g.levels().iter().any(|l| !l.dense));
    let bound = GridBound { min: [-1.5, -1.5, -1.0], max: [1.5, 1.5, 2.0] };
    check(&g, &bound, HashOps::Bitwise, 18, 12_000, dir.path());
    // The bitwise-free lowering (opset 17) on fewer points: its index tensors are k× larger.
    let small = grid(HashGridConfig { levels: 8, features_per_level: 4, log2_table_size: 12, base_resolution: 8, max_resolution: 512 });
    check(&small, &bound, HashOps::Arithmetic, 17, 3_000, dir.path());
}
