//! `nerf mesh` end to end on the generated scene, whose surfaces are known exactly: a tiny
//! hash-grid run's mesh, carved by its training views, lies on the spheres and the plinth to
//! within a lattice cell at the 95th percentile (through burn, and through onnxruntime from its
//! bundle given the same views), carving takes away vertices that lie off the true surfaces
//! and keeps those on them, the mesh is a PLY that reads back, and bad input is refused with
//! nothing written.
//!
//! Only vertices above the plinth's bottom face (z > −1) are measured: every camera is above
//! the scene, so nothing under the plinth was ever seen and the field there is free
//! (docs/mesh.md).

mod common;

use common::{nerf, s, small_scene, tiny_ngp};
use glam::Vec3;
use nerf::train::{TrainOptions, train};
use nerf_core::dataset::{SyntheticSceneConfig, generate_scene, surface_distance};
use nerf_core::mesh::ply::{PlyMesh, PlyVertex, read_ply};
use std::collections::HashSet;
use std::path::Path;

/// Training steps of the tiny run (≈ 30 s on 2 cores).
const STEPS: usize = 1000;
/// Lattice cells per axis over the field's box ±1.5.
const RESOLUTION: usize = 32;

/// Mean, median and 95th percentile of the distances to the scene's true surfaces of the
/// vertices above the plinth's bottom face.
fn distances(mesh: &PlyMesh) -> (f32, f32, f32) {
    let mut d: Vec<f32> = mesh.vertices.iter().filter(|v| v.position[2] > -1.0).map(|v| surface_distance(Vec3::from_array(v.position))).collect();
    d.sort_by(f32::total_cmp);
    let mean = d.iter().sum::<f32>() / d.len() as f32;
    let at = |q: f32| d[(q * (d.len() - 1) as f32).round() as usize];
    (mean, at(0.5), at(0.95))
}

/// The vertices of `plain` that `carved` (the same field's mesh, carved) no longer has, and those
/// it keeps. Carving only fills lattice nodes, and marching cubes puts a vertex on an edge from
/// the edge's two densities alone, so a kept vertex is at the same position to the bit.
fn carved_away<'a>(plain: &'a PlyMesh, carved: &PlyMesh) -> (Vec<&'a PlyVertex>, Vec<&'a PlyVertex>) {
    let key = |v: &PlyVertex| v.position.map(f32::to_bits);
    let carved: HashSet<_> = carved.vertices.iter().map(key).collect();
    plain.vertices.iter().partition(|v| !carved.contains(&key(v)))
}

/// The mean distance of `vertices` to the scene's true surfaces (NaN for none).
fn mean_distance(vertices: &[&PlyVertex]) -> f32 {
    vertices.iter().map(|v| surface_distance(Vec3::from_array(v.position))).sum::<f32>() / vertices.len() as f32
}

fn mesh(args: &[&str], out: &Path) -> PlyMesh {
    let (ok, text) = nerf(&[&["mesh", "--out", s(out)], args].concat());
    assert!(ok, "{text}");
    println!("{}", text.trim());
    read_ply(out).unwrap()
}

