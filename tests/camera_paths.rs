//! nerfstudio camera paths (`--camera-path`): a path written by hand in nerfstudio's format
//! renders through `nerf render` (burn) and `nerf-render` (onnxruntime) to the same frames
//! (≥ 60 dB between them) and the same animation; bad files are refused by both, naming the key,
//! before anything is written. A path's poses are in the capture's own coordinates: on a capture
//! in arbitrary units, a path through its test cameras renders its test views. A path's rays go
//! through the run's or bundle's pixel centres: on a Blender scene (integer centres) a path
//! through the test poses renders `--split test`'s views through both binaries.

mod common;

use common::{nerf, nerf_render, s, tiny_config, trained_run};
use glam::Vec3;
use image::AnimationDecoder;
use nerf::train::{TrainOptions, train};
use nerf_core::dataset::{Split, SyntheticSceneConfig, render_reference, split_poses};
use nerf_core::frames::raw::load_npy;
use nerf_core::io::image::save_png_rgba;
use nerf_core::render::metrics::psnr;
use nerf_core::{PinholeCamera, PixelCenter};
use std::path::Path;

/// Three cameras 4 units from the generated scene's centre, looking at it: from +z (identity
/// rotation), from +x (camera −z along world −x) and from −y (camera −z along world +y, up +z);
/// 24×18 pixels, fields of view 50°, 40° and 60°, 1.5 s in all.
const PATH: &str = r#"{
  "camera_type": "perspective",
  "render_height": 18,
  "render_width": 24,
  "camera_path": [
    {"camera_to_world": [1, 0, 0, 0,  0, 1, 0, 0,  0, 0, 1, 4,  0, 0, 0, 1], "fov": 50, "aspect": 1.3333},
    {"camera_to_world": [0, 0, 1, 4,  0, 1, 0, 0,  -1, 0, 0, 0,  0, 0, 0, 1], "fov": 40, "aspect": 1.3333},
    {"camera_to_world": [1, 0, 0, 0,  0, 0, -1, -4,  0, 1, 0, 0,  0, 0, 0, 1], "fov": 60, "aspect": 1.3333}
  ],
  "fps": 2,
  "seconds": 1.5,
  "smoothness_value": 0,
  "is_cycle": false,
  "crop": null
}"#;

/// The rgb of `<dir>/<name>.npy`: (height, width, pixels).
fn rgb(dir: &Path, name: &str) -> (usize, usize, Vec<[f32; 3]>) {
    let (h, w, v) = load_npy(&dir.join(format!("{name}.npy"))).unwrap();
    (h, w, v.chunks_exact(5).map(|p| [p[0], p[1], p[2]]).collect())
}

#[test]
fn a_hand_written_camera_path_renders_the_same_through_both_binaries() {
    let dir = tempfile::tempdir().unwrap();
    let (_, run) = trained_run(dir.path());
    let bundle = dir.path().join("bundle");
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    let path = dir.path().join("camera_path.json");
    std::fs::write(&path, PATH).unwrap();
    let (burn, ort) = (dir.path().join("burn"), dir.path().join("ort"));
    let (ok, text) = nerf(&["render", "--run", s(&run), "--camera-path", s(&path), "--out", s(&burn), "--npy"]);
    assert!(ok, "{text}");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--camera-path", s(&path), "--out", s(&ort), "--npy"]);
    assert!(ok, "{text}");
    for k in 0..3 {
        let name = format!("frame_{k:05}");
        let ((h1, w1, a), (h2, w2, b)) = (rgb(&burn, &name), rgb(&ort, &name));
        assert_eq!((h1, w1, h2, w2), (18, 24, 18, 24), "{name}: the path's render size");
        let off_white = a.iter().flatten().map(|v| (1.0 - v).abs()).fold(0.0, f32::max);
        let db = psnr(&a, &b);
        println!("{name}: burn vs onnxruntime {db:.1} dB (largest deviation from white {off_white:.2})");
        assert!(off_white > 0.05, "{name} is blank: the camera misses the scene and parity would mean nothing");
        assert!(db >= 60.0, "{name}: burn vs onnxruntime {db:.1} dB");
        assert!(burn.join(format!("{name}.png")).is_file() && ort.join(format!("{name}_depth.png")).is_file());
    }
    // Frames differ from each other (the cameras moved), and the animation has them all, half a
    // second each (1.5 s over 3 cameras).
    assert!(psnr(&rgb(&ort, "frame_00000").2, &rgb(&ort, "frame_00001").2) < 40.0, "two cameras gave the same frame");
    for out in [&burn, &ort] {
        let gif = std::fs::File::open(out.join("camera_path.gif")).unwrap();
        let frames = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(gif)).unwrap().into_frames().collect_frames().unwrap();
        assert_eq!(frames.len(), 3, "{}", out.display());
        assert_eq!(frames[1].delay().numer_denom_ms(), (500, 1));
        assert!(!out.join("orbit.gif").exists() && !out.join("frame_00003.png").exists());
    }
    // nerf-render resizes the path with --width (focal scaled with it).
    let small = dir.path().join("small");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--camera-path", s(&path), "--width", "12", "--out", s(&small)]);
    assert!(ok, "{text}");
    assert_eq!(image::open(small.join("frame_00002.png")).unwrap().height(), 9);
}

