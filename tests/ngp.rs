//! The hash-grid field end to end on a generated scene: training (the loss falls, a resumed run
//! equals an uninterrupted one, with pixel centres and with jittered rays), export (the graph
//! holds exactly the trained field), rendering
//! (`nerf render` vs `nerf-render` ≥ 60 dB, the numpy consumer ≤ 1e-4, marched through the grid
//! and, with `--dense`, through the whole box),
//! and bad input (a truncated table, impossible grid configs, a `min_views` no cell reaches)
//! refused with clear errors.

mod common;

use common::{nerf, nerf_render, python, s, small_scene, tiny_ngp};
use nerf::run_dir::RunDir;
use nerf::config::TrainConfig;
use nerf::train::{TrainOptions, train};
use nerf_core::frames::raw::load_npy;
use nerf_core::render::metrics::psnr;
use nerf_export::proto::ModelProto;
use prost::Message;
use std::path::{Path, PathBuf};
use std::process::Command;

fn train_tiny(scene: &Path, run: &Path, iters: usize) -> nerf::train::TrainSummary {
    train_tiny_at(scene, run, iters, 1)
}

fn train_tiny_at(scene: &Path, run: &Path, iters: usize, downscale: u32) -> nerf::train::TrainSummary {
    let options = TrainOptions { format: None, data: scene.to_path_buf(), run: run.to_path_buf(), config: tiny_ngp(), ndc: None, contract: None, downscale, time_budget_min: None, iters: Some(iters), progress: false };
    train(&options).unwrap()
}

#[test]
fn a_min_views_no_cell_reaches_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene(dir.path());
    let mut config = tiny_ngp();
    // The scene has 20 training cameras: no cell can be seen by 21.
    config.occupancy.min_views = 21;
    let options = TrainOptions { format: None, data: scene, run: dir.path().join("run"), config, ndc: None, contract: None, downscale: 1, time_budget_min: None, iters: Some(2), progress: false };
    let err = train(&options).err().expect("min_views above the camera count is refused").to_string();
    assert!(err.contains("min_views = 21") && err.contains("of the 20 training cameras"), "{err}");
}

/// `nerf render --npy` of test view 0 (burn) vs `nerf-render --npy` of the bundle
/// (onnxruntime): (PSNR, largest deviation from white, the onnxruntime frame's path).
fn render_both(run: &Path, scene: &Path, bundle: &Path, dir: &Path) -> (f32, f32, PathBuf) {
    let burn_out = dir.join("burn");
    let (ok, text) = nerf(&["render", "--run", s(run), "--split", "test", "--data", s(scene), "--out", s(&burn_out), "--npy"]);
    assert!(ok, "{text}");
    let ort_out = dir.join("ort");
    let (ok, text) = nerf_render(&["--bundle", s(bundle), "--split", "test", "--data", s(scene), "--limit", "1", "--out", s(&ort_out), "--npy"]);
    assert!(ok, "{text}");
    let (_, _, a) = load_npy(&burn_out.join("r_0.npy")).unwrap();
    let (_, _, b) = load_npy(&ort_out.join("r_0.npy")).unwrap();
    let rgb = |v: &[f32]| v.chunks_exact(5).map(|p| [p[0], p[1], p[2]]).collect::<Vec<_>>();
    let (a_rgb, b_rgb) = (rgb(&a), rgb(&b));
    let off_white = a_rgb.iter().flatten().map(|v| (1.0 - v).abs()).fold(0.0, f32::max);
    (psnr(&a_rgb, &b_rgb), off_white, ort_out.join("r_0.npy"))
}

