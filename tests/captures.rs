//! A captured scene end to end: an instant-ngp `transforms.json` in arbitrary units (the
//! generated scene's cameras scaled ×10 and moved by (100, 0, 0)), seen through a phone's
//! camera (fx ≠ fy, cx ≠ W/2, distortion), trains, evaluates and renders through the run's
//! recorded placement, which data given later never changes; its bundle records the placement
//! and holds test poses in the field's frame. A forward-facing LLFF capture trains on NDC rays.
//! burn, onnxruntime and the numpy consumer render both alike.

mod common;

use common::{max_difference, nerf, nerf_render, python, s, tiny_ngp};
use glam::Vec3;
use nerf::run_dir::RunDir;
use nerf::train::{TrainOptions, train};
use nerf_core::io::image::save_png_rgba;
use nerf_core::{OpenCvDistortion, PinholeCamera, PixelCenter, Pose};
use nerf_core::dataset::{CameraPath, Split, SyntheticSceneConfig, render_reference, split_poses};
use std::path::{Path, PathBuf};

/// The world of the capture: `x' = 10·x + (100, 0, 0)`.
fn to_capture(p: Vec3) -> Vec3 {
    10.0 * p + Vec3::new(100.0, 0.0, 0.0)
}

/// The capture's camera as a phone would have it: fx ≠ fy, the principal point off the centre,
/// half-pixel centres and OpenCV distortion.
fn phone_camera() -> PinholeCamera {
    let focal = 16.0 / (0.5 * nerf_core::dataset::CAMERA_ANGLE_X).tan();
    let distortion = Some(OpenCvDistortion { k1: 0.01, k2: -0.002, p1: 0.001, p2: -0.0005 });
    PinholeCamera { width: 32, height: 32, fx: focal, fy: 1.05 * focal, cx: 15.3, cy: 16.6, pixel_center: PixelCenter::HalfPixel, distortion }
}

/// A transforms.json (nerfstudio style: no aabb_scale) over the generated scene's train and
/// test poses, its images (under `images/`) rendered through [`phone_camera`].
fn capture(dir: &Path) -> PathBuf {
    capture_exposed(dir, |_| 1.0)
}

/// [`capture`] with training image `k`'s colours scaled by `exposure(k)`.
fn capture_exposed(dir: &Path, exposure: impl Fn(usize) -> f32) -> PathBuf {
    capture_with(dir, exposure, |_, pose| pose)
}

/// [`capture`] with training image `k`'s colours scaled by `exposure(k)` and its pose recorded
/// as `recorded(k, its true pose)` (the image is taken from the true one).
fn capture_with(dir: &Path, exposure: impl Fn(usize) -> f32, recorded: impl Fn(usize, Pose) -> Pose) -> PathBuf {
    let cfg = SyntheticSceneConfig { width: 32, height: 32, n_train: 14, n_val: 0, n_test: 2, seed: 3 };
    let out = dir.join("capture");
    std::fs::create_dir_all(out.join("images")).unwrap();
    let camera = phone_camera();
    let mut frames = Vec::new();
    for split in [Split::Train, Split::Test] {
        for (k, pose) in split_poses(&cfg, split).iter().enumerate() {
            let name = format!("{split}_{k}.png");
            let gain = if split == Split::Train { exposure(k) } else { 1.0 };
            let image: Vec<[f32; 4]> = render_reference(pose, &camera).iter().map(|p| [p[0] * gain, p[1] * gain, p[2] * gain, p[3]]).collect();
            save_png_rgba(&out.join("images").join(&name), 32, 32, &image).unwrap();
            let pose = if split == Split::Train { recorded(k, *pose) } else { *pose };
            frames.push(serde_json::json!({"file_path": format!("images/{name}"), "transform_matrix": capture_matrix(&pose)}));
        }
    }
    let d = camera.distortion.unwrap();
    let file = serde_json::json!({"fl_x": camera.fx, "fl_y": camera.fy, "cx": camera.cx, "cy": camera.cy, "w": 32, "h": 32,
        "k1": d.k1, "k2": d.k2, "p1": d.p1, "p2": d.p2, "frames": frames});
    std::fs::write(out.join("transforms.json"), serde_json::to_string_pretty(&file).unwrap()).unwrap();
    out
}

/// `pose` in the capture's world, as transforms.json's row-major 4×4.
fn capture_matrix(pose: &Pose) -> [[f32; 4]; 4] {
    let o = to_capture(pose.origin());
    let r = pose.0;
    [[r[0][0], r[0][1], r[0][2], o.x], [r[1][0], r[1][1], r[1][2], o.y], [r[2][0], r[2][1], r[2][2], o.z], [0.0, 0.0, 0.0, 1.0]]
}

