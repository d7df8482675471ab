//! `nerf-render` end to end on the bundles shipped in `models/`: outputs, the Python
//! consumer's agreement, and clear errors (never a panic) for broken bundles.

use nerf_bundle::proto::ModelProto;
use prost::Message;
use serde_json::json;
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
    let (h, w, v) = nerf_core::frames::raw::load_npy(&out.join("frame_000.npy")).unwrap();
    assert_eq!((h, w), (64, 64));
    let acc: Vec<f32> = v.chunks_exact(5).map(|p| p[4]).collect();
    assert!(acc.iter().any(|a| *a > 0.9) && acc.iter().any(|a| *a < 0.1), "an empty or a full frame");
    // --width rescales (height keeps the aspect).
    let out2 = dir.path().join("small");
    let (ok, text) = nerf_render(&["--bundle", s(&shipped_bundle()), "--split", "test", "--limit", "1", "--width", "32", "--out", s(&out2), "--npy"]);
    assert!(ok, "{text}");
    assert_eq!(nerf_core::frames::raw::load_npy(&out2.join("r_0.npy")).unwrap().0, 32);
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
    // The shipped bundle (the older camera, `focal` alone), and a copy whose camera is a real
    // capture's: fx ≠ fy, the principal point off the centre, half-pixel centres, distortion on.
    let captured = copy_bundle(&dir.path().join("captured"));
    let scene_path = captured.join("scene.json");
    let mut scene: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&scene_path).unwrap()).unwrap();
    let camera = scene["camera"].as_object_mut().unwrap();
    camera.remove("focal");
    for (key, value) in [("fx", json!(70.0)), ("fy", json!(66.5)), ("cx", json!(29.3)), ("cy", json!(35.9)), ("pixel_center", json!("half_pixel"))] {
        camera.insert(key.into(), value);
    }
    camera.insert("distortion".into(), json!({"k1": -0.21, "k2": 0.05, "p1": 0.003, "p2": -0.002}));
    std::fs::write(&scene_path, serde_json::to_string(&scene).unwrap()).unwrap();
    for (bundle, dense, width) in [(shipped_bundle(), false, "64"), (shipped_bundle(), true, "48"), (captured.clone(), false, "64"), (captured, true, "40")] {
        let out = dir.path().join(format!("out-{}-{dense}", bundle.file_name().unwrap().to_string_lossy()));
        let mut args = vec!["--bundle", s(&bundle), "--split", "test", "--limit", "1", "--width", width, "--out", s(&out), "--npy"];
        if dense {
            args.push("--dense");
        }
        let (ok, text) = nerf_render(&args);
        assert!(ok, "{text}");
        let mut cmd = Command::new(python());
        cmd.arg(&script).arg(&bundle).args(["--npy", s(&out.join("r_0.npy")), "--test-pose", "0", "--rays", "96"]);
        if dense {
            cmd.arg("--dense");
        }
        let result = cmd.output().unwrap_or_else(|e| panic!("cannot run {} ({e}): run scripts/setup.sh and source scripts/env.sh", python()));
        let text = format!("{}{}", String::from_utf8_lossy(&result.stdout), String::from_utf8_lossy(&result.stderr));
        assert!(result.status.success(), "render_rays.py failed:\n{text}");
        assert!(text.contains("max |Δrgb|"), "{text}");
    }
}