#[test]
fn bad_camera_paths_are_refused_by_both_binaries_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let (_, run) = trained_run(dir.path());
    let bundle = dir.path().join("bundle");
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    let good: serde_json::Value = serde_json::from_str(PATH).unwrap();
    let cases: Vec<(&str, Box<dyn Fn(&mut serde_json::Value)>, &str)> = vec![
        ("missing", Box::new(|v: &mut serde_json::Value| drop(v.as_object_mut().unwrap().remove("render_height"))), "render_height: missing"),
        ("missing-fov", Box::new(|v: &mut serde_json::Value| drop(v["camera_path"][2].as_object_mut().unwrap().remove("fov"))), "camera_path[2].fov: missing"),
        ("15-floats", Box::new(|v: &mut serde_json::Value| drop(v["camera_path"][1]["camera_to_world"].as_array_mut().unwrap().pop())), "camera_path[1].camera_to_world: 15 numbers, expected 16"),
        ("fov-0", Box::new(|v: &mut serde_json::Value| v["camera_path"][0]["fov"] = 0.into()), "camera_path[0].fov: 0 is outside (0, 180) degrees"),
        ("fisheye", Box::new(|v: &mut serde_json::Value| v["camera_type"] = "fisheye".into()), "camera_type \"fisheye\": only perspective cameras are supported"),
    ];
    let mut files: Vec<(std::path::PathBuf, String)> = cases
        .into_iter()
        .map(|(name, edit, needle)| {
            let mut v = good.clone();
            edit(&mut v);
            let file = dir.path().join(format!("{name}.json"));
            std::fs::write(&file, serde_json::to_string_pretty(&v).unwrap()).unwrap();
            (file, needle.to_string())
        })
        .collect();
    // A NaN as Python's json.dump writes it (not JSON: read so the key is named).
    let nan = dir.path().join("nan.json");
    std::fs::write(&nan, PATH.replacen("0, 0, 1, 4,  0, 0, 0, 1]", "0, 0, 1, NaN,  0, 0, 0, 1]", 1)).unwrap();
    files.push((nan, "camera_path[0].camera_to_world[11]: NaN is not a finite number".into()));
    files.push((dir.path().join("nowhere.json"), "nowhere.json".into()));
    let out = dir.path().join("out");
    for (file, needle) in &files {
        let runs = [
            ("nerf render", nerf(&["render", "--run", s(&run), "--camera-path", s(file), "--out", s(&out)])),
            ("nerf-render", nerf_render(&["--bundle", s(&bundle), "--camera-path", s(file), "--out", s(&out)])),
        ];
        for (binary, (ok, text)) in runs {
            assert!(!ok, "{binary} accepted {}:\n{text}", file.display());
            assert!(text.contains(needle.as_str()) && text.contains(s(file)), "{binary}: the error for {} should name the file and {needle:?}:\n{text}", file.display());
            assert!(!out.exists(), "{binary} wrote {} for {}", out.display(), file.display());
        }
    }
    // A camera path is one thing to render: not with --orbit.
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--camera-path", s(&files[0].0), "--orbit", "--out", s(&out)]);
    assert!(!ok && text.contains("cannot be used with"), "{text}");
}