/// `nerf render --npy` (burn) vs the `nerf-render --npy` frame at `ort_npy` (onnxruntime) for
/// view `name` of `data`'s test split: the largest difference, after checking that the frame
/// is not flat (parity on a blank image would mean nothing). Then the numpy consumer renders
/// rays of test pose 0 and must agree with onnxruntime.
fn check_parity(run: &Path, bundle: &Path, data: &Path, name: &str, ort_npy: &Path, out: &Path) -> f32 {
    let (ok, text) = nerf(&["render", "--run", s(run), "--split", "test", "--data", s(data), "--out", s(out), "--npy"]);
    assert!(ok, "{text}");
    let (_, _, a) = nerf_core::frames::raw::load_npy(&out.join(format!("{name}.npy"))).unwrap();
    let (_, _, b) = nerf_core::frames::raw::load_npy(ort_npy).unwrap();
    let red = || a.chunks_exact(5).map(|p| p[0]);
    assert!(red().fold(f32::INFINITY, f32::min) < red().fold(0.0, f32::max) - 0.1, "a flat image: parity would mean nothing");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/render_rays.py");
    let py = std::process::Command::new(python())
        .args([s(&script), s(bundle), "--npy", s(ort_npy), "--test-pose", "0"])
        .output()
        .unwrap_or_else(|e| panic!("cannot run {} ({e}): run scripts/setup.sh and source scripts/env.sh", python()));
    let text = format!("{}{}", String::from_utf8_lossy(&py.stdout), String::from_utf8_lossy(&py.stderr));
    assert!(py.status.success(), "render_rays.py: {text}");
    // r, g, b and acc are in [0, 1]; depth is in world units (up to `far`, 100 for a contracted
    // capture), so it is compared relative to its size (as ngp_parity.rs compares σ): a depth of
    // 50 carries rounding of 4e-6.
    let channel = |v: &[f32], c: usize| v.chunks_exact(5).map(|p| p[c]).collect::<Vec<f32>>();
    ["r", "g", "b", "depth", "acc"]
        .iter()
        .enumerate()
        .map(|(c, what)| {
            let scale: fn(f32) -> f32 = if *what == "depth" { |d| d.abs().max(1.0) } else { |_| 1.0 };
            max_difference(what, &channel(&a, c), &channel(&b, c), scale)
        })
        .fold(0.0f32, f32::max)
}

/// Train the tiny hash-grid field on `data` for `iters` steps, NDC as `ndc` says, in the cube
/// (the generated ring would contract by default: that has its own test).
fn train_capture(data: &Path, run: &Path, iters: usize, ndc: Option<bool>) {
    let config = tiny_ngp();
    let options = TrainOptions { format: None, data: data.to_path_buf(), run: run.to_path_buf(), config, ndc, contract: Some(false), downscale: 1, time_budget_min: None, iters: Some(iters), progress: false };
    train(&options).unwrap();
}