/// The hash-grid example (`models/lego-ngp`, float16 table): lego val r_0 at 200×200 close to
/// the ground truth (25.92 dB when it was shipped; the field was trained at 400×400), and the
/// Python consumer's pixels within 1e-4 of `nerf-render`'s on the bundle's test pose 0.
#[test]
fn the_shipped_hash_grid_bundle_renders_lego() {
    let bundle = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/lego-ngp");
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/nerf_synthetic/lego");
    let dir = tempfile::tempdir().unwrap();
    let val = dir.path().join("val");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--split", "val", "--data", s(&data), "--limit", "1", "--downscale", "2", "--out", s(&val)]);
    assert!(ok, "{text}");
    let metrics: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(val.join("metrics.json")).unwrap()).unwrap();
    let db = metrics["psnr_mean"].as_f64().unwrap();
    assert!(db > 25.0, "models/lego-ngp on lego val r_0 at 200×200: {db:.2} dB");
    let test = dir.path().join("test");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--split", "test", "--limit", "1", "--width", "100", "--out", s(&test), "--npy"]);
    assert!(ok, "{text}");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/python/render_rays.py");
    let result = Command::new(python())
        .arg(&script)
        .arg(&bundle)
        .args(["--npy", s(&test.join("r_0.npy")), "--test-pose", "0", "--rays", "64"])
        .output()
        .unwrap_or_else(|e| panic!("cannot run {} ({e}): run scripts/setup.sh and source scripts/env.sh", python()));
    let text = format!("{}{}", String::from_utf8_lossy(&result.stdout), String::from_utf8_lossy(&result.stderr));
    assert!(result.status.success() && text.contains("max |Δrgb|"), "render_rays.py:\n{text}");
    println!("{text}");
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

    // No onnxruntime library: say where it was looked for and how to install it. The
    // hash-grid bundle too: its shared tables were once made (by ort, which then loaded the
    // library itself and panicked) before the library was looked for.
    let not_a_library = dir.path().join("libonnxruntime.so");
    std::fs::write(&not_a_library, b"not a shared library").unwrap();
    for bundle in [shipped_bundle(), shipped_bundle().with_file_name("lego-ngp")] {
        let args = render(&bundle);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        expect_error(&args, &[("ORT_DYLIB_PATH", "/nonexistent/libonnxruntime.so")], &["ORT_DYLIB_PATH", "scripts/setup.sh"]);
        expect_error(&args, &[("ORT_DYLIB_PATH", s(&not_a_library))], &[s(&not_a_library), "cannot load onnxruntime", "scripts/setup.sh"]);
        // Nothing set, and no venv under $NERF_HOME: where it looked.
        expect_error(&args, &[("ORT_DYLIB_PATH", ""), ("NERF_HOME", s(dir.path()))], &["onnxruntime library not found", "scripts/setup.sh"]);
    }
    assert!(!out.exists(), "no output is written for a bundle that cannot be opened");
}

/// The default preset's bundles march 2048 intervals: marching takes at most 16 samples per
/// ray per call, so the default chunk renders them; a `--chunk` whose 16 samples a ray pass
/// the points limit is still refused.
#[test]
fn a_bundle_marching_2048_intervals_renders_with_the_default_chunk() {
    let dir = tempfile::tempdir().unwrap();
    let bundle = edited_bundle(&dir.path().join("bundle"), |scene| scene["march_steps"] = 2048.into());
    let out = dir.path().join("out");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--orbit", "--frames", "1", "--out", s(&out)]);
    assert!(ok && out.join("frame_000.png").is_file(), "{text}");
    let refused_out = dir.path().join("refused");
    refused(&["--bundle", s(&bundle), "--orbit", "--frames", "1", "--chunk", "524288", "--out", s(&refused_out)], &refused_out, &["--chunk: 524288 rays × 16 samples"]);
}

/// A copy of the shipped bundle whose `scene.json` went through `edit`.
fn edited_bundle(to: &Path, edit: impl FnOnce(&mut serde_json::Value)) -> PathBuf {
    let dir = copy_bundle(to);
    let mut scene: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("scene.json")).unwrap()).unwrap();
    edit(&mut scene);
    std::fs::write(dir.join("scene.json"), scene.to_string()).unwrap();
    dir
}

/// `nerf-render` with `args` fails within `seconds`, its message contains every needle, and
/// `out` is not created.
fn refused(args: &[&str], out: &Path, needles: &[&str]) {
    let start = std::time::Instant::now();
    expect_error(args, &[], needles);
    let seconds = start.elapsed().as_secs_f64();
    assert!(seconds < 20.0, "nerf-render {args:?} took {seconds:.1} s to refuse");
    assert!(!out.exists(), "nerf-render {args:?} wrote {}", out.display());
}

