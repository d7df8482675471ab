//! `nerf process-data --colmap-model`: the fox capture's poses written as a COLMAP model
//! (OpenGL camera-to-world → COLMAP's OpenCV world-to-camera quaternion and translation, the
//! inverse of the conversion under test), converted back, must give the shipped poses and
//! intrinsics; the result loads as a capture; unregistered images are named; bad input is
//! refused with clear errors and nothing written.

mod common;

use common::{nerf, s};
use std::path::{Path, PathBuf};

fn fox() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/real/fox")
}

/// A unit quaternion (w, x, y, z) of a rotation matrix (Shepperd's method).
fn quaternion(r: [[f64; 3]; 3]) -> [f64; 4] {
    let trace = r[0][0] + r[1][1] + r[2][2];
    let q = if trace > 0.0 {
        let s = (trace + 1.0).sqrt() * 2.0;
        [0.25 * s, (r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s]
    } else if r[0][0] > r[1][1] && r[0][0] > r[2][2] {
        let s = (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt() * 2.0;
        [(r[2][1] - r[1][2]) / s, 0.25 * s, (r[0][1] + r[1][0]) / s, (r[0][2] + r[2][0]) / s]
    } else if r[1][1] > r[2][2] {
        let s = (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt() * 2.0;
        [(r[0][2] - r[2][0]) / s, (r[0][1] + r[1][0]) / s, 0.25 * s, (r[1][2] + r[2][1]) / s]
    } else {
        let s = (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt() * 2.0;
        [(r[1][0] - r[0][1]) / s, (r[0][2] + r[2][0]) / s, (r[1][2] + r[2][1]) / s, 0.25 * s]
    };
    q
}

/// Write the frames of fox's transforms.json whose image exists, except `skip`, as a COLMAP
/// text model in `dir`; returns (name, OpenGL c2w) of the frames written.
fn colmap_from_fox(dir: &Path, skip: usize) -> Vec<(String, Vec<Vec<f64>>)> {
    let t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(fox().join("transforms.json")).unwrap()).unwrap();
    let f = |k: &str| t[k].as_f64().unwrap();
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(
        dir.join("cameras.txt"),
        format!("1 OPENCV {} {} {} {} {} {} {} {} {} {}\n", f("w"), f("h"), f("fl_x"), f("fl_y"), f("cx"), f("cy"), f("k1"), f("k2"), f("p1"), f("p2")),
    )
    .unwrap();
    let mut lines = String::from("# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME\n");
    let mut written = Vec::new();
    let frames = t["frames"].as_array().unwrap().iter().filter(|fr| fox().join(fr["file_path"].as_str().unwrap()).is_file());
    for (k, frame) in frames.enumerate().skip(skip) {
        let name = Path::new(frame["file_path"].as_str().unwrap()).file_name().unwrap().to_string_lossy().into_owned();
        let m: Vec<Vec<f64>> = serde_json::from_value(frame["transform_matrix"].clone()).unwrap();
        // OpenGL → OpenCV camera axes (negate columns 1, 2), then invert: R = R_c2wᵀ, t = −R·C.
        let rc = [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[i][j] * if j == 0 { 1.0 } else { -1.0 }));
        let r = [0, 1, 2].map(|i| [0, 1, 2].map(|j| rc[j][i]));
        let tv = [0, 1, 2].map(|i| -(0..3).map(|j| r[i][j] * m[j][3]).sum::<f64>());
        let q = quaternion(r);
        lines += &format!("{} {} {} {} {} {} {} {} 1 {name}\n\n", k + 1, q[0], q[1], q[2], q[3], tv[0], tv[1], tv[2]);
        written.push((name, m));
    }
    std::fs::write(dir.join("images.txt"), lines).unwrap();
    written
}

#[test]
fn a_colmap_model_of_the_fox_converts_back_to_its_poses_and_loads() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("project/sparse/0");
    let frames = colmap_from_fox(&model, 2);
    let out = dir.path().join("fox-processed");
    let (ok, text) = nerf(&["process-data", "--colmap-model", s(&dir.path().join("project")), "--images", s(&fox().join("images")), "--keep-colmap-coords", "--out", s(&out)]);
    assert!(ok, "{text}");
    let total = std::fs::read_dir(fox().join("images")).unwrap().count();
    assert!(text.contains(&format!("{} of {total} images registered", frames.len())), "{text}");
    // Two images left out of the model: named in the warning (2 of 45 is under 10%: none).
    let t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("transforms.json")).unwrap()).unwrap();
    assert_eq!(t["camera_model"], "OPENCV");
    assert_eq!((t["fl_x"].as_f64(), t["w"].as_f64()), (Some(275.104), Some(216.0)));
    let got = t["frames"].as_array().unwrap();
    assert_eq!(got.len(), frames.len());
    for (name, m) in &frames {
        let frame = got.iter().find(|f| f["file_path"] == format!("images/{name}")).unwrap_or_else(|| panic!("{name} missing"));
        let back: Vec<Vec<f64>> = serde_json::from_value(frame["transform_matrix"].clone()).unwrap();
        // The shipped rotations are orthonormal to ≈ 1e-6 only, which a quaternion cannot keep.
        for (a, b) in back.iter().flatten().zip(m.iter().flatten()) {
            assert!((a - b).abs() < 1e-5, "{name}: {back:?} vs {m:?}");
        }
        assert!(out.join("images").join(name).is_file());
    }
    // `nerf train` reads it as an instant-ngp capture.
    use nerf_core::dataset::{Background, CaptureSplit, LoadOptions, SceneFrame, load_dataset};
    let options = LoadOptions { format: None, downscale: 1, images: false, background: Background::White, frame: SceneFrame::Fit { bound: 1.5, ndc: None, contraction: None } };
    let all = load_dataset(&out, CaptureSplit::All, &options).unwrap();
    assert_eq!(all.data.views.len(), frames.len(), "{:?}", all.warnings);

    // By default, instant-ngp's placement: mean up +z, mean camera distance 4, aabb_scale 4,
    // and `applied_transform` maps the model's coordinates to the file's.
    let placed = dir.path().join("fox-placed");
    let (ok, text) = nerf(&["process-data", "--colmap-model", s(&dir.path().join("project")), "--images", s(&fox().join("images")), "--downscales", "0", "--out", s(&placed)]);
    assert!(ok, "{text}");
    let t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(placed.join("transforms.json")).unwrap()).unwrap();
    assert_eq!(t["aabb_scale"], 4);
    let applied: Vec<Vec<f64>> = serde_json::from_value(t["applied_transform"].clone()).unwrap();
    let (mut up, mut distance) = ([0.0f64; 3], 0.0);
    for (name, m) in &frames {
        let frame = t["frames"].as_array().unwrap().iter().find(|f| f["file_path"] == format!("images/{name}")).unwrap();
        let p: Vec<Vec<f64>> = serde_json::from_value(frame["transform_matrix"].clone()).unwrap();
        distance += (0..3).map(|i| p[i][3] * p[i][3]).sum::<f64>().sqrt() / frames.len() as f64;
        for i in 0..3 {
            up[i] += p[i][1];
            let mapped = (0..3).map(|j| applied[i][j] * m[j][3]).sum::<f64>() + applied[i][3];
            assert!((mapped - p[i][3]).abs() < 1e-4, "{name}: {mapped} vs {}", p[i][3]);
        }
    }
    let norm = up.iter().map(|u| u * u).sum::<f64>().sqrt();
    assert!((up[2] / norm - 1.0).abs() < 1e-9 && (distance - 4.0).abs() < 1e-9, "up {up:?}, mean distance {distance}");
    let (ok, text) = nerf(&["process-data", "--colmap-model", s(&dir.path().join("project")), "--images", s(&fox().join("images")), "--aabb-scale", "0", "--out", s(&dir.path().join("zero"))]);
    assert!(!ok && text.contains("--aabb-scale 0"), "{text}");

    // Too few registered images, a folder of no images, and no model: clear errors, nothing written.
    let few = dir.path().join("few");
    let kept = colmap_from_fox(&few, frames.len());
    assert!(kept.len() < 3);
    let nothing = dir.path().join("nothing");
    let (ok, text) = nerf(&["process-data", "--colmap-model", s(&few), "--images", s(&fox().join("images")), "--out", s(&nothing)]);
    assert!(!ok && text.contains("images registered") && text.contains("at least 3"), "{text}");
    let empty = dir.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let (ok, text) = nerf(&["process-data", "--colmap-model", s(&model), "--images", s(&empty), "--out", s(&nothing)]);
    assert!(!ok && text.contains("no .png/.jpg images"), "{text}");
    let (ok, text) = nerf(&["process-data", "--colmap-model", s(&empty), "--images", s(&fox().join("images")), "--out", s(&nothing)]);
    assert!(!ok && text.contains("not a COLMAP sparse model"), "{text}");
    assert!(!nothing.exists(), "nothing half-written");
}