#[test]
fn a_capture_trains_evaluates_and_renders_through_its_recorded_placement() {
    let dir = tempfile::tempdir().unwrap();
    let data = capture(dir.path());
    let run = dir.path().join("run");
    train_capture(&data, &run, 60, None);

    // The fit: centred where the cameras look (the capture's (100, 0, 0)), the cameras, 40
    // units away there, at a third of the cube's bound 1.5.
    let source = RunDir::open(&run).unwrap().read_source().unwrap().unwrap();
    let placement = source.placement.unwrap();
    let t = placement.transform;
    assert!((t.scale - 0.5 / 40.0).abs() < 1e-5, "{t:?}");
    assert!(t.apply_point(to_capture(Vec3::ZERO)).length() < 1e-4, "{t:?}");
    // near/far of a capture without bounds: 1.5/30 to 0.5 + √3·1.5, also in config.toml.
    let config = RunDir::open(&run).unwrap().read_config().unwrap();
    assert!((config.sampling.near - 0.05).abs() < 1e-6 && (config.sampling.far - (0.5 + 1.5 * 3f32.sqrt())).abs() < 1e-4);
    // Photos in the world train with the distortion loss against floaters; in the cube, cells
    // one camera alone sees stay empty. The test's own march_steps and target_samples (not the
    // preset's) are kept.
    assert_eq!(config.distortion_loss, Some(nerf::config::CAPTURE_DISTORTION_LOSS));
    assert_eq!(config.occupancy.min_views, nerf::config::CUBE_CAPTURE.min_views);
    assert_eq!((config.march_steps, config.target_samples), (tiny_ngp().march_steps, tiny_ngp().target_samples));
    // The orbit circles the cameras around the centre.
    let Some(CameraPath::Circle(orbit)) = placement.orbit else { panic!("{:?}", placement.orbit) };
    assert!(Vec3::from(orbit.target).length() < 1e-3);

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
        nerf_core::frames::raw::load_npy(&out.join("train_0.npy")).unwrap().2
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
    let scene = nerf_bundle::read_scene(&bundle).unwrap();
    assert_eq!(scene.placement.as_ref().unwrap().transform, t);
    assert_eq!(scene.camera.camera, phone_camera());
    let test0 = scene.poses.test.iter().find(|p| p.name == "train_0").unwrap();
    let pose0 = split_poses(&SyntheticSceneConfig { width: 32, height: 32, n_train: 14, n_val: 0, n_test: 2, seed: 3 }, Split::Train)[0];
    let origin = Vec3::new(test0.transform_matrix[0][3], test0.transform_matrix[1][3], test0.transform_matrix[2][3]);
    assert!((origin - pose0.origin() * 0.5 / 4.0).length() < 1e-4, "{origin} vs {}", pose0.origin());
    // nerf-render renders the capture's own test split through the bundle's placement, with metrics.
    let ort = dir.path().join("ort");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--split", "test", "--data", s(&data), "--out", s(&ort), "--npy"]);
    assert!(ok && text.contains("PSNR"), "{text}");
    // burn, onnxruntime and the numpy consumer agree on the captured camera's rays.
    let diff = check_parity(&run, &bundle, &data, "train_0", &ort.join("train_0.npy"), &dir.path().join("burn"));
    assert!(diff < 1e-3, "burn vs onnxruntime on a captured scene: max |Δ| {diff}");
}

#[test]
fn a_run_recorded_without_the_distortion_key_resumes_without_the_loss() {
    let dir = tempfile::tempdir().unwrap();
    let data = capture(dir.path());
    // Three runs alike (seeded) up to step 3; then each resumes to step 6 with `config.toml`
    // as a run from before the key has it (absent), with 0, and as recorded (0.01).
    let table_at_6 = |name: &str, recorded: Option<&str>| {
        let run = dir.path().join(name);
        train_capture(&data, &run, 3, None);
        let path = run.join("config.toml");
        let text = std::fs::read_to_string(&path).unwrap();
        let line = format!("distortion_loss = {}\n", nerf::config::CAPTURE_DISTORTION_LOSS);
        assert!(text.contains(&line), "{text}");
        std::fs::write(&path, text.replace(&line, recorded.unwrap_or(""))).unwrap();
        train_capture(&data, &run, 6, None);
        let checkpoint = RunDir::open(&run).unwrap().latest_checkpoint().unwrap().unwrap();
        assert!(checkpoint.dir.ends_with("step-0000006"), "{}", checkpoint.dir.display());
        std::fs::read(checkpoint.dir.join(nerf::field::ngp::GRID_FILE)).unwrap()
    };
    let absent = table_at_6("absent", None);
    let off = table_at_6("off", Some("distortion_loss = 0.0\n"));
    let on = table_at_6("on", Some(&format!("distortion_loss = {}\n", nerf::config::CAPTURE_DISTORTION_LOSS)));
    assert!(absent == off, "a run recorded without the key resumed with a loss");
    assert!(absent != on, "the loss left the table unchanged: the test cannot tell");
}