/// Bundles made by someone else: file names that leave the bundle, sizes that would allocate
/// without bound or render forever. Each is refused at once, naming the file and the field,
/// before anything is written (the table in docs/robustness.md, "Bad input", lists these).
#[test]
fn untrusted_bundles_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let orbit = |bundle: &Path| vec!["--bundle".to_string(), s(bundle).into(), "--orbit".into(), "--frames".into(), "1".into(), "--out".into(), s(&out).into()];
    let check = |bundle: &Path, needles: &[&str]| {
        let args = orbit(bundle);
        refused(&args.iter().map(String::as_str).collect::<Vec<_>>(), &out, needles);
    };
    let at = |name: &str| dir.path().join(name);

    // File names outside the bundle: absolute, "..", a sub-directory.
    let b = edited_bundle(&at("absolute"), |j| j["networks"]["coarse"] = "/etc/hostname".into());
    check(&b, &["scene.json: networks.coarse: \"/etc/hostname\" is not a plain file name"]);
    std::fs::copy(shipped_bundle().join("fine.onnx"), dir.path().join("fine.onnx")).unwrap();
    let b = edited_bundle(&at("dotdot"), |j| j["networks"]["fine"] = "../fine.onnx".into());
    check(&b, &["scene.json: networks.fine: \"../fine.onnx\" is not a plain file name"]);
    let b = edited_bundle(&at("subdir"), |j| j["networks"]["coarse"] = "nets/coarse.onnx".into());
    check(&b, &["networks.coarse", "not a plain file name"]);
    let b = edited_bundle(&at("grid-path"), |j| j["occupancy"]["file"] = "../../occupancy.bin".into());
    check(&b, &["scene.json: occupancy.file", "not a plain file name"]);
    // A symbolic link that leaves the bundle; a FIFO that would block the reader forever.
    let b = copy_bundle(&at("link"));
    std::fs::remove_file(b.join("coarse.onnx")).unwrap();
    std::os::unix::fs::symlink(dir.path().join("fine.onnx"), b.join("coarse.onnx")).unwrap();
    check(&b, &["networks.coarse", "symbolic link", "outside"]);
    let b = copy_bundle(&at("fifo"));
    std::fs::remove_file(b.join("coarse.onnx")).unwrap();
    assert!(Command::new("mkfifo").arg(b.join("coarse.onnx")).status().unwrap().success());
    check(&b, &["networks.coarse", "not a regular file"]);

    // Sizes: a 10⁸ × 10⁸ camera, samples per ray, grid resolution (scene.json and the grid's own
    // header), pose counts, a pose name that would write outside --out, a huge scene.json.
    let b = edited_bundle(&at("huge-camera"), |j| {
        j["camera"]["width"] = 100_000_000.into();
        j["camera"]["height"] = 100_000_000.into();
    });
    check(&b, &["scene.json: camera: 100000000×100000000 pixels", "limit of 16384"]);
    let b = edited_bundle(&at("samples"), |j| j["sampling"]["n_fine"] = 1_000_000.into());
    check(&b, &["scene.json: sampling: n_coarse + n_fine = 1000032 samples per ray", "4096"]);
    let b = edited_bundle(&at("grid-res"), |j| j["occupancy"]["resolution"] = 100_000.into());
    check(&b, &["scene.json: occupancy.resolution: 100000 cells per axis", "512"]);
    let b = copy_bundle(&at("grid-header"));
    let mut grid = std::fs::read(b.join("occupancy.bin")).unwrap();
    grid[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
    std::fs::write(b.join("occupancy.bin"), &grid).unwrap();
    check(&b, &["occupancy.bin: header resolution: 4294967295 cells per axis", "512"]);
    let b = edited_bundle(&at("poses"), |j| {
        let pose = j["poses"]["orbit"][0].clone();
        j["poses"]["orbit"] = serde_json::Value::Array(vec![pose; 10_001]);
    });
    check(&b, &["scene.json: poses.orbit: 10001 poses", "10000"]);
    let b = edited_bundle(&at("pose-name"), |j| j["poses"]["test"][0]["name"] = "../../escaped".into());
    let args = ["--bundle", s(&b), "--split", "test", "--out", s(&out)];
    refused(&args, &out, &["scene.json: poses.test[0].name", "not a plain file name"]);
    assert!(!dir.path().join("escaped.png").exists() && !at("escaped.png").exists());
    let b = copy_bundle(&at("big-json"));
    std::fs::File::options().write(true).open(b.join("scene.json")).unwrap().set_len((64 << 20) + 1).unwrap();
    check(&b, &["scene.json: 67108865 bytes is more than the limit of 67108864"]);

    // Options that size allocations.
    let bundle = shipped_bundle();
    for (option, value, needle) in [
        ("--width", "100000000", "--width/--height: 100000000×100000000 pixels"),
        ("--frames", "100000000", "--frames: 100000000 frames is more than the limit of 10000"),
        ("--chunk", "1000000000", "--chunk: 1000000000 rays is more than the limit"),
        ("--chunk", "300000", "--chunk: 300000 rays × 16 samples"),
        ("--threads", "100000", "--threads: 100000 threads is more than the limit of 1024"),
        ("--threads", "0", "--threads: must be at least 1"),
    ] {
        let args = ["--bundle", s(&bundle), "--orbit", option, value, "--out", s(&out)];
        refused(&args, &out, &[needle]);
    }
}

