//! `nerf-render` end to end on the bundle shipped in `models/spheres`: outputs, the Python
//! consumer's agreement, and clear errors (never a panic) for broken bundles.

use nerf_export::proto::ModelProto;
use prost::Message;
use std::path::{Path, PathBuf};
use std::process::Command;

fn shipped_bundle() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/spheres")
}

/// Run `nerf-render` with `env` set: (success, stdout + stderr); a panic fails the test.
fn nerf_render_env(args: &[&str], env: &[(&str, &str)]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_nerf-render")).args(args).envs(env.iter().copied()).output().expect("run nerf-render");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(!text.contains("panicked"), "nerf-render {args:?} panicked:\n{text}");
    (out.status.success(), text)
}

fn nerf_render(args: &[&str]) -> (bool, String) {
    nerf_render_env(args, &[])
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn copy_bundle(to: &Path) -> PathBuf {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(shipped_bundle()).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
    to.to_path_buf()
}

#[test]
fn orbit_of_the_shipped_bundle() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("orbit");
    let (ok, text) = nerf_render(&["--bundle", s(&shipped_bundle()), "--orbit", "--frames", "3", "--out", s(&out), "--npy"]);
    assert!(ok, "{text}");
    for name in ["frame_000.png", "frame_002_depth.png", "orbit.gif", "frame_001.npy"] {
        assert!(out.join(name).exists(), "{name} missing:\n{text}");
    }
    // The scene is there: some pixels are opaque, some show the white background.
    let (h, w, v) = nerf_core::frames::load_npy(&out.join("frame_000.npy")).unwrap();
    assert_eq!((h, w), (64, 64));
    let acc: Vec<f32> = v.chunks_exact(5).map(|p| p[4]).collect();
    assert!(acc.iter().any(|a| *a > 0.9) && acc.iter().any(|a| *a < 0.1), "an empty or a full frame");
    // --width rescales (height keeps the aspect).
    let out2 = dir.path().join("small");
    let (ok, text) = nerf_render(&["--bundle", s(&shipped_bundle()), "--split", "test", "--limit", "1", "--width", "32", "--out", s(&out2), "--npy"]);
    assert!(ok, "{text}");
    assert_eq!(nerf_core::frames::load_npy(&out2.join("r_0.npy")).unwrap().0, 32);
}

fn python() -> String {
    std::env::var("NERF_PYTHON").unwrap_or_else(|_| "python3".into())
}

/// The numpy + onnxruntime consumer in tests/python renders rays itself and must match
/// `nerf-render`'s pixels to 1e-4, with the occupancy grid and without.
#[test]
fn python_consumer_matches_nerf_render() {
    let dir = tempfile::tempdir().unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/python/render_rays.py");
    let bundle = shipped_bundle();
    for (dense, width) in [(false, "64"), (true, "48")] {
        let out = dir.path().join(format!("dense-{dense}"));
        let mut args = vec!["--bundle", s(&bundle), "--split", "test", "--limit", "1", "--width", width, "--out", s(&out), "--npy"];
        if dense {
            args.push("--dense");
        }
        let (ok, text) = nerf_render(&args);
        assert!(ok, "{text}");
        let mut cmd = Command::new(python());
        cmd.arg(&script).arg(shipped_bundle()).args(["--npy", s(&out.join("r_0.npy")), "--test-pose", "0", "--rays", "96"]);
        if dense {
            cmd.arg("--dense");
        }
        let result = cmd.output().unwrap_or_else(|e| panic!("cannot run {} ({e}): run scripts/setup.sh and source scripts/env.sh", python()));
        let text = format!("{}{}", String::from_utf8_lossy(&result.stdout), String::from_utf8_lossy(&result.stderr));
        assert!(result.status.success(), "render_rays.py failed:\n{text}");
        assert!(text.contains("max |Δrgb|"), "{text}");
    }
}

fn expect_error(args: &[&str], env: &[(&str, &str)], needles: &[&str]) {
    let (ok, text) = nerf_render_env(args, env);
    assert!(!ok, "nerf-render {args:?} should fail:\n{text}");
    for n in needles {
        assert!(text.contains(n), "error for {args:?} should mention {n:?}:\n{text}");
    }
}

#[test]
fn broken_bundles_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let render = |bundle: &Path| vec!["--bundle".to_string(), s(bundle).to_string(), "--orbit".into(), "--frames".into(), "1".into(), "--out".into(), s(&out).to_string()];
    let run = |bundle: &Path, needles: &[&str]| {
        let args = render(bundle);
        expect_error(&args.iter().map(String::as_str).collect::<Vec<_>>(), &[], needles);
    };

    run(&dir.path().join("nowhere"), &["nowhere", "no such bundle directory"]);

    let missing = copy_bundle(&dir.path().join("missing"));
    std::fs::remove_file(missing.join("fine.onnx")).unwrap();
    run(&missing, &["fine.onnx", "cannot read"]);

    let truncated = copy_bundle(&dir.path().join("truncated"));
    let bytes = std::fs::read(truncated.join("coarse.onnx")).unwrap();
    std::fs::write(truncated.join("coarse.onnx"), &bytes[..bytes.len() / 2]).unwrap();
    run(&truncated, &["coarse.onnx", "truncated"]);

    let renamed = copy_bundle(&dir.path().join("renamed"));
    let mut model = ModelProto::decode(bytes.as_slice()).unwrap();
    model.graph.as_mut().unwrap().output[0].name = "colour".into();
    std::fs::write(renamed.join("coarse.onnx"), model.encode_to_vec()).unwrap();
    run(&renamed, &["coarse.onnx", "colour", "contract"]);

    let scene_json = std::fs::read_to_string(shipped_bundle().join("scene.json")).unwrap();
    let mut scene: serde_json::Value = serde_json::from_str(&scene_json).unwrap();
    let no_camera = copy_bundle(&dir.path().join("no-camera"));
    scene.as_object_mut().unwrap().remove("camera");
    std::fs::write(no_camera.join("scene.json"), scene.to_string()).unwrap();
    run(&no_camera, &["scene.json", "missing field `camera`"]);

    let mut scene: serde_json::Value = serde_json::from_str(&scene_json).unwrap();
    let bad_near = copy_bundle(&dir.path().join("bad-near"));
    scene["sampling"]["near"] = serde_json::json!("two");
    std::fs::write(bad_near.join("scene.json"), scene.to_string()).unwrap();
    run(&bad_near, &["scene.json", "near"]);

    let mut scene: serde_json::Value = serde_json::from_str(&scene_json).unwrap();
    let far = copy_bundle(&dir.path().join("far-before-near"));
    scene["sampling"]["far"] = serde_json::json!(1.0);
    std::fs::write(far.join("scene.json"), scene.to_string()).unwrap();
    run(&far, &["scene.json", "near < far"]);

    let grid = copy_bundle(&dir.path().join("grid"));
    let bytes = std::fs::read(grid.join("occupancy.bin")).unwrap();
    std::fs::write(grid.join("occupancy.bin"), &bytes[..1000]).unwrap();
    run(&grid, &["occupancy.bin", "truncated"]);

    // No onnxruntime library: say where it was looked for and how to install it.
    let args = render(&shipped_bundle());
    expect_error(&args.iter().map(String::as_str).collect::<Vec<_>>(), &[("ORT_DYLIB_PATH", "/nonexistent/libonnxruntime.so")], &["ORT_DYLIB_PATH", "scripts/setup.sh"]);
    assert!(!out.exists(), "no output is written for a bundle that cannot be opened");
}