#[test]
fn a_capture_without_a_small_scene_box_contracts_by_default() {
    let dir = tempfile::tempdir().unwrap();
    let data = capture(dir.path());
    let train_one = |run: &str, extra: &[&str]| -> (bool, String, PathBuf) {
        let out = dir.path().join(run);
        let mut args = vec!["train", "--data", s(&data), "--iters", "1", "--out", s(&out)];
        args.extend_from_slice(extra);
        let (ok, text) = nerf(&args);
        (ok, text, out)
    };
    let contraction = |run: &str, extra: &[&str]| {
        let (ok, text, out) = train_one(run, extra);
        assert!(ok, "{text}");
        (RunDir::open(&out).unwrap().read_config().unwrap().occupancy.contraction, text)
    };
    // A ring of cameras looking in, no scene box: contracted, and said so.
    let (c, text) = contraction("ring", &[]);
    assert_eq!(c, Some(nerf_core::sample::Contraction::Linf), "{text}");
    assert!(text.contains("contracting the world around the capture") && text.contains("--contract false keeps the cube"), "{text}");
    let (c, text) = contraction("cube", &["--contract", "false"]);
    assert!(c.is_none() && !text.contains("contracting"), "{text}");
    // The cube's photos march coarser intervals in smaller steps, said so; contracted ones keep
    // the preset's.
    let steps = |run: &str| RunDir::open(&dir.path().join(run)).unwrap().read_config().unwrap().march_steps;
    assert_eq!((steps("cube"), steps("ring")), (nerf::config::CUBE_CAPTURE.march_steps, nerf::config::Preset::Ngp.config().march_steps));
    assert!(text.contains("photos in the cube: march_steps = 512"), "{text}");
    // An instant-ngp box under 8 bounds the scene (the cube); 16 says the background reaches far.
    let file: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(data.join("transforms.json")).unwrap()).unwrap();
    for (aabb, contracted) in [(4, false), (16, true)] {
        let mut boxed = file.clone();
        boxed["aabb_scale"] = aabb.into();
        std::fs::write(data.join("transforms.json"), boxed.to_string()).unwrap();
        let (c, text) = contraction(&format!("aabb{aabb}"), &[]);
        assert_eq!(c.is_some(), contracted, "aabb_scale {aabb}: {text}");
    }
    // A configuration that contracts, told not to: refused, nothing trained.
    let (ok, text, out) = train_one("refused", &["--config", s(&dir.path().join("ring/config.toml")), "--contract", "false"]);
    assert!(!ok && text.contains("--contract false, but the configuration contracts"), "{text}");
    assert!(!out.join("checkpoints").exists(), "{text}");
}

/// An LLFF capture of the generated scene seen from the front: of nine cameras on a 3×3 grid
/// in the plane z = 4, all looking down −z (forward-facing), the views `keep`; 40×30 images,
/// bounds 2.5..6; written to `dir/name`.
fn forward_facing_capture(dir: &Path, name: &str, keep: &[usize]) -> PathBuf {
    let out = dir.join(name);
    std::fs::create_dir_all(out.join("images")).unwrap();
    let (w, h, focal) = (40u32, 30u32, 36.0f32);
    let camera = PinholeCamera { width: w, height: h, fx: focal, fy: focal, cx: 20.0, cy: 15.0, pixel_center: PixelCenter::Integer, distortion: None };
    let mut rows = Vec::new();
    for &k in keep {
        let (x, y) = (0.3 * (k % 3) as f32 - 0.3, 0.2 * (k / 3) as f32 - 0.2);
        let pose = Pose::from_rows([[1.0, 0.0, 0.0, x], [0.0, 1.0, 0.0, y], [0.0, 0.0, 1.0, 4.0], [0.0, 0.0, 0.0, 1.0]]);
        let rgba = render_reference(&pose, &camera);
        let bytes: Vec<u8> = rgba.iter().flat_map(|p| p.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)).collect();
        image::RgbaImage::from_raw(w, h, bytes).unwrap().save(out.join(format!("images/{k:03}.png"))).unwrap();
        // LLFF columns [down, right, back | centre | hwf] (right = +x, up = +y, back = +z).
        let m = [[0.0, 1.0, 0.0, x, h as f32], [-1.0, 0.0, 0.0, y, w as f32], [0.0, 0.0, 1.0, 4.0, focal]];
        rows.extend(m.iter().flatten().map(|&v| v as f64));
        rows.extend([2.5, 6.0]);
    }
    // numpy's format 1.0: magic, header length, the dict padded to 64 bytes, then '<f8' data.
    let mut header = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({}, 17), }}", keep.len());
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut npy = b"\x93NUMPY\x01\x00".to_vec();
    npy.extend((header.len() as u16).to_le_bytes());
    npy.extend(header.as_bytes());
    npy.extend(rows.iter().flat_map(|v| v.to_le_bytes()));
    std::fs::write(out.join("poses_bounds.npy"), npy).unwrap();
    out
}