/// A capture in its own units (the generated scene ×10, moved by (100, 0, 0); an ideal camera
/// with half-pixel centres) and a camera path through its two test cameras, frames 0 and 8 of
/// 16 (their `transform_matrix` as `camera_to_world`, the fov of its focal length): `nerf-render
/// --camera-path` renders what `--split test --data` renders, through the bundle's placement.
#[test]
fn camera_path_poses_are_in_the_captures_coordinates() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("capture");
    std::fs::create_dir_all(capture.join("images")).unwrap();
    let focal = 16.0 / (0.5 * nerf_core::dataset::CAMERA_ANGLE_X).tan();
    let camera = PinholeCamera { width: 32, height: 32, fx: focal, fy: focal, cx: 16.0, cy: 16.0, pixel_center: PixelCenter::HalfPixel, distortion: None };
    let cfg = SyntheticSceneConfig { width: 32, height: 32, n_train: 14, n_val: 0, n_test: 2, seed: 3 };
    let fov = 2.0 * (16.0f64 / focal as f64).atan().to_degrees();
    let (mut frames, mut path) = (Vec::new(), Vec::new());
    for split in [Split::Train, Split::Test] {
        for (k, pose) in split_poses(&cfg, split).iter().enumerate() {
            let name = format!("{split}_{k}.png");
            save_png_rgba(&capture.join("images").join(&name), 32, 32, &render_reference(pose, &camera)).unwrap();
            let o = 10.0 * pose.origin() + Vec3::new(100.0, 0.0, 0.0);
            let r = pose.0;
            let m = [[r[0][0], r[0][1], r[0][2], o.x], [r[1][0], r[1][1], r[1][2], o.y], [r[2][0], r[2][1], r[2][2], o.z], [0.0, 0.0, 0.0, 1.0]];
            if frames.len() % 8 == 0 {
                path.push(serde_json::json!({"camera_to_world": m.concat(), "fov": fov, "aspect": 1.0}));
            }
            frames.push(serde_json::json!({"file_path": format!("images/{name}"), "transform_matrix": m}));
        }
    }
    let transforms = serde_json::json!({"fl_x": focal, "fl_y": focal, "cx": 16.0, "cy": 16.0, "w": 32, "h": 32, "frames": frames});
    std::fs::write(capture.join("transforms.json"), transforms.to_string()).unwrap();
    let path_file = dir.path().join("camera_path.json");
    let camera_path = serde_json::json!({"camera_type": "perspective", "render_width": 32, "render_height": 32, "fps": 1, "seconds": 2, "camera_path": path});
    std::fs::write(&path_file, camera_path.to_string()).unwrap();
    let run = dir.path().join("run");
    let mut config = tiny_config();
    config.iters = 20;
    train(&TrainOptions { format: None, data: capture.clone(), run: run.clone(), config, ndc: None, contract: None, downscale: 1, time_budget_min: None, iters: None, progress: false }).unwrap();
    let placement = nerf::run_dir::RunDir::open(&run).unwrap().read_source().unwrap().unwrap().placement.unwrap();
    assert!(placement.transform.scale < 0.5, "the capture's units were not rescaled: {:?}", placement.transform);
    let bundle = dir.path().join("bundle");
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    let (views, along) = (dir.path().join("views"), dir.path().join("path"));
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--split", "test", "--data", s(&capture), "--out", s(&views), "--npy"]);
    assert!(ok, "{text}");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--camera-path", s(&path_file), "--out", s(&along), "--npy"]);
    assert!(ok, "{text}");
    for (k, view) in ["train_0", "train_8"].iter().enumerate() {
        let (a, b) = (rgb(&views, view).2, rgb(&along, &format!("frame_{k:05}")).2);
        let off_white = a.iter().flatten().map(|v| (1.0 - v).abs()).fold(0.0, f32::max);
        let db = psnr(&a, &b);
        println!("test view {view}: --split test vs --camera-path {db:.1} dB");
        assert!(off_white > 0.05, "{view} is blank: the comparison would mean nothing");
        assert!(db >= 60.0, "{view}: --split test vs --camera-path {db:.1} dB");
    }
}