#[test]
fn ngp_trains_exports_and_renders_the_same_everywhere() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene(dir.path());
    let run = dir.path().join("run");
    let summary = train_tiny(&scene, &run, 80);
    println!("tiny ngp: {} steps, train PSNR {:.2} dB", summary.steps, summary.train_psnr);
    assert!(summary.train_psnr > 14.0, "the field did not learn: {:.2} dB", summary.train_psnr);

    let bundle = dir.path().join("bundle");
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    let scene_json: serde_json::Value = serde_json::from_slice(&std::fs::read(bundle.join("scene.json")).unwrap()).unwrap();
    assert_eq!(scene_json["field"], "ngp");
    assert_eq!(scene_json["graphs"], serde_json::json!({ "field": "field.onnx" }), "one graph, named by its role");
    assert!(scene_json["networks"].is_null() && scene_json["occupancy"]["file"] == "occupancy.bin");
    // The bundle marches as `nerf render` does: the render steps, not the training ones.
    assert_eq!(scene_json["march_steps"], 320);
    // The graph holds exactly the trained field (opset 18, bitwise hash by default).
    let model = ModelProto::decode(std::fs::read(bundle.join("field.onnx")).unwrap().as_slice()).unwrap();
    assert_eq!(model.opset_import[0].version, 18);
    let trained = nerf::field::load_latest(&RunDir::open(&run).unwrap(), &nerf::backend::cpu()).unwrap().model;
    let field = trained.as_any().downcast_ref::<nerf::field::ngp::NgpField>().expect("an ngp run loads as an ngp field");
    assert_eq!(nerf_export::field::ngp::read_ngp(&model).unwrap(), field.to_plain());

    // burn vs onnxruntime through the grid; the numpy consumer vs onnxruntime through the grid
    // and, with --dense, through the whole box.
    let (db, off_white, npy) = render_both(&run, &scene, &bundle, dir.path());
    println!("nerf render vs nerf-render: {db:.1} dB");
    assert!(off_white > 0.05, "the image is blank: parity would mean nothing");
    assert!(db >= 60.0, "burn vs onnxruntime: {db:.1} dB");
    let dense_out = dir.path().join("dense");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--split", "test", "--data", s(&scene), "--limit", "1", "--out", s(&dense_out), "--npy", "--dense"]);
    assert!(ok, "{text}");
    // Marching the whole box sums ~10× more samples per ray, and float32 rounding with them.
    for (npy, extra, tolerance) in [(npy, &[][..], "1e-4"), (dense_out.join("r_0.npy"), &["--dense"][..], "5e-4")] {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/render_rays.py");
        let mut cmd = Command::new(python());
        cmd.args([s(&script), s(&bundle), "--npy", s(&npy), "--test-pose", "0", "--tolerance", tolerance]).args(extra);
        let out = cmd.output().unwrap_or_else(|e| panic!("cannot run {} ({e}): run scripts/setup.sh and source scripts/env.sh", python()));
        let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        println!("python {extra:?}: {text}");
        assert!(out.status.success(), "{text}");
    }

    // Graphs written before the table format was recorded (trained layout, no metadata) read
    // back the same.
    let mut old = model.clone();
    old.metadata_props.retain(|p| p.key != nerf_export::field::ngp::hash_grid::table::TABLE_KEY);
    let table = old.graph.as_mut().unwrap().initializer.iter_mut().find(|t| t.name == "grid.table").unwrap();
    let f = field.to_plain().spec.grid.features_per_level as i64;
    table.raw_data = field.to_plain().table.iter().flat_map(|v| v.to_le_bytes()).collect();
    table.dims = vec![table.raw_data.len() as i64 / 4 / f, f];
    assert_eq!(nerf_export::field::ngp::read_ngp(&old).unwrap(), field.to_plain());

    // The portable lowering with a float16 table: the trained table rounded to float16, and
    // the same frame as burn's within float16's rounding.
    let compact = dir.path().join("compact");
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&compact), "--portable", "--tables", "f16"]);
    assert!(ok, "{text}");
    let small = ModelProto::decode(std::fs::read(compact.join("field.onnx")).unwrap().as_slice()).unwrap();
    assert!(!small.graph.as_ref().unwrap().node.iter().any(|n| n.op_type.starts_with("Bitwise")));
    let back = nerf_export::field::ngp::read_ngp(&small).unwrap();
    let rounded: Vec<f32> = field.to_plain().table.iter().map(|&v| half::f16::from_f32(v).to_f32()).collect();
    assert_eq!(back.table, rounded);
    let table_bytes = |m: &ModelProto| m.graph.as_ref().unwrap().initializer.iter().find(|t| t.name == "grid.table").unwrap().raw_data.len();
    assert_eq!(table_bytes(&small) * 2, table_bytes(&model));
    let (db, _, _) = render_both(&run, &scene, &compact, &dir.path().join("compact-render"));
    println!("nerf render vs nerf-render (portable, float16 table): {db:.1} dB");
    assert!(db >= 45.0, "burn vs the compact bundle: {db:.1} dB");

    // Compiled again from the compact bundle (`export --bundle`): the bitwise lowering, its
    // float16 table kept, the same field and the same frame through nerf-render, bit for bit.
    let again = dir.path().join("again");
    let (ok, text) = nerf(&["export", "--bundle", s(&compact), "--out", s(&again)]);
    assert!(ok, "{text}");
    let bitwise = ModelProto::decode(std::fs::read(again.join("field.onnx")).unwrap().as_slice()).unwrap();
    assert!(bitwise.graph.as_ref().unwrap().node.iter().any(|n| n.op_type == "BitwiseXor"), "the default lowering");
    assert_eq!(nerf_export::field::ngp::read_ngp(&bitwise).unwrap(), back);
    assert_eq!(table_bytes(&bitwise), table_bytes(&small));
    let frame = |bundle: &Path, out: &str| {
        let out = dir.path().join(out);
        let (ok, text) = nerf_render(&["--bundle", s(bundle), "--orbit", "--frames", "3", "--npy", "--whole-graph", "--out", s(&out)]);
        assert!(ok, "{text}");
        std::fs::read(out.join("frame_001.npy")).unwrap()
    };
    assert!(frame(&compact, "compact-frame") == frame(&again, "again-frame"), "the same pixels from either lowering");
    // `nerf bench --only render` on this bundle: each lowering's CPU split and whole-graph
    // frame, split into onnxruntime, encoding and loop, the same pixels as the split frame.
    let json = dir.path().join("bench.json");
    let (ok, text) = nerf(&["bench", "--only", "render", "--sizes", "8", "--repeats", "1", "--ngp-bundle", s(&again), "--json", s(&json)]);
    assert!(ok, "{text}");
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let frames = report["device_frames"].as_array().unwrap();
    let rows: Vec<(&str, &str)> = frames.iter().map(|f| (f["lowering"].as_str().unwrap(), f["path"].as_str().unwrap())).collect();
    assert_eq!(rows, [("bitwise", "split"), ("bitwise", "whole graph"), ("portable", "split"), ("portable", "whole graph")]);
    for f in frames {
        let (frame, ort, encoding, rest) = (f["seconds"].as_f64().unwrap(), f["onnxruntime_s"].as_f64().unwrap(), f["encoding_s"].as_f64().unwrap(), f["loop_s"].as_f64().unwrap());
        assert!(frame > 0.0 && ort > 0.0 && rest >= 0.0 && (ort + encoding + rest - frame).abs() < 1e-9, "{f}");
        assert_eq!(encoding > 0.0, f["path"] == "split", "{f}");
        assert_eq!(f["max_abs_vs_cpu"].as_f64(), Some(0.0), "the same pixels: {f}");
        assert_eq!(f["points_per_pixel"], frames[0]["points_per_pixel"], "one marching: {f}");
    }

    // Only hash-grid bundles: an MLP bundle's field is not read back.
    let (ok, text) = nerf(&["export", "--bundle", s(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models/lego")), "--out", s(&dir.path().join("mlp"))]);
    assert!(!ok && text.contains("models/lego/scene.json: field \"mlp\": only hash-grid bundles"), "{text}");
    assert!(!dir.path().join("mlp").exists());

    // A table cut short is refused before onnxruntime indexes into it.
    let mut bad = model.clone();
    let table = bad.graph.as_mut().unwrap().initializer.iter_mut().find(|t| t.name == "grid.table").unwrap();
    table.raw_data.truncate(table.raw_data.len() - 64);
    std::fs::write(bundle.join("field.onnx"), bad.encode_to_vec()).unwrap();
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--orbit", "--frames", "1", "--out", s(&dir.path().join("bad"))]);
    assert!(!ok && text.contains("field.onnx") && text.contains("grid.table") && text.contains("truncated"), "{text}");
}

#[test]
fn a_resumed_ngp_run_equals_an_uninterrupted_one() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene(dir.path());
    // At the images' resolution rays go through pixel centres; downscaled, through a random
    // point of each pixel (one more draw from the run's random stream, which resuming restores).
    for (downscale, jitter) in [(1, false), (2, true)] {
        let straight = dir.path().join(format!("straight{downscale}"));
        let resumed = dir.path().join(format!("resumed{downscale}"));
        train_tiny_at(&scene, &straight, 40, downscale);
        train_tiny_at(&scene, &resumed, 20, downscale);
        train_tiny_at(&scene, &resumed, 40, downscale);
        assert_eq!(RunDir::open(&resumed).unwrap().read_config().unwrap().jitter_pixels, Some(jitter));
        assert_same_field(&straight, &resumed);
    }
    // Per-image appearance codes, camera corrections and their Adam states resume too (past
    // the corrections' warm-up, so that they move).
    let with_codes = |run: &Path, iters: usize| {
        let config = nerf::config::TrainConfig { appearance: true, refine_cameras: true, ..tiny_ngp() };
        train(&TrainOptions { format: None, data: scene.clone(), run: run.to_path_buf(), config, ndc: None, contract: None, downscale: 1, time_budget_min: None, iters: Some(iters), progress: false }).unwrap();
    };
    let (straight, resumed) = (dir.path().join("straight-codes"), dir.path().join("resumed-codes"));
    let steps = nerf::train::cameras::WARM_UP_STEPS + 30;
    with_codes(&straight, steps);
    with_codes(&resumed, steps - 20);
    with_codes(&resumed, steps);
    assert_same_field(&straight, &resumed);
    let file = |run: &Path, name: &str| std::fs::read(run.join(format!("checkpoints/step-{steps:07}")).join(name)).unwrap();
    assert!(file(&straight, "appearance.json") == file(&resumed, "appearance.json"), "appearance codes or their Adam state differ after resuming");
    assert!(file(&straight, "cameras.json") == file(&resumed, "cameras.json"), "camera corrections or their Adam state differ after resuming");
    let moved: serde_json::Value = serde_json::from_slice(&file(&resumed, "cameras.json")).unwrap();
    assert!(moved["corrections"].as_array().unwrap().iter().flat_map(|c| c.as_array().unwrap()).any(|v| v.as_f64().unwrap() != 0.0), "the corrections moved");
    // The decision reaches the trainer: the same downscaled run through pixel centres differs.
    let centres = dir.path().join("centres2");
    let config = nerf::config::TrainConfig { jitter_pixels: Some(false), ..tiny_ngp() };
    train(&TrainOptions { format: None, data: scene.clone(), run: centres.clone(), config, ndc: None, contract: None, downscale: 2, time_budget_min: None, iters: Some(40), progress: false }).unwrap();
    let grid = |run: &Path| std::fs::read(run.join("checkpoints/step-0000040").join(nerf::field::ngp::GRID_FILE)).unwrap();
    assert!(grid(&centres) != grid(&dir.path().join("straight2")), "jitter_pixels changed nothing");
}

#[test]
fn a_new_run_trains_rgba_scenes_on_random_backgrounds_and_opaque_ones_on_white() {
    use nerf_core::dataset::Background;
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene(dir.path());
    let background = |run: &Path| RunDir::open(run).unwrap().read_config().unwrap().train_background;
    let rgba = dir.path().join("rgba");
    train_tiny(&scene, &rgba, 2);
    assert_eq!(background(&rgba), Some(Background::Random));
    // A Blender scene trains without the distortion loss (lego lost with it).
    assert_eq!(RunDir::open(&rgba).unwrap().read_config().unwrap().distortion_loss, Some(0.0));
    // The same scene with its background painted white into RGB images: an empty ray on white
    // explains those pixels.
    for split in ["train", "val", "test"] {
        for entry in std::fs::read_dir(scene.join(split)).unwrap() {
            let path = entry.unwrap().path();
            let img = image::open(&path).unwrap().to_rgba8();
            let rgb = image::RgbImage::from_fn(img.width(), img.height(), |x, y| {
                let p = img.get_pixel(x, y).0;
                let a = p[3] as f32 / 255.0;
                image::Rgb([0, 1, 2].map(|c| (p[c] as f32 * a + 255.0 * (1.0 - a)).round() as u8))
            });
            rgb.save(&path).unwrap();
        }
    }
    let opaque = dir.path().join("opaque");
    train_tiny(&scene, &opaque, 2);
    assert_eq!(background(&opaque), Some(Background::White));
    // An explicit choice is kept.
    let black = dir.path().join("black");
    let config = TrainConfig { train_background: Some(Background::Black), white_background: false, ..tiny_ngp() };
    train(&TrainOptions { format: None, data: scene.clone(), run: black.clone(), config, ndc: None, contract: None, downscale: 1, time_budget_min: None, iters: Some(2), progress: false }).unwrap();
    assert_eq!(background(&black), Some(Background::Black));
}

#[test]
fn the_distortion_weight_reaches_the_trainer() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene(dir.path());
    let grid = |weight: f32| {
        let run = dir.path().join(format!("distortion-{weight}"));
        let config = TrainConfig { distortion_loss: Some(weight), ..tiny_ngp() };
        train(&TrainOptions { format: None, data: scene.clone(), run: run.clone(), config, ndc: None, contract: None, downscale: 1, time_budget_min: None, iters: Some(30), progress: false }).unwrap();
        assert_eq!(RunDir::open(&run).unwrap().read_config().unwrap().distortion_loss, Some(weight), "a set weight is kept");
        std::fs::read(run.join("checkpoints/step-0000030").join(nerf::field::ngp::GRID_FILE)).unwrap()
    };
    assert!(grid(0.0) != grid(0.1), "distortion_loss changed nothing");
}