/// Horn's closed-form similarity (scale, rotation, translation) taking points `a` onto `b`
/// (least squares), via the largest eigenvector of his 4 × 4 matrix (power iteration).
fn similarity(a: &[[f64; 3]], b: &[[f64; 3]]) -> (f64, [[f64; 3]; 3], [f64; 3], [f64; 3]) {
    let n = a.len() as f64;
    let mean = |p: &[[f64; 3]]| [0, 1, 2].map(|d| p.iter().map(|v| v[d]).sum::<f64>() / n);
    let (ma, mb) = (mean(a), mean(b));
    let mut s = [[0.0; 3]; 3];
    for (p, q) in a.iter().zip(b) {
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += (p[i] - ma[i]) * (q[j] - mb[j]);
            }
        }
    }
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = s;
    let m = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    // Shift so that the largest eigenvalue is the largest in magnitude, then iterate.
    let shift: f64 = m.iter().flatten().map(|v| v.abs()).sum();
    let mut q = [1.0, 0.1, 0.1, 0.1];
    for _ in 0..2000 {
        let next = [0, 1, 2, 3].map(|i| (0..4).map(|j| m[i][j] * q[j]).sum::<f64>() + shift * q[i]);
        let norm = next.iter().map(|v| v * v).sum::<f64>().sqrt();
        q = next.map(|v| v / norm);
    }
    let [w, x, y, z] = q;
    let r = [
        [w * w + x * x - y * y - z * z, 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), w * w - x * x + y * y - z * z, 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), w * w - x * x - y * y + z * z],
    ];
    let spread = |p: &[[f64; 3]], m: [f64; 3]| p.iter().map(|v| (0..3).map(|d| (v[d] - m[d]).powi(2)).sum::<f64>()).sum::<f64>();
    ((spread(b, mb) / spread(a, ma)).sqrt(), r, ma, mb)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[v.len() / 2]
}