/// The generated Blender scene (integer pixel centres) and a camera path whose cameras are its
/// test poses (`transforms_test.json`'s matrices, `camera_angle_x` as the fov of the square
/// image): each binary renders the path's frames as its own `--split test` renders the test
/// views (≥ 60 dB). Rays through nerfstudio's half-pixel centres instead would shift every frame
/// by half a pixel against the views the field was trained on.
#[test]
fn a_camera_path_through_the_test_poses_renders_the_test_views() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, run) = trained_run(dir.path());
    let bundle = dir.path().join("bundle");
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    let scene_json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(bundle.join("scene.json")).unwrap()).unwrap();
    assert_eq!(scene_json["camera"]["pixel_center"], "integer", "the Blender scene's convention, which this test is about");
    let test: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(scene.join("transforms_test.json")).unwrap()).unwrap();
    let fov = test["camera_angle_x"].as_f64().unwrap().to_degrees();
    let frames = test["frames"].as_array().unwrap();
    let path: Vec<_> = frames.iter().map(|f| serde_json::json!({"camera_to_world": f["transform_matrix"], "fov": fov, "aspect": 1.0})).collect();
    let names: Vec<String> = frames.iter().map(|f| Path::new(f["file_path"].as_str().unwrap()).file_name().unwrap().to_str().unwrap().to_string()).collect();
    assert_eq!(names.len(), 2);
    let path_file = dir.path().join("camera_path.json");
    let camera_path = serde_json::json!({"camera_type": "perspective", "render_width": 32, "render_height": 32, "seconds": 2, "camera_path": path});
    std::fs::write(&path_file, camera_path.to_string()).unwrap();
    let out = |name: &str| dir.path().join(name);
    let runs = [
        ("nerf render", nerf(&["render", "--run", s(&run), "--split", "test", "--data", s(&scene), "--out", s(&out("burn-views")), "--npy"]), "burn-views"),
        ("nerf render", nerf(&["render", "--run", s(&run), "--camera-path", s(&path_file), "--out", s(&out("burn-path")), "--npy"]), "burn-path"),
        ("nerf-render", nerf_render(&["--bundle", s(&bundle), "--split", "test", "--data", s(&scene), "--out", s(&out("ort-views")), "--npy"]), "ort-views"),
        ("nerf-render", nerf_render(&["--bundle", s(&bundle), "--camera-path", s(&path_file), "--out", s(&out("ort-path")), "--npy"]), "ort-path"),
    ];
    for (binary, (ok, text), what) in runs {
        assert!(ok, "{binary} ({what}): {text}");
    }
    for (binary, views, along) in [("nerf render", "burn-views", "burn-path"), ("nerf-render", "ort-views", "ort-path")] {
        for (k, view) in names.iter().enumerate() {
            let (a, b) = (rgb(&out(views), view).2, rgb(&out(along), &format!("frame_{k:05}")).2);
            let off_white = a.iter().flatten().map(|v| (1.0 - v).abs()).fold(0.0, f32::max);
            let db = psnr(&a, &b);
            println!("{binary}, test view {view}: --split test vs --camera-path {db:.1} dB");
            assert!(off_white > 0.05, "{binary}: {view} is blank: the comparison would mean nothing");
            assert!(db >= 60.0, "{binary}, {view}: --split test vs --camera-path {db:.1} dB");
        }
    }
}
