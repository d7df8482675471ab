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
    let (ok, text) = nerf(&["process-data", "--colmap-model", s(&dir.path().join("project")), "--images", s(&fox().join("images")), "--out", s(&out)]);
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
    let options = LoadOptions { format: None, downscale: 1, images: false, background: Background::White, frame: SceneFrame::Fit { bound: 1.5, ndc: None } };
    let all = load_dataset(&out, CaptureSplit::All, &options).unwrap();
    assert_eq!(all.data.views.len(), frames.len(), "{:?}", all.warnings);

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