/// The Python consumer applies the same rules to the same bad bundles.
#[test]
fn python_consumer_refuses_untrusted_bundles() {
    let dir = tempfile::tempdir().unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/python/render_rays.py");
    let cases: Vec<(PathBuf, &str)> = vec![
        (edited_bundle(&dir.path().join("absolute"), |j| j["networks"]["coarse"] = "/etc/hostname".into()), "networks.coarse: '/etc/hostname' is not a plain file name"),
        (edited_bundle(&dir.path().join("dotdot"), |j| j["occupancy"]["file"] = "../occupancy.bin".into()), "occupancy.file: '../occupancy.bin' is not a plain file name"),
        (
            edited_bundle(&dir.path().join("huge"), |j| {
                j["camera"]["width"] = 100_000_000.into();
                j["camera"]["height"] = 100_000_000.into();
            }),
            "camera: 100000000×100000000 pixels",
        ),
        (edited_bundle(&dir.path().join("samples"), |j| j["sampling"]["n_fine"] = 1_000_000.into()), "1000032 samples per ray"),
    ];
    let header = copy_bundle(&dir.path().join("header"));
    let mut grid = std::fs::read(header.join("occupancy.bin")).unwrap();
    grid[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
    std::fs::write(header.join("occupancy.bin"), &grid).unwrap();
    let link = copy_bundle(&dir.path().join("link"));
    std::fs::remove_file(link.join("coarse.onnx")).unwrap();
    std::os::unix::fs::symlink(shipped_bundle().join("coarse.onnx").canonicalize().unwrap(), link.join("coarse.onnx")).unwrap();
    let cases = cases.into_iter().chain([(header, "header resolution: 4294967295 cells per axis"), (link, "is a symbolic link to")]);
    for (bundle, needle) in cases {
        let result = Command::new(python()).arg(&script).arg(&bundle).args(["--npy", "unused.npy", "--orbit-pose", "0"]).output().unwrap();
        let text = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.code(), Some(2), "{}: {text}", bundle.display());
        assert!(text.starts_with("error: ") && text.contains(needle), "{} should say {needle:?}:\n{text}", bundle.display());
    }
}