#[test]
fn a_trained_run_meshes_onto_the_true_surfaces_through_burn_and_onnxruntime() {
    let dir = tempfile::tempdir().unwrap();
    // 64×64 views: at 32×32 a pixel spans a whole cell at the object.
    let scene = dir.path().join("scene");
    generate_scene(&scene, &SyntheticSceneConfig { width: 64, height: 64, n_train: 40, n_val: 1, n_test: 1, seed: 1 }).unwrap();
    let run = dir.path().join("run");
    let options = TrainOptions { format: None, data: scene.clone(), run: run.clone(), config: tiny_ngp(), ndc: None, contract: None, downscale: 1, time_budget_min: None, iters: Some(STEPS), progress: false };
    train(&options).unwrap();
    let cell = 3.0 / RESOLUTION as f32;
    let resolution = RESOLUTION.to_string();

    // Not carved: within a cell on average.
    let plain = mesh(&["--run", s(&run), "--resolution", &resolution, "--no-carve"], &dir.path().join("plain.ply"));
    let (plain_mean, plain_median, plain_p95) = distances(&plain);
    println!("burn, not carved: {} vertices; mean {plain_mean:.4}, median {plain_median:.4}, p95 {plain_p95:.4}", plain.vertices.len());
    assert!(plain_mean < cell && plain_median < 0.75 * cell, "mean {plain_mean}, median {plain_median}, cell {cell}");

    // Carved by default with the run's 40 training views.
    let burn = mesh(&["--run", s(&run), "--resolution", &resolution], &dir.path().join("burn.ply"));
    assert!(burn.comments.iter().any(|c| c.contains(&format!("density 2.5 on {RESOLUTION}^3 cells"))), "{:?}", burn.comments);
    assert!(burn.comments.iter().any(|c| c.contains("none of 40 views saw empty")), "{:?}", burn.comments);
    assert!(burn.faces.len() > 1000, "{} triangles", burn.faces.len());
    let (mean, median, p95) = distances(&burn);
    println!("burn: {} vertices; distance to the true surfaces (z > −1): mean {mean:.4}, median {median:.4}, 95th percentile {p95:.4} (cell {cell:.4})", burn.vertices.len());
    assert!(mean < cell && median < 0.75 * cell, "mean {mean}, median {median}, cell {cell}");
    // Within a cell at the 95th percentile (0.090 for a cell of 0.094 when measured), and
    // carving does not push the surfaces out.
    assert!(p95 < cell && p95 <= plain_p95 * 1.02, "95th percentile {p95} (not carved {plain_p95}), cell {cell}");
    // Carving takes away surfaces no view saw, mostly the hull's inner walls under the plinth
    // (whose closing face is as far off as they were: the distances of all vertices hardly
    // change), and keeps what the views saw: the vertices it removes lie off the true surfaces,
    // those it keeps on them. Measured: 1,290 of 3,107 removed, 1.72 cells off on average
    // (54% of them more than a cell), the kept 0.51 (8%).
    let (removed, kept) = carved_away(&plain, &burn);
    let (removed_mean, kept_mean) = (mean_distance(&removed) / cell, mean_distance(&kept) / cell);
    println!("carving removed {} of {} vertices, {removed_mean:.2} cells off the true surfaces on average; kept {kept_mean:.2}", removed.len(), plain.vertices.len());
    assert!(removed.len() * 5 >= plain.vertices.len(), "carving removed {} of {} vertices", removed.len(), plain.vertices.len());
    assert!(removed_mean > 1.2 && kept_mean < 0.75, "the removed vertices are {removed_mean:.2} cells off the true surfaces on average, the kept {kept_mean:.2}");
    // Normals are unit; the red sphere's cap (albedo 0.9, 0.2, 0.15, lit from above) is red.
    assert!(burn.vertices.iter().all(|v| (Vec3::from_array(v.normal).length() - 1.0).abs() < 1e-4));
    let cap: Vec<[u8; 3]> = burn.vertices.iter().filter(|v| v.position[2] > 0.2 && Vec3::from_array(v.position).length() < 0.8).map(|v| v.color).collect();
    let channel = |c: usize| cap.iter().map(|v| v[c] as f32).sum::<f32>() / cap.len() as f32;
    assert!(cap.len() > 20 && channel(0) > 150.0 && channel(1) < 60.0 && channel(2) < 60.0, "{} cap vertices, mean colour {:?}", cap.len(), [0, 1, 2].map(channel));

    let bundle = dir.path().join("bundle");
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    // A bundle carves only with --data; here the run's own views, rendered through onnxruntime.
    let ort = mesh(&["--bundle", s(&bundle), "--resolution", &resolution, "--data", s(&scene)], &dir.path().join("ort.ply"));
    let ort_plain = mesh(&["--bundle", s(&bundle), "--resolution", &resolution], &dir.path().join("ort-plain.ply"));
    assert!(ort_plain.comments.iter().any(|c| c == "cavities: filled"), "{:?}", ort_plain.comments);
    // The same field and views in another runtime: the same surface up to float rounding.
    for (ort, burn, what) in [(&ort, &burn, "carved"), (&ort_plain, &plain, "not carved")] {
        let ((ort_mean, ort_median, ort_p95), (mean, _, p95)) = (distances(ort), distances(burn));
        println!("onnxruntime, {what}: {} vertices; mean {ort_mean:.4}, median {ort_median:.4}, p95 {ort_p95:.4}", ort.vertices.len());
        let diff = ort.vertices.len().abs_diff(burn.vertices.len());
        assert!(diff * 100 <= burn.vertices.len(), "{what}: {} vs {} vertices", ort.vertices.len(), burn.vertices.len());
        assert!((ort_mean - mean).abs() < 0.05 * cell && (ort_p95 - p95).abs() < 0.1 * cell, "{what}: {ort_mean} vs {mean}, {ort_p95} vs {p95}");
    }
}