#[test]
fn a_forward_facing_capture_trains_on_ndc_rays_and_renders_alike_everywhere() {
    let dir = tempfile::tempdir().unwrap();
    let data = forward_facing_capture(dir.path(), "llff", &(0..9).collect::<Vec<_>>());
    let run = dir.path().join("run");
    train_capture(&data, &run, 60, None);

    // NDC was chosen (LLFF, forward-facing): near/far 0..1, the first camera's projection with
    // nerf-pytorch's near plane 1, random backgrounds for a capture, a spiral for renders.
    let config = RunDir::open(&run).unwrap().read_config().unwrap();
    let ndc = config.sampling.ndc.expect("NDC rays for a forward-facing LLFF capture");
    assert_eq!((config.sampling.near, config.sampling.far), (0.0, 1.0));
    assert_eq!((ndc.width, ndc.height, ndc.fx, ndc.near), (40.0, 30.0, 36.0, 1.0));
    assert_eq!(config.train_background, Some(nerf_core::dataset::Background::Random));
    // NDC rays lost with the distortion loss (fern): off, as the cube's settings.
    assert_eq!(config.distortion_loss, Some(0.0));
    assert_eq!(config.occupancy.min_views, 0);
    let placement = RunDir::open(&run).unwrap().read_source().unwrap().unwrap().placement.unwrap();
    assert_eq!(placement.ndc, Some(ndc));
    assert!(matches!(placement.orbit, Some(CameraPath::Spiral(_))), "{:?}", placement.orbit);

    // burn, onnxruntime and numpy render the held-out view 000 alike, and it shows the scene.
    let bundle = dir.path().join("bundle");
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    let scene_json: serde_json::Value = serde_json::from_slice(&std::fs::read(bundle.join("scene.json")).unwrap()).unwrap();
    assert_eq!(scene_json["sampling"]["ndc"]["fx"], 36.0);
    let ort_out = dir.path().join("ort");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--split", "test", "--data", s(&data), "--limit", "1", "--out", s(&ort_out), "--npy"]);
    assert!(ok && text.contains("PSNR"), "{text}");
    // The numpy consumer warps the rays itself (check_parity runs it).
    let diff = check_parity(&run, &bundle, &data, "000", &ort_out.join("000.npy"), &dir.path().join("burn"));
    assert!(diff < 1e-3, "burn vs onnxruntime on NDC rays: max |Δ| {diff}");
    // Views the run never had, in a folder of their own (its poses_bounds.npy normalises
    // differently): --split all renders them through the run's placement, as the test split.
    let held = forward_facing_capture(dir.path(), "held", &[0]);
    let (ok, text) = nerf(&["render", "--run", s(&run), "--split", "all", "--data", s(&held), "--out", s(&dir.path().join("held-out")), "--npy"]);
    assert!(ok, "{text}");
    let (_, _, a) = nerf_core::frames::raw::load_npy(&dir.path().join("held-out/000.npy")).unwrap();
    let (_, _, b) = nerf_core::frames::raw::load_npy(&dir.path().join("burn/000.npy")).unwrap();
    let moved = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
    assert!(moved < 1e-3, "a view given in another file renders elsewhere: max |Δ| {moved}");

    // The orbit (a spiral, through NDC rays) renders; with --ndc false the same data trains
    // in the field's cube instead.
    let (ok, text) = nerf(&["render", "--run", s(&run), "--orbit", "--frames", "2", "--out", s(&dir.path().join("orbit"))]);
    assert!(ok && dir.path().join("orbit/orbit.gif").is_file(), "{text}");
    let cube = dir.path().join("cube");
    train_capture(&data, &cube, 2, Some(false));
    let config = RunDir::open(&cube).unwrap().read_config().unwrap();
    assert_eq!((config.sampling.ndc, config.distortion_loss), (None, Some(nerf::config::CAPTURE_DISTORTION_LOSS)));
}