/// COLMAP run here on the fox photos alone: ≥ 95% registered, and after a similarity alignment
/// the poses agree with the shipped transforms.json (median rotation error ≤ 1°, median camera
/// centre error ≤ 1% of the cameras' extent).
#[test]
fn colmap_on_the_fox_photos_recovers_the_shipped_poses() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fox");
    let (ok, text) = nerf(&["process-data", "--images", s(&fox().join("images")), "--out", s(&out)]);
    assert!(ok, "{text}");
    for log in ["1-features.log", "2-matching.log", "3-mapping.log"] {
        assert!(out.join("colmap").join(log).is_file(), "{log} kept");
    }
    // Shrunk copies as nerfstudio writes them (216×384 divides by 2, 4 and 8).
    assert!(text.contains("images_2/, images_4/, images_8/"), "{text}");
    for (f, size) in [(2, (108, 192)), (4, (54, 96)), (8, (27, 48))] {
        let copy = out.join(format!("images_{f}/0002.png"));
        assert_eq!(image::image_dimensions(&copy).unwrap(), size, "{}", copy.display());
    }
    let read = |p: &Path| -> Vec<(String, Vec<Vec<f64>>)> {
        let t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap();
        let name = |f: &serde_json::Value| Path::new(f["file_path"].as_str().unwrap()).file_name().unwrap().to_string_lossy().into_owned();
        t["frames"].as_array().unwrap().iter().map(|f| (name(f), serde_json::from_value(f["transform_matrix"].clone()).unwrap())).collect()
    };
    let ours = read(&out.join("transforms.json"));
    let shipped: Vec<_> = read(&fox().join("transforms.json")).into_iter().filter(|(n, _)| fox().join("images").join(n).is_file()).collect();
    let registered = ours.len() as f64 / shipped.len() as f64;
    assert!(registered >= 0.95, "{} of {} registered", ours.len(), shipped.len());
    let pairs: Vec<_> = ours.iter().filter_map(|(n, m)| shipped.iter().find(|(s, _)| s == n).map(|(_, t)| (m, t))).collect();
    let centre = |m: &Vec<Vec<f64>>| [m[0][3], m[1][3], m[2][3]];
    let a: Vec<[f64; 3]> = pairs.iter().map(|(m, _)| centre(m)).collect();
    let b: Vec<[f64; 3]> = pairs.iter().map(|(_, t)| centre(t)).collect();
    let (scale, r, ma, mb) = similarity(&a, &b);
    let extent = b.iter().flat_map(|p| b.iter().map(move |q| (0..3).map(|d| (p[d] - q[d]).powi(2)).sum::<f64>().sqrt())).fold(0.0, f64::max);
    let centre_errors: Vec<f64> = a
        .iter()
        .zip(&b)
        .map(|(p, q)| {
            let moved = [0, 1, 2].map(|i| scale * (0..3).map(|j| r[i][j] * (p[j] - ma[j])).sum::<f64>() + mb[i]);
            (0..3).map(|d| (moved[d] - q[d]).powi(2)).sum::<f64>().sqrt() / extent
        })
        .collect();
    let rotation_errors: Vec<f64> = pairs
        .iter()
        .map(|(m, t)| {
            // angle of t_Rᵀ · r · m_R, from its trace.
            let rm = [0, 1, 2].map(|i| [0, 1, 2].map(|j| (0..3).map(|k| r[i][k] * m[k][j]).sum::<f64>()));
            let trace: f64 = (0..3).map(|i| (0..3).map(|k| t[k][i] * rm[k][i]).sum::<f64>()).sum();
            ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
        })
        .collect();
    let (centre_med, rot_med) = (median(centre_errors), median(rotation_errors));
    println!("fox: {} of {} registered; median centre error {:.3}% of the extent, median rotation error {:.3}°", ours.len(), shipped.len(), 100.0 * centre_med, rot_med);
    assert!(centre_med <= 0.01 && rot_med <= 1.0, "centre {centre_med}, rotation {rot_med}°");
}