/// The Python package's table of limits and defaults (python/nerf_bundle/_limits.py) holds
/// exactly the Rust constants it needs, by name, with the same values: a value changed on
/// either side, a constant the package needs missing there, or a name there that Rust does
/// not know fails here.
#[test]
fn python_limits_match_the_core() {
    use nerf_core::io::limits::*;
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../python/nerf_bundle/_limits.py");
    let script = std::fs::read_to_string(&file).unwrap();
    let int = |v: u64| v.to_string();
    let rust: std::collections::BTreeMap<&str, String> = [
        ("MAX_IMAGE_SIDE", int(MAX_IMAGE_SIDE as u64)),
        ("MAX_FRAME_PIXELS", int(MAX_FRAME_PIXELS)),
        ("MAX_FRAMES", int(MAX_FRAMES as u64)),
        ("MAX_SAMPLES_PER_RAY", int(MAX_SAMPLES_PER_RAY as u64)),
        ("MAX_CHUNK", int(MAX_CHUNK as u64)),
        ("MAX_POINTS_PER_CALL", int(MAX_POINTS_PER_CALL as u64)),
        ("MAX_GRID_RESOLUTION", int(MAX_GRID_RESOLUTION as u64)),
        ("MAX_THREADS", int(MAX_THREADS as u64)),
        ("MAX_JSON_BYTES", int(MAX_JSON_BYTES)),
        ("MAX_GRAPH_BYTES", int(nerf_bundle::graph::MAX_GRAPH_BYTES)),
        ("DEFAULT_CHUNK", int(nerf_runtime::scene::DEFAULT_CHUNK as u64)),
        ("DEFAULT_MARCH_STEPS", int(nerf_core::render::DEFAULT_MARCH_STEPS as u64)),
        ("POINTS_PER_RUN", int(nerf_runtime::network::POINTS_PER_RUN as u64)),
        ("READ_FORMATS", format!("{:?}", nerf_bundle::scene::READ_FORMATS)),
    ]
    .into();
    // `NAME = value` lines: integers (digits, `_`) or a tuple of strings, shown as Rust shows a list.
    let python: std::collections::BTreeMap<&str, String> = script
        .lines()
        .filter_map(|l| l.split_once(" = ").filter(|(name, _)| !name.is_empty() && name.chars().all(|c| c.is_ascii_uppercase() || c == '_')))
        .map(|(name, value)| {
            let value = value.trim();
            let shown = match value.strip_prefix('(').and_then(|v| v.strip_suffix(')')) {
                Some(items) => format!("[{}]", items.split(',').map(str::trim).filter(|s| !s.is_empty()).collect::<Vec<_>>().join(", ")),
                None => value.replace('_', "").parse::<u64>().map_or_else(|e| panic!("{}: {name} = {value}: {e}", file.display()), int),
            };
            (name, shown)
        })
        .collect();
    let missing: Vec<&&str> = rust.keys().filter(|k| !python.contains_key(*k)).collect();
    let unknown: Vec<&&str> = python.keys().filter(|k| !rust.contains_key(*k)).collect();
    assert!(missing.is_empty() && unknown.is_empty(), "{}: missing {missing:?}, unknown to Rust {unknown:?}", file.display());
    for (name, value) in &rust {
        assert_eq!(&python[name], value, "{}: {name}", file.display());
    }
}