#[test]
fn a_contracted_capture_renders_alike_everywhere() {
    let dir = tempfile::tempdir().unwrap();
    let data = capture(dir.path());
    let run = dir.path().join("run");
    let config = tiny_ngp().contracted(nerf_core::sample::Contraction::Linf).unwrap();
    let options = TrainOptions { format: None, data: data.clone(), run: run.clone(), config, ndc: None, contract: None, downscale: 1, time_budget_min: None, iters: Some(60), progress: false };
    train(&options).unwrap();

    // The cameras (40 units from where they look) on the unit sphere; near 1/30, far 100; the
    // grids' cube the contracted ±2.
    let placement = RunDir::open(&run).unwrap().read_source().unwrap().unwrap().placement.unwrap();
    assert!((placement.transform.scale - 1.0 / 40.0).abs() < 1e-6, "{:?}", placement.transform);
    let config = RunDir::open(&run).unwrap().read_config().unwrap();
    assert_eq!((config.sampling.near, config.sampling.far), (1.0 / 30.0, 100.0));
    assert_eq!((config.occupancy.bound, config.occupancy.contraction), (2.0, Some(nerf_core::sample::Contraction::Linf)));

    // Its bundle says so (scene-3, a NERFOCC2 grid); burn, onnxruntime and numpy render alike.
    let bundle = dir.path().join("bundle");
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    let scene = nerf_bundle::read_scene(&bundle).unwrap();
    assert_eq!((scene.format.as_str(), scene.contraction), ("nerf-rs-scene-3", Some(nerf_core::sample::Contraction::Linf)));
    // Rendered with the training march steps (the cube's runs render with more).
    assert_eq!((config.render_march_steps, scene.march_steps), (Some(config.march_steps), config.march_steps));
    assert_eq!(&std::fs::read(bundle.join("occupancy.bin")).unwrap()[..8], b"NERFOCC2");
    let ort = dir.path().join("ort");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--split", "test", "--data", s(&data), "--out", s(&ort), "--npy"]);
    assert!(ok && text.contains("PSNR"), "{text}");
    let diff = check_parity(&run, &bundle, &data, "train_0", &ort.join("train_0.npy"), &dir.path().join("burn"));
    assert!(diff < 1e-5, "burn vs onnxruntime, contracted: max |Δ| {diff}");

    // Contraction is for the hash-grid field, and not with NDC rays.
    let (ok, text) = nerf(&["train", "--data", s(&data), "--contract", "--preset", "paper", "--out", s(&dir.path().join("mlp"))]);
    assert!(!ok && text.contains("--contract: a contracted scene needs the ngp field"), "{text}");
    let (ok, text) = nerf(&["train", "--data", s(&data), "--contract", "--ndc", "true", "--iters", "1", "--out", s(&dir.path().join("ndc"))]);
    assert!(!ok && text.contains("transforms.json") && text.contains("exclude each other"), "{text}");
}