fn assert_same_field(straight: &Path, resumed: &Path) {
    let grid = |run: &Path| {
        let latest = std::fs::read_to_string(run.join("checkpoints/latest")).unwrap();
        std::fs::read(run.join("checkpoints").join(latest.trim()).join(nerf::field::ngp::GRID_FILE)).unwrap()
    };
    assert!(grid(straight) == grid(resumed), "table or its Adam state differ after resuming");
    let load = |run: &Path| {
        let model = nerf::field::load_latest(&RunDir::open(run).unwrap(), &nerf::backend::cpu()).unwrap().model;
        model.as_any().downcast_ref::<nerf::field::ngp::NgpField>().expect("an ngp run").to_plain()
    };
    assert_eq!(load(straight), load(resumed));
}

#[test]
fn impossible_grid_configs_are_refused_by_name() {
    for (toml, needle) in [
        ("[ngp.grid]\nlevels = 0", "levels"),
        ("[ngp.grid]\nmax_resolution = 8", "max_resolution"),
        ("[ngp.grid]\nlog2_table_size = 40", "log2_table_size"),
        ("[ngp.grid]\nfeatures_per_level = 3", "features_per_level"),
        ("[ngp.grid]\ntable_size = 1000", "table_size"),
        ("[sampling]\nn_fine = 64", "n_fine"),
        ("[occupancy]\nbound = 2.0", "bound"),
    ] {
        let err = TrainConfig::from_toml_str(&format!("preset = 'ngp'\n{toml}\n"), None).unwrap_err().to_string();
        assert!(err.contains(needle), "{toml:?}: {err}");
    }
}
