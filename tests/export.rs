//! `nerf export`: the bundle's contents, graphs that onnx and onnxruntime (Python) accept and
//! that compute what the network computes, and clean failures that leave no partial bundle.

mod common;

use common::{nerf, python, s, small_scene, tiny_config, trained_run};
use nerf::run_dir::RunDir;
use nerf::train::{TrainOptions, train};
use std::path::Path;
use std::process::Command;

/// Random points in the scene cube and unit directions, with the plain network's answers.
fn reference(net: &nerf_core::field::mlp::PlainNetwork, n: usize, seed: u64) -> serde_json::Value {
    let (points, dirs) = nerf::bench::random_points(n, seed);
    let out: Vec<_> = points.iter().zip(&dirs).map(|(p, d)| net.forward(*p, *d)).collect();
    serde_json::json!({
        "points": points,
        "viewdirs": dirs,
        "rgb": out.iter().map(|o| o.rgb).collect::<Vec<_>>(),
        "raw_sigma": out.iter().map(|o| o.raw_sigma).collect::<Vec<_>>(),
    })
}

#[test]
fn export_writes_a_bundle_that_onnx_and_onnxruntime_accept() {
    let dir = tempfile::tempdir().unwrap();
    let (_, run) = trained_run(dir.path());
    let bundle = dir.path().join("bundle");
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    for file in ["coarse.onnx", "fine.onnx", "scene.json"] {
        assert!(bundle.join(file).is_file(), "{file} missing:\n{text}");
    }
    let scene = nerf_bundle::read_scene(&bundle).unwrap();
    assert_eq!((scene.camera.camera.width, scene.camera.camera.height), (32, 32));
    assert_eq!((scene.sampling.near, scene.sampling.far), (2.0, 6.0));
    assert_eq!(scene.poses.test.len(), 2, "the generated scene's test poses");
    assert_eq!(scene.poses.orbit.len(), nerf_core::camera::ORBIT_FRAMES);
    let roles: Vec<_> = scene.graph_files().iter().map(|g| (g.role.name(), g.file.to_string())).collect();
    assert_eq!(roles, [("coarse", "coarse.onnx".to_string()), ("fine", "fine.onnx".to_string())], "graphs named by role");
    assert_eq!(scene.format, nerf_bundle::scene::SCENE_FORMAT);
    assert_eq!(scene.position_encoding.as_ref().unwrap().output_dim, 63);

    // The graphs carry exactly the trained weights.
    let model = nerf::field::load_latest(&RunDir::open(&run).unwrap(), &nerf::backend::cpu()).unwrap().model.as_any().downcast_ref::<nerf::field::mlp::NerfModel>().unwrap().clone();
    let coarse = nerf_export::field::mlp::read_bundle_network(&bundle, "coarse.onnx").unwrap();
    let fine = nerf_export::field::mlp::read_bundle_network(&bundle, "fine.onnx").unwrap();
    assert_eq!(coarse, model.coarse.to_plain());
    assert_eq!(fine, model.fine.as_ref().unwrap().to_plain());

    // Python: checker, shape inference, contract, onnxruntime vs the reference forward pass.
    let refs = serde_json::json!({ "coarse": reference(&coarse, 10_000, 1), "fine": reference(&fine, 10_000, 2) });
    let ref_file = dir.path().join("reference.json");
    std::fs::write(&ref_file, refs.to_string()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/check_graphs.py");
    let out = Command::new(python())
        .args([s(&script), s(&bundle), "--reference", s(&ref_file)])
        .output()
        .unwrap_or_else(|e| panic!("cannot run {} ({e}): run scripts/setup.sh and source scripts/env.sh", python()));
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "check_graphs.py failed (is onnx installed? scripts/setup.sh):\n{text}");
    assert_eq!(text.matches("ok ").count(), 2, "{text}");
}

#[test]
fn export_failures_leave_no_bundle() {
    let dir = tempfile::tempdir().unwrap();
    let (_, run) = trained_run(dir.path());
    let bundle = dir.path().join("out").join("bundle");
    let no_partial = |why: &str| {
        assert!(!bundle.exists(), "{why}: a bundle was written");
        let leftovers: Vec<_> = std::fs::read_dir(dir.path().join("out")).map(|d| d.flatten().map(|e| e.path()).collect()).unwrap_or_default();
        assert!(leftovers.is_empty(), "{why}: left {leftovers:?}");
    };

    let (ok, text) = nerf(&["export", "--run", s(&dir.path().join("nope")), "--out", s(&bundle)]);
    assert!(!ok && text.contains("config.toml"), "{text}");
    no_partial("missing run");

    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle), "--opset", "9"]);
    assert!(!ok && text.contains("opset 9"), "{text}");
    no_partial("bad opset");

    // A checkpoint from another network shape (foreign weights).
    let other = dir.path().join("other");
    let mut config = tiny_config();
    config.shapes.network.width = 32;
    config.iters = 1;
    let scene = small_scene(&dir.path().join("s2"));
    train(&TrainOptions { format: None, data: scene, run: other.clone(), config, ndc: None, contract: None, downscale: 1, time_budget_min: None, iters: None, progress: false }).unwrap();
    let latest = RunDir::open(&run).unwrap().latest_checkpoint().unwrap().unwrap().dir;
    let other_latest = RunDir::open(&other).unwrap().latest_checkpoint().unwrap().unwrap().dir;
    let model = latest.join("model.bpk");
    let original = std::fs::read(&model).unwrap();
    std::fs::copy(other_latest.join("model.bpk"), &model).unwrap();
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(!ok && text.contains("model.bpk"), "{text}");
    no_partial("foreign checkpoint");

    // A truncated checkpoint.
    std::fs::write(&model, &original[..original.len() / 3]).unwrap();
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(!ok && text.contains("model.bpk"), "{text}");
    no_partial("truncated checkpoint");

    // Restored, it exports; a later failure leaves that bundle as it was.
    std::fs::write(&model, &original).unwrap();
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    let before = std::fs::read(bundle.join("coarse.onnx")).unwrap();
    std::fs::write(&model, b"garbage").unwrap();
    let (ok, _) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(!ok);
    assert_eq!(std::fs::read(bundle.join("coarse.onnx")).unwrap(), before, "the old bundle is untouched");
}