#[test]
fn appearance_codes_learn_each_image_exposure_and_bundles_hold_the_fixed_one() {
    let dir = tempfile::tempdir().unwrap();
    // Odd training images taken at 60% of the exposure of the others.
    let gain = |k: usize| if k % 2 == 1 { 0.6 } else { 1.0 };
    let data = capture_exposed(dir.path(), gain);
    let run = dir.path().join("run");
    let config = nerf::config::TrainConfig { appearance: true, ..tiny_ngp() };
    let options = TrainOptions { format: None, data: data.clone(), run: run.clone(), config, ndc: None, contract: Some(false), downscale: 1, time_budget_min: None, iters: Some(120), progress: false };
    train(&options).unwrap();

    // Each image's code renders its exposure: the field through a dark image's code is darker
    // than through a bright one's, from the same pose.
    let loaded = nerf::field::load_latest(&RunDir::open(&run).unwrap(), &nerf::backend::cpu()).unwrap();
    let mut field = loaded.model;
    assert_eq!(field.appearance(), Some(&nerf_bundle::scene::FixedAppearance::Mean));
    let camera = phone_camera();
    let pose = split_poses(&SyntheticSceneConfig { width: 32, height: 32, n_train: 14, n_val: 0, n_test: 2, seed: 3 }, Split::Test)[0];
    let mut brightness = |image: &str| {
        field.fix_appearance(&nerf_bundle::scene::FixedAppearance::parse(image)).unwrap();
        let rendered = field.render(&nerf::backend::cpu(), loaded.occupancy.as_ref(), &camera, &pose, &loaded.config.render_options(), &mut |_, _| {});
        // The object's own colour: the pixels less the white behind them, per unit of opacity.
        let r = &rendered.rays;
        let colour: f64 = r.rgb.iter().zip(&r.acc).map(|(p, &a)| (p[0] + p[1] + p[2] - 3.0 * (1.0 - a)) as f64).sum();
        colour / r.acc.iter().map(|&a| a as f64).sum::<f64>()
    };
    // The run's training images (the loader holds some of the file's frames back for testing).
    let codes: serde_json::Value = serde_json::from_slice(&std::fs::read(RunDir::open(&run).unwrap().latest_checkpoint().unwrap().unwrap().dir.join("appearance.json")).unwrap()).unwrap();
    let images: Vec<String> = codes["images"].as_array().unwrap().iter().map(|v| v.as_str().unwrap().to_string()).collect();
    let is_dark = |name: &str| name.strip_prefix("train_").is_some_and(|k| gain(k.parse().unwrap()) < 1.0);
    let (dark_images, bright_images): (Vec<&String>, Vec<&String>) = images.iter().partition(|n| is_dark(n));
    assert!(dark_images.len() >= 4 && bright_images.len() >= 4, "{images:?}");
    let mut average = |names: &[&String]| names.iter().map(|n| brightness(n)).sum::<f64>() / names.len() as f64;
    let (dark, bright) = (average(&dark_images), average(&bright_images));
    let mean = brightness("mean");
    assert!(dark < 0.9 * bright && dark < mean && mean < bright, "rendered brightness: dark images' codes {dark:.3}, bright ones' {bright:.3}, the mean {mean:.3}");
    let held_back = (0..14).map(|k| format!("train_{k}")).find(|n| !images.contains(n)).unwrap();
    let err = field.fix_appearance(&nerf_bundle::scene::FixedAppearance::parse(&held_back)).unwrap_err();
    assert!(err.contains(&format!("{held_back:?}")) && err.contains(&images[..2].join(", ")), "{err}");

    // The bundle holds the mean code as color.0's bias and says so; burn, onnxruntime and numpy
    // render alike.
    let code = |k: usize| -> Vec<f32> { codes["codes"].as_array().unwrap()[k * 32..(k + 1) * 32].iter().map(|v| v.as_f64().unwrap() as f32).collect() };
    let n = images.len();
    let bias_of = |bundle: &Path| {
        let model = nerf_bundle::read_model(&bundle.join("field.onnx")).unwrap();
        nerf_bundle::ngp::read_ngp(&model).unwrap().layers[2].bias.clone()
    };
    let bundle = dir.path().join("bundle");
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    assert_eq!(nerf_bundle::read_scene(&bundle).unwrap().appearance, Some(nerf_bundle::scene::FixedAppearance::Mean));
    let mean_code: Vec<f32> = (0..32).map(|c| ((0..n).map(|k| code(k)[c] as f64).sum::<f64>() / n as f64) as f32).collect();
    assert_eq!(bias_of(&bundle), mean_code);
    assert!(mean_code.iter().any(|&v| v.abs() > 1e-3), "the codes moved: {mean_code:?}");
    let ort = dir.path().join("ort");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--split", "test", "--data", s(&data), "--out", s(&ort), "--npy"]);
    assert!(ok, "{text}");
    let diff = check_parity(&run, &bundle, &data, &held_back, &ort.join(format!("{held_back}.npy")), &dir.path().join("burn"));
    assert!(diff < 1e-5, "burn vs onnxruntime with an appearance code: max |Δ| {diff}");

    // Another image's code on request; unknown names and bundles are refused clearly.
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle), "--appearance", &images[3]]);
    assert!(ok, "{text}");
    assert_eq!(nerf_bundle::read_scene(&bundle).unwrap().appearance, Some(nerf_bundle::scene::FixedAppearance::parse(&images[3])));
    assert_eq!(bias_of(&bundle), code(3));
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&dir.path().join("nope")), "--appearance", "IMG_9"]);
    assert!(!ok && text.contains("--appearance") && text.contains("IMG_9") && text.contains(&images[0]), "{text}");
    assert!(!dir.path().join("nope").exists());
    let (ok, text) = nerf(&["export", "--bundle", s(&bundle), "--out", s(&dir.path().join("again")), "--appearance", "mean"]);
    assert!(!ok && text.contains("give --run"), "{text}");
    let plain = dir.path().join("plain");
    train_capture(&data, &plain, 2, None);
    let (ok, text) = nerf(&["export", "--run", s(&plain), "--out", s(&dir.path().join("plain-bundle")), "--appearance", "mean"]);
    assert!(!ok && text.contains("trained without --appearance"), "{text}");
    let (ok, text) = nerf(&["train", "--data", s(&data), "--appearance", "--preset", "paper", "--iters", "1", "--out", s(&dir.path().join("mlp"))]);
    assert!(!ok && text.contains("appearance codes are the ngp field's"), "{text}");
}