#[test]
fn imported_nerf_pytorch_bundles_mesh_and_ndc_ones_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/nerf-pytorch");
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    let import = |checkpoint: &str, data: &Path, out: &Path| {
        let (ok, text) = nerf(&["import", "nerf-pytorch", "--checkpoint", s(&fixtures.join(checkpoint)), "--data", s(data), "--out", s(out)]);
        assert!(ok, "{text}");
    };
    // The tiny lego MLPs of the import tests (1000 steps): σ stays under 20, far below the
    // default 50 of a fully trained NeRF, which the error says.
    let lego = dir.path().join("lego");
    import("trained/001000.tar", &shared.join("nerf_synthetic/lego"), &lego);
    let out = dir.path().join("lego.ply");
    let (ok, text) = nerf(&["mesh", "--bundle", s(&lego), "--out", s(&out), "--resolution", "24"]);
    assert!(!ok && text.contains("no density above --threshold 50") && text.contains("the largest seen is"), "{text}");
    let mesh = mesh(&["--bundle", s(&lego), "--resolution", "24", "--threshold", "5"], &out);
    assert!(mesh.faces.len() > 100, "{} triangles", mesh.faces.len());
    // No occupancy grid, no box: the Blender cube ±1.5, where the lego's vertices are.
    assert!(mesh.vertices.iter().all(|v| v.position.iter().all(|x| x.abs() <= 1.5)));
    // fern with NDC rays: refused, nothing written.
    let fern = dir.path().join("fern");
    import("llff/001500.tar", &shared.join("real/fern"), &fern);
    let out = dir.path().join("fern.ply");
    let (ok, text) = nerf(&["mesh", "--bundle", s(&fern), "--out", s(&out), "--resolution", "8"]);
    assert!(!ok && text.contains("fern/scene.json: the scene was trained with NDC rays"), "{text}");
    assert!(!out.exists());
}

#[test]
fn bad_input_is_refused_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out/mesh.ply");
    let refuse = |args: &[&str], want: &str| {
        let (ok, text) = nerf(&[&["mesh", "--out", s(&out)], args].concat());
        assert!(!ok && text.contains(want), "nerf mesh {args:?}: {text}");
        assert!(!out.exists(), "nerf mesh {args:?} wrote {}", out.display());
    };
    let missing = dir.path().join("no-run");
    refuse(&["--run", s(&missing)], "no-run");
    refuse(&["--bundle", s(&missing)], "no such bundle directory");
    refuse(&[], "--run <RUN>");
    refuse(&["--run", "a", "--bundle", "b"], "cannot be used with");

    // A trained run (a few steps: only the options matter here).
    let scene_dir = small_scene(dir.path());
    let run = dir.path().join("run");
    let options = TrainOptions { format: None, data: scene_dir.clone(), run: run.clone(), config: tiny_ngp(), ndc: None, contract: None, downscale: 1, time_budget_min: None, iters: Some(20), progress: false };
    train(&options).unwrap();
    refuse(&["--run", s(&run), "--resolution", "0"], "--resolution: must be at least 1");
    refuse(&["--run", s(&run), "--resolution", "1"], "at least 2 cells");
    refuse(&["--run", s(&run), "--resolution", "100000"], "--resolution");
    refuse(&["--run", s(&run), "--threshold=-3"], "--threshold -3");
    refuse(&["--run", s(&run), "--threshold", "nan"], "--threshold NaN");
    refuse(&["--run", s(&run), "--bound", "0"], "--bound 0");
    refuse(&["--run", s(&run), "--resolution", "8", "--threshold", "1e30"], "no density above --threshold");
    // Carving: a dataset that is not there, or asked for while turned off.
    refuse(&["--run", s(&run), "--resolution", "8", "--data", s(&missing)], "no-run");
    refuse(&["--run", s(&run), "--resolution", "8", "--data", s(&missing)], "or --no-carve");
    refuse(&["--run", s(&run), "--data", s(&scene_dir), "--no-carve"], "cannot be used with");
    refuse(&["--run", s(&run), "--data", s(&scene_dir), "--keep-cavities"], "cannot be used with");
    // The output is a directory.
    std::fs::create_dir_all(&out).unwrap();
    let (ok, text) = nerf(&["mesh", "--run", s(&run), "--out", s(&out), "--resolution", "8"]);
    assert!(!ok && text.contains("is a directory"), "{text}");
    let names: Vec<_> = std::fs::read_dir(out.parent().unwrap()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names.len(), 1, "no temporaries left: {names:?}");
}