/// A video made from the fox photos (ffmpeg, 10 frames/s) through `--video`: frames picked
/// evenly, COLMAP with the sequential matcher, and a short training run on the result.
#[test]
fn a_video_of_the_fox_goes_to_a_trained_scene() {
    let dir = tempfile::tempdir().unwrap();
    let video = dir.path().join("fox.mp4");
    let glob = fox().join("images/*.jpg");
    let made = std::process::Command::new("ffmpeg")
        .args(["-nostdin", "-loglevel", "error", "-framerate", "10", "-pattern_type", "glob", "-i", s(&glob), "-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "18", s(&video)])
        .status()
        .expect("ffmpeg (.ci/run installs it)");
    assert!(made.success());
    let out = dir.path().join("capture");
    let (ok, text) = nerf(&["process-data", "--video", s(&video), "--frames", "40", "--out", s(&out)]);
    assert!(ok, "{text}");
    let t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("transforms.json")).unwrap()).unwrap();
    let n = t["frames"].as_array().unwrap().len();
    println!("{text}");
    assert!(n >= 36, "{n} of about 40 frames registered");
    assert!(out.join("colmap/0-frames.log").is_file());
    let run = dir.path().join("run");
    let (ok, text) = nerf(&["train", "--data", s(&out), "--iters", "40", "--out", s(&run)]);
    assert!(ok, "{text}");
    let curve = std::fs::read_to_string(run.join("curve.csv")).unwrap();
    assert!(curve.lines().count() >= 2, "a trained run records its curve: {curve}");

    // A file that is not a video, and a missing one: clear errors, nothing written.
    let bad = dir.path().join("notes.mp4");
    std::fs::write(&bad, "not a video").unwrap();
    let nothing = dir.path().join("nothing");
    let (ok, text) = nerf(&["process-data", "--video", s(&bad), "--out", s(&nothing)]);
    assert!(!ok && text.contains("notes.mp4") && text.contains("ffprobe"), "{text}");
    let (ok, text) = nerf(&["process-data", "--video", s(&dir.path().join("missing.mp4")), "--out", s(&nothing)]);
    assert!(!ok && text.contains("no such video"), "{text}");
    assert!(!nothing.exists());
}