#[test]
fn refined_cameras_are_saved_resumed_and_render_the_training_views() {
    let dir = tempfile::tempdir().unwrap();
    // Odd training images recorded 2° off their true orientation (about the world's vertical
    // axis through the camera).
    let misrecord = |k: usize, pose: Pose| {
        if k.is_multiple_of(2) {
            return pose;
        }
        let r = glam::Mat3::from_rotation_y(2f32.to_radians()) * pose.rotation();
        let c = pose.origin();
        Pose([0, 1, 2].map(|i| [r.col(0)[i], r.col(1)[i], r.col(2)[i], c[i]]))
    };
    let data = capture_with(dir.path(), |_| 1.0, misrecord);
    let run = dir.path().join("run");
    let config = nerf::config::TrainConfig { refine_cameras: true, ..tiny_ngp() };
    let iters = nerf::train::cameras::WARM_UP_STEPS + 60;
    let options = TrainOptions { format: None, data: data.clone(), run: run.clone(), config, ndc: None, contract: Some(false), downscale: 1, time_budget_min: None, iters: Some(iters), progress: false };
    train(&options).unwrap();

    // cameras.json: a correction per training image, small, and the poses they refine to.
    let checkpoint = RunDir::open(&run).unwrap().latest_checkpoint().unwrap().unwrap();
    let file: serde_json::Value = serde_json::from_slice(&std::fs::read(checkpoint.dir.join("cameras.json")).unwrap()).unwrap();
    let refined: Vec<Pose> = serde_json::from_value(file["refined_poses"].clone()).unwrap();
    let images: Vec<String> = serde_json::from_value(file["images"].clone()).unwrap();
    let corrections: Vec<[f32; 6]> = serde_json::from_value(file["corrections"].clone()).unwrap();
    assert_eq!((refined.len(), corrections.len()), (images.len(), images.len()));
    let largest = corrections.iter().fold(0.0f32, |m, c| m.max(Vec3::from_slice(&c[..3]).length()));
    assert!(largest > 1e-5 && largest < 1f32.to_radians(), "largest rotation {largest} rad");
    let transform = nerf::run_dir::RunSource::transform_of(RunDir::open(&run).unwrap().read_source().unwrap().as_ref());

    // Renders of the training views use the refined poses; of the test views, their own.
    let (ok, text) = nerf(&["eval", "--run", s(&run), "--data", s(&data), "--split", "train", "--out", s(&dir.path().join("train-eval"))]);
    assert!(ok, "{text}");
    let loaded = nerf::evaluate::LoadedRun::open(&run).unwrap();
    let choice = nerf_core::frames::views::SplitChoice { dir: data.clone(), format: None, split: nerf_core::dataset::CaptureSplit::Train, downscale: 1 };
    let views = loaded.split_views(&choice, nerf_core::frames::views::Images::Skip).unwrap();
    for v in &views {
        let k = images.iter().position(|n| *n == v.name).unwrap();
        let close = v.pose.0.iter().flatten().zip(refined[k].0.iter().flatten()).all(|(a, b)| (a - b).abs() < 1e-6);
        assert!(close, "{}: {:?} vs the refined {:?}", v.name, v.pose, refined[k]);
    }
    let as_recorded = nerf_core::frames::views::split_views(&choice, transform, nerf_core::dataset::Background::White, nerf_core::frames::views::Images::Skip).unwrap();
    let moved = views.iter().zip(&as_recorded).filter(|(a, b)| a.pose.0.iter().flatten().zip(b.pose.0.iter().flatten()).any(|(x, y)| (x - y).abs() > 1e-5)).count();
    assert!(moved > views.len() / 2, "only {moved} of {} training views render from a refined pose", views.len());
    let test = nerf_core::frames::views::SplitChoice { split: nerf_core::dataset::CaptureSplit::Test, ..choice };
    let recorded = nerf_core::frames::views::split_views(&test, transform, nerf_core::dataset::Background::White, nerf_core::frames::views::Images::Skip).unwrap();
    assert_eq!(loaded.split_views(&test, nerf_core::frames::views::Images::Skip).unwrap().iter().map(|v| v.pose).collect::<Vec<_>>(), recorded.iter().map(|v| v.pose).collect::<Vec<_>>());

    // Not on NDC rays, and not for the MLP field.
    let llff = forward_facing_capture(dir.path(), "ff", &[0, 1, 2, 3]);
    let (ok, text) = nerf(&["train", "--data", s(&llff), "--refine-cameras", "--iters", "1", "--out", s(&dir.path().join("ndc"))]);
    assert!(!ok && text.contains("NDC rays") && text.contains("--refine-cameras") && text.contains("ff"), "{text}");
    let (ok, text) = nerf(&["train", "--data", s(&data), "--refine-cameras", "--preset", "paper", "--iters", "1", "--out", s(&dir.path().join("mlp"))]);
    assert!(!ok && text.contains("camera refinement is the ngp field's"), "{text}");
}
