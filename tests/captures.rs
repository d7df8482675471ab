//! A captured scene end to end: an instant-ngp `transforms.json` in arbitrary units (the
//! generated scene's cameras scaled ×10 and moved by (100, 0, 0)) trains, evaluates and renders
//! through the run's recorded placement, which data given later never changes; its bundle
//! records the placement and holds test poses in the field's frame.

mod common;

use common::{nerf, nerf_render, s, tiny_config};
use glam::Vec3;
use nerf::run_dir::RunDir;
use nerf::train::{TrainOptions, train};
use nerf_core::dataset::{Split, SyntheticSceneConfig, generate_scene, split_poses};
use std::path::{Path, PathBuf};

/// The world of the capture: `x' = 10·x + (100, 0, 0)`.
fn to_capture(p: Vec3) -> Vec3 {
    10.0 * p + Vec3::new(100.0, 0.0, 0.0)
}

/// A transforms.json (nerfstudio style: no aabb_scale) over the generated scene's train and
/// test views, with its images under `images/`.
fn capture(dir: &Path) -> PathBuf {
    let cfg = SyntheticSceneConfig { width: 32, height: 32, n_train: 14, n_val: 0, n_test: 2, seed: 3 };
    let scene = dir.join("scene");
    generate_scene(&scene, &cfg).unwrap();
    let out = dir.join("capture");
    std::fs::create_dir_all(out.join("images")).unwrap();
    let mut frames = Vec::new();
    for split in [Split::Train, Split::Test] {
        for (k, pose) in split_poses(&cfg, split).iter().enumerate() {
            let name = format!("{split}_{k}.png");
            std::fs::copy(scene.join(format!("{split}/r_{k}.png")), out.join("images").join(&name)).unwrap();
            let o = to_capture(pose.origin());
            let r = pose.0;
            let m = [[r[0][0], r[0][1], r[0][2], o.x], [r[1][0], r[1][1], r[1][2], o.y], [r[2][0], r[2][1], r[2][2], o.z], [0.0, 0.0, 0.0, 1.0]];
            frames.push(serde_json::json!({"file_path": format!("images/{name}"), "transform_matrix": m}));
        }
    }
    let focal = 16.0 / (0.5 * nerf_core::dataset::CAMERA_ANGLE_X).tan();
    let file = serde_json::json!({"fl_x": focal, "fl_y": focal, "cx": 16.0, "cy": 16.0, "w": 32, "h": 32, "k1": 0.01, "frames": frames});
    std::fs::write(out.join("transforms.json"), serde_json::to_string_pretty(&file).unwrap()).unwrap();
    out
}

#[test]
fn a_capture_trains_evaluates_and_renders_through_its_recorded_placement() {
    let dir = tempfile::tempdir().unwrap();
    let data = capture(dir.path());
    let run = dir.path().join("run");
    let mut config = tiny_config();
    config.iters = 20;
    train(&TrainOptions { format: None, data: data.clone(), run: run.clone(), config, downscale: 1, time_budget_min: None, iters: None, progress: false }).unwrap();

    // The fit: centred where the cameras look (the capture's (100, 0, 0)), the cameras, 40
    // units away there, on the cube's bound 1.5.
    let source = RunDir::open(&run).unwrap().read_source().unwrap().unwrap();
    let placement = source.placement.unwrap();
    let t = placement.transform;
    assert!((t.scale - 1.5 / 40.0).abs() < 1e-5, "{t:?}");
    assert!(t.apply_point(to_capture(Vec3::ZERO)).length() < 1e-4, "{t:?}");
    // near/far of a capture without bounds: 1.5/30 to 1.5 + √3·1.5, also in config.toml.
    let config = RunDir::open(&run).unwrap().read_config().unwrap();
    assert!((config.sampling.near - 0.05).abs() < 1e-6 && (config.sampling.far - 1.5 * (1.0 + 3f32.sqrt())).abs() < 1e-4);
    // The orbit circles the cameras around the centre.
    assert!(Vec3::from(placement.orbit.unwrap().target).length() < 1e-3);

    // Test = frames 0 and 8 of the 16 (train_0, train_8); eval and render them.
    let eval_dir = dir.path().join("eval");
    let (ok, text) = nerf(&["eval", "--run", s(&run), "--data", s(&data), "--split", "test", "--out", s(&eval_dir)]);
    assert!(ok, "{text}");
    assert!(eval_dir.join("train_0.png").is_file() && eval_dir.join("train_8.png").is_file(), "{text}");
    let (ok, text) = nerf(&["eval", "--run", s(&run), "--data", s(&data), "--split", "all", "--format", "instant-ngp", "--out", s(&dir.path().join("all"))]);
    assert!(ok && text.contains("16 views"), "{text}");
    let render = |out: &str| {
        let out = dir.path().join(out);
        let (ok, text) = nerf(&["render", "--run", s(&run), "--data", s(&data), "--split", "test", "--npy", "--out", s(&out)]);
        assert!(ok, "{text}");
        nerf_core::frames::load_npy(&out.join("train_0.npy")).unwrap().2
    };
    let before = render("before");
    // A far-away extra frame would move a refit's centre and scale; the run's placement holds.
    let mut file: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(data.join("transforms.json")).unwrap()).unwrap();
    let far = serde_json::json!({"file_path": "images/train_1.png", "transform_matrix": [[1, 0, 0, 5000], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]});
    file["frames"].as_array_mut().unwrap().push(far);
    std::fs::write(data.join("transforms.json"), file.to_string()).unwrap();
    // (Equal up to the rounding of undoing the parser's own normalisation.)
    let after = render("after");
    let diff = after.iter().zip(&before).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(after.len() == before.len() && diff < 1e-3, "data given at evaluation changed the placement: max |Δ| {diff}");

    // The bundle records the placement; its test poses are already in the field's frame.
    let bundle = dir.path().join("bundle");
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    let scene = nerf_export::read_scene(&bundle).unwrap();
    assert_eq!(scene.placement.as_ref().unwrap().transform, t);
    assert_eq!(scene.camera.camera.distortion.unwrap().k1, 0.01);
    let test0 = scene.poses.test.iter().find(|p| p.name == "train_0").unwrap();
    let pose0 = split_poses(&SyntheticSceneConfig { width: 32, height: 32, n_train: 14, n_val: 0, n_test: 2, seed: 3 }, Split::Train)[0];
    let origin = Vec3::new(test0.transform_matrix[0][3], test0.transform_matrix[1][3], test0.transform_matrix[2][3]);
    assert!((origin - pose0.origin() * 1.5 / 4.0).length() < 1e-4, "{origin} vs {}", pose0.origin());
    // nerf-render renders the capture's own test split through the bundle's placement, with metrics.
    let ort = dir.path().join("ort");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--split", "test", "--data", s(&data), "--out", s(&ort)]);
    assert!(ok && text.contains("PSNR"), "{text}");
}