/// Without COLMAP or ffmpeg on the PATH, the error says how to install them.
#[test]
fn missing_tools_say_how_to_install_them() {
    let dir = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_nerf")).args(args).env("PATH", dir.path()).output().unwrap();
        (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    let (ok, text) = run(&["process-data", "--images", s(&fox().join("images")), "--out", s(&dir.path().join("a"))]);
    assert!(!ok && text.contains("colmap") && text.contains("apt-get install colmap"), "{text}");
    let video = dir.path().join("v.mp4");
    std::fs::write(&video, "x").unwrap();
    let (ok, text) = run(&["process-data", "--video", s(&video), "--out", s(&dir.path().join("b"))]);
    assert!(!ok && text.contains("apt-get install ffmpeg"), "{text}");
    assert!(!dir.path().join("a").exists() && !dir.path().join("b").exists());
}

/// Fewer than three photos: nothing to reconstruct, said before COLMAP runs; nothing written.
#[test]
fn too_few_photos_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let photos = dir.path().join("photos");
    std::fs::create_dir_all(&photos).unwrap();
    for name in ["0002.jpg", "0003.jpg"] {
        std::fs::copy(fox().join("images").join(name), photos.join(name)).unwrap();
    }
    std::fs::write(photos.join("notes.txt"), "not a photo").unwrap();
    let out = dir.path().join("out");
    let (ok, text) = nerf(&["process-data", "--images", s(&photos), "--out", s(&out)]);
    assert!(!ok && text.contains("photos") && text.contains("2 .png/.jpg images: at least 3"), "{text}");
    let (ok, text) = nerf(&["process-data", "--images", s(&dir.path().join("missing")), "--out", s(&out)]);
    assert!(!ok && text.contains("missing"), "{text}");
    assert!(!out.exists());
}

/// `--matcher vocab-tree` with a tree COLMAP built from the fox's own features registers the
/// photos; without a tree, or with a missing file, the error says where trees come from.
#[test]
fn the_vocab_tree_matcher_registers_the_fox() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let photos = fox().join("images");
    let (ok, text) = nerf(&["process-data", "--images", s(&photos), "--matcher", "vocab-tree", "--out", s(&out)]);
    assert!(!ok && text.contains("--vocab-tree FILE") && text.contains("vocab_tree_builder"), "{text}");
    let tree = dir.path().join("tree.bin");
    let (ok, text) = nerf(&["process-data", "--images", s(&photos), "--matcher", "vocab-tree", "--vocab-tree", s(&tree), "--out", s(&out)]);
    assert!(!ok && text.contains("tree.bin") && text.contains("no such vocabulary tree"), "{text}");
    assert!(!out.exists());

    // A small tree (1,024 words) from the photos' SIFT features.
    let db = dir.path().join("features.db");
    let colmap = |args: &[&str]| {
        let status = std::process::Command::new("colmap").args(args).env("QT_QPA_PLATFORM", "offscreen").stdout(std::process::Stdio::null()).stderr(std::process::Stdio::null()).status();
        assert!(status.expect("colmap (.ci/run installs it)").success(), "colmap {args:?}");
    };
    colmap(&["feature_extractor", "--database_path", s(&db), "--image_path", s(&photos), "--SiftExtraction.use_gpu", "0"]);
    colmap(&["vocab_tree_builder", "--database_path", s(&db), "--vocab_tree_path", s(&tree), "--num_visual_words", "1024", "--branching", "32"]);
    let (ok, text) = nerf(&["process-data", "--images", s(&photos), "--matcher", "vocab-tree", "--vocab-tree", s(&tree), "--downscales", "0", "--out", s(&out)]);
    assert!(ok, "{text}");
    let t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("transforms.json")).unwrap()).unwrap();
    let n = t["frames"].as_array().unwrap().len();
    println!("vocab tree: {n} of 45 registered");
    assert!(n >= 43, "{n} of 45 registered");
    let matching = std::fs::read_to_string(out.join("colmap/2-matching.log")).unwrap();
    assert!(matching.contains("vocab") || matching.contains("Vocab"), "the vocab-tree matcher ran: {matching}");
    assert!(!out.join("images_2").exists(), "--downscales 0 writes no shrunk copies");
}
