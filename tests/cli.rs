//! The `nerf` binary: outputs of eval/render, and clear errors (never a panic) on bad input.

mod common;

use common::{nerf, s, trained_run};
use std::path::Path;

#[test]
fn eval_and_render_write_named_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, run) = trained_run(dir.path());
    let out = dir.path().join("eval");
    let (ok, text) = nerf(&["eval", "--run", s(&run), "--data", s(&scene), "--split", "val", "--limit", "2", "--out", s(&out)]);
    assert!(ok, "{text}");
    let metrics: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    assert!(metrics["psnr_mean"].as_f64().unwrap() > 5.0);
    assert!(metrics["ssim_mean"].as_f64().unwrap() > 0.0);
    let names: Vec<&str> = metrics["per_image"].as_array().unwrap().iter().map(|m| m["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["r_0", "r_1"]);
    for name in names {
        let img = image::open(out.join(format!("{name}.png"))).unwrap();
        assert_eq!((img.width(), img.height()), (32, 32));
        assert!(out.join(format!("{name}_depth.png")).exists());
    }

    let orbit = dir.path().join("orbit");
    let (ok, text) = nerf(&["render", "--run", s(&run), "--orbit", "--frames", "3", "--out", s(&orbit)]);
    assert!(ok, "{text}");
    let gif = std::fs::File::open(orbit.join("orbit.gif")).unwrap();
    let decoder = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(gif)).unwrap();
    use image::AnimationDecoder;
    assert_eq!(decoder.into_frames().count(), 3);
    assert!(orbit.join("frame_002_depth.png").exists());

    let test = dir.path().join("test");
    let (ok, text) = nerf(&["render", "--run", s(&run), "--split", "test", "--data", s(&scene), "--out", s(&test)]);
    assert!(ok, "{text}");
    assert!(test.join("r_1.png").exists() && test.join("r_1_depth.png").exists());
}

#[test]
fn bad_inputs_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nowhere");
    let (ok, text) = nerf(&["train", "--data", s(&missing), "--iters", "1", "--out", s(&dir.path().join("r0"))]);
    assert!(!ok && text.contains("transforms_train.json"), "{text}");

    let bad = dir.path().join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    std::fs::write(bad.join("transforms_train.json"), "{\"camera_angle_x\": 0.7, \"frames\": [").unwrap();
    let (ok, text) = nerf(&["train", "--data", s(&bad), "--iters", "1", "--out", s(&dir.path().join("r1"))]);
    assert!(!ok && text.contains("transforms_train.json"), "{text}");

    let (scene, run) = trained_run(dir.path());
    // A missing image.
    let broken = dir.path().join("broken");
    copy_dir(&scene, &broken);
    std::fs::remove_file(broken.join("train/r_3.png")).unwrap();
    let (ok, text) = nerf(&["train", "--data", s(&broken), "--iters", "1", "--out", s(&dir.path().join("r2"))]);
    assert!(!ok && text.contains("r_3.png"), "{text}");
    // A non-finite pose.
    let text_json = std::fs::read_to_string(scene.join("transforms_train.json")).unwrap();
    let mut json: serde_json::Value = serde_json::from_str(&text_json).unwrap();
    json["frames"][2]["transform_matrix"][0][3] = serde_json::json!(12345.5);
    // 1e39 parses as f64 and overflows to +inf as f32.
    let text_json = json.to_string().replace("12345.5", "1e39");
    std::fs::write(broken.join("transforms_train.json"), text_json).unwrap();
    let (ok, text) = nerf(&["train", "--data", s(&broken), "--iters", "1", "--out", s(&dir.path().join("r3"))]);
    assert!(!ok && text.contains("transforms_train.json") && text.contains("non-finite"), "{text}");

    // A truncated checkpoint: eval and resume both refuse it, naming the file.
    let latest = std::fs::read_to_string(run.join("checkpoints/latest")).unwrap();
    let model = run.join("checkpoints").join(latest.trim()).join("model.bpk");
    let bytes = std::fs::read(&model).unwrap();
    std::fs::write(&model, &bytes[..bytes.len() / 2]).unwrap();
    let (ok, text) = nerf(&["eval", "--run", s(&run), "--data", s(&scene), "--out", s(&dir.path().join("e"))]);
    assert!(!ok && text.contains("model.bpk"), "{text}");
    let (ok, text) = nerf(&["train", "--data", s(&scene), "--iters", "30", "--out", s(&run)]);
    assert!(!ok && text.contains("model.bpk"), "{text}");
    // Not a run directory at all.
    let (ok, text) = nerf(&["render", "--run", s(&scene), "--orbit", "--out", s(&dir.path().join("o"))]);
    assert!(!ok && text.contains("config.toml"), "{text}");
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let dest = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &dest);
        } else {
            std::fs::copy(entry.path(), dest).unwrap();
        }
    }
}