/// `--device cuda[:N]` where onnxruntime is the CPU wheel's (as everywhere in CI): a clear
/// error naming what is missing and how to get it, and nothing written.
#[test]
fn cuda_without_a_cuda_build_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let ngp = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/lego-ngp");
    let needles = ["not a CUDA build", "lack CUDAExecutionProvider", "setup.sh --gpu", "ORT_DYLIB_PATH"];
    for (k, device) in ["cuda", "cuda:0"].into_iter().enumerate() {
        let out = dir.path().join(format!("out{k}"));
        expect_error(&["--bundle", s(&shipped_bundle()), "--split", "test", "--limit", "1", "--device", device, "--out", s(&out)], &[], &needles);
        assert!(!out.exists(), "--device {device} wrote {}", out.display());
    }
    // The bitwise hash-grid lowering: a warning that its BitwiseXor stays on the CPU, then the
    // error; the same with the GPU loop asked for.
    for extra in [&[][..], &["--gpu-loop"]] {
        let out = dir.path().join("ngp");
        expect_error(&[&["--bundle", s(&ngp), "--split", "test", "--limit", "1", "--device", "cuda", "--out", s(&out)], extra].concat(), &[], &["BitwiseXor nodes run on the CPU", "--portable", needles[0]]);
        assert!(!out.exists());
    }
    // Without $ORT_DYLIB_PATH and without $NERF_HOME/venv-gpu, the CPU wheel is found after
    // venv-gpu, and refused the same way (its path named).
    let home = std::env::var_os("NERF_HOME").map(PathBuf::from).unwrap_or_else(|| Path::new(&std::env::var_os("HOME").unwrap()).join(".cache/nerf-rs"));
    let fake = dir.path().join("home");
    std::fs::create_dir(&fake).unwrap();
    std::os::unix::fs::symlink(home.join("venv"), fake.join("venv")).unwrap();
    let out = dir.path().join("fallback");
    let result = Command::new(env!("CARGO_BIN_EXE_nerf-render"))
        .args(["--bundle", s(&shipped_bundle()), "--split", "test", "--device", "cuda", "--out", s(&out)])
        .env_remove("ORT_DYLIB_PATH")
        .env("NERF_HOME", &fake)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&result.stderr);
    assert!(!result.status.success() && !text.contains("panicked"), "{text}");
    for n in [needles[0], needles[2], &format!("{}/venv/lib/python3", fake.display())] {
        assert!(text.contains(n), "should mention {n:?}:\n{text}");
    }
    assert!(!out.exists());
}

#[test]
fn bad_device_strings_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    for device in ["gpu", "cuda:x", "cuda:-1", "cuda:", "cuda:+1"] {
        let out = dir.path().join("out");
        expect_error(&["--bundle", s(&shipped_bundle()), "--split", "test", "--device", device, "--out", s(&out)], &[], &["--device", "expected cpu, cuda or cuda:N"]);
        assert!(!out.exists());
    }
    // The GPU loop without a GPU device.
    let out = dir.path().join("out");
    expect_error(&["--bundle", s(&shipped_bundle()), "--split", "test", "--gpu-loop", "--out", s(&out)], &[], &["--gpu-loop", "needs --device cuda"]);
    assert!(!out.exists());
}

/// `--device cpu` is the default: the same bytes (PNG, depth, .npy), for an MLP bundle and a
/// hash-grid one (whose encoding then runs in Rust).
#[test]
fn device_cpu_renders_the_same_bytes_as_no_flag() {
    let dir = tempfile::tempdir().unwrap();
    let ngp = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/lego-ngp");
    for (k, bundle) in [shipped_bundle(), ngp].iter().enumerate() {
        let (a, b) = (dir.path().join(format!("plain{k}")), dir.path().join(format!("cpu{k}")));
        let common = ["--bundle", s(bundle), "--split", "test", "--limit", "1", "--width", "24", "--npy"];
        let (ok, text) = nerf_render(&[&common[..], &["--out", s(&a)]].concat());
        assert!(ok, "{text}");
        let (ok, text) = nerf_render(&[&common[..], &["--device", "cpu", "--out", s(&b)]].concat());
        assert!(ok, "{text}");
        let mut names: Vec<_> = std::fs::read_dir(&a).unwrap().map(|e| e.unwrap().file_name()).filter(|n| !n.to_string_lossy().ends_with(".json")).collect();
        names.sort();
        assert!(names.iter().any(|n| n.to_string_lossy().ends_with(".npy")), "{names:?}");
        for n in &names {
            assert_eq!(std::fs::read(a.join(n)).unwrap(), std::fs::read(b.join(n)).unwrap(), "{n:?} differs with --device cpu");
        }
    }
}
