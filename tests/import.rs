//! `nerf import nerf-pytorch`: checkpoints written by nerf-pytorch itself
//! (`tests/fixtures/nerf-pytorch/`, its README says how) import into bundles that `nerf-render`
//! renders as nerf-pytorch rendered them; bad input gets a clear error and writes no bundle.

mod common;

use common::{lego_dir, nerf, nerf_render, s};
use nerf_core::frames::raw::load_npy;
use std::path::{Path, PathBuf};

fn fixture(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/nerf-pytorch").join(path)
}

fn lego() -> PathBuf {
    let lego = lego_dir();
    assert!(lego.join("transforms_test.json").is_file(), "{} is missing (CI provides ../shared)", lego.display());
    lego
}

/// How far our render of a view is from nerf-pytorch's.
struct Agreement {
    psnr_db: f64,
    max_rgb: f32,
    max_acc: f32,
    rgb_std: f32,
}

/// Import the checkpoint `fixtures/<checkpoint>` (with `fixtures/<args>` when given) trained on
/// `data`, render the first `views.len()` test views at `width`×`height` with
/// `nerf-render --npy`, and compare each with nerf-pytorch's render `fixtures/<run>/<view>.npy`.
fn import_and_compare(run: &str, checkpoint: &str, args: Option<&str>, data: &Path, (width, height): (u32, u32), views: &[&str]) -> Vec<Agreement> {
    let dir = tempfile::tempdir().unwrap();
    let bundle = dir.path().join("bundle");
    let checkpoint = fixture(checkpoint);
    let mut cli = vec!["import", "nerf-pytorch", "--checkpoint", s(&checkpoint), "--data", s(data), "--out", s(&bundle)];
    let args = args.map(fixture);
    if let Some(a) = &args {
        cli.extend(["--args", s(a)]);
    }
    let (ok, text) = nerf(&cli);
    assert!(ok, "import failed:\n{text}");
    let out = dir.path().join("render");
    let (width, height) = (width.to_string(), height.to_string());
    let limit = views.len().to_string();
    let args = ["--bundle", s(&bundle), "--split", "test", "--limit", &limit, "--width", &width, "--height", &height, "--npy", "--threads", "1", "--out", s(&out)];
    let (ok, text) = nerf_render(&args);
    assert!(ok, "nerf-render failed:\n{text}");
    views
        .iter()
        .map(|view| {
            let (h, w, ours) = load_npy(&out.join(format!("{view}.npy"))).unwrap();
            let (rh, rw, theirs) = load_npy(&fixture(run).join(format!("{view}.npy"))).unwrap();
            assert_eq!((h, w), (rh, rw), "{view}: size");
            let (mut se, mut max_rgb, mut max_acc) = (0.0f64, 0.0f32, 0.0f32);
            let rgb: Vec<f32> = theirs.chunks_exact(5).flat_map(|p| p[..3].to_vec()).collect();
            for (a, b) in ours.chunks_exact(5).zip(theirs.chunks_exact(5)) {
                for c in 0..3 {
                    let d = a[c] - b[c];
                    se += f64::from(d * d);
                    max_rgb = max_rgb.max(d.abs());
                }
                max_acc = max_acc.max((a[4] - b[4]).abs());
            }
            let mse = se / rgb.len() as f64;
            let mean = rgb.iter().sum::<f32>() / rgb.len() as f32;
            let rgb_std = (rgb.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / rgb.len() as f32).sqrt();
            let agreement = Agreement { psnr_db: -10.0 * mse.max(1e-20).log10(), max_rgb, max_acc, rgb_std };
            println!(
                "{run} {view} ({h}×{w}): nerf-render vs nerf-pytorch {:.1} dB, max |Δrgb| {:.2e}, max |Δacc| {:.2e} (image std {:.3})",
                agreement.psnr_db, agreement.max_rgb, agreement.max_acc, agreement.rgb_std
            );
            agreement
        })
        .collect()
}

#[test]
fn trained_checkpoint_renders_as_nerf_pytorch_renders_it() {
    // Coarse 4×64 (no skip) + fine 6×64 (skip after layer 4), view-dependent, 32 + 32 samples,
    // trained by nerf-pytorch on lego; zip format.
    for a in import_and_compare("trained", "trained/001000.tar", None, &lego(), (100, 100), &["r_0", "r_1"]) {
        assert!(a.rgb_std > 0.05, "nerf-pytorch's render is nearly flat: the comparison would mean little");
        assert!(a.psnr_db >= 50.0, "{:.1} dB", a.psnr_db);
        assert!(a.max_acc < 1e-3, "acc differs by {}", a.max_acc);
    }
}

#[test]
fn coarse_only_legacy_checkpoint_without_viewdirs_imports() {
    // 2×32, use_viewdirs False (output_linear), N_importance 0 (network_fine_state_dict None),
    // saved in torch's legacy (pre-1.6) format.
    for a in import_and_compare("coarse-only", "coarse-only/000000.tar", None, &lego(), (40, 40), &["r_0"]) {
        // The untrained network's colours vary little, so hold it to its own scale.
        assert!(a.psnr_db >= 60.0 && a.max_rgb < 1e-4, "{:.1} dB, max |Δ| {}", a.psnr_db, a.max_rgb);
        assert!(a.max_acc < 1e-4, "acc differs by {}", a.max_acc);
    }
}

#[test]
fn paper_size_checkpoint_imports() {
    // The paper's 8×256 network (skip after layer 4, L = 10 / 4, view-dependent), untrained
    // (seed 0), coarse only (N_importance 0) so that the fixture stays at 2.4 MB; 64 samples.
    for a in import_and_compare("paper-coarse", "paper-coarse/000000.tar", None, &lego(), (32, 32), &["r_0"]) {
        assert!(a.rgb_std > 0.05, "nerf-pytorch's render is nearly flat: the comparison would mean little");
        assert!(a.psnr_db >= 50.0, "{:.1} dB", a.psnr_db);
        assert!(a.max_acc < 1e-3, "acc differs by {}", a.max_acc);
    }
}

#[test]
fn llff_checkpoint_renders_through_ndc_rays_as_nerf_pytorch_renders_it() {
    // Trained by nerf-pytorch on fern (factor 1, llffhold 8, NDC rays): coarse 2×32, fine 6×32
    // (skip after layer 4), 16 + 16 samples; test view image001 at 40×30 (a tenth).
    let fern = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/real/fern");
    assert!(fern.join("poses_bounds.npy").is_file(), "{} is missing (CI provides ../shared)", fern.display());
    for a in import_and_compare("llff", "llff/001500.tar", None, &fern, (40, 30), &["image001"]) {
        assert!(a.rgb_std > 0.05, "nerf-pytorch's render is nearly flat: the comparison would mean little");
        assert!(a.psnr_db >= 50.0, "{:.1} dB", a.psnr_db);
        assert!(a.max_acc < 1e-3, "acc differs by {}", a.max_acc);
    }
    // The same networks with no_ndc: world rays between 0.9 · the nearest bound and the farthest.
    // Fed world points, far from the NDC ones it was trained on, the network is steep: one pixel
    // of the 1,200 differs by 1.5e-2 (rounding moves a fine sample), 8 by more than 1e-4.
    for a in import_and_compare("llff-no-ndc", "llff/001500.tar", Some("llff-no-ndc/args.txt"), &fern, (40, 30), &["image001"]) {
        assert!(a.rgb_std > 0.05, "nerf-pytorch's render is nearly flat: the comparison would mean little");
        assert!(a.psnr_db >= 60.0, "{:.1} dB", a.psnr_db);
    }
}

/// Run an import expected to fail: the message must contain `expect`, and nothing may be
/// written next to `out` (no bundle, no temporary directory).
fn import_fails(checkpoint: &Path, args: Option<&Path>, data: Option<&Path>, expect: &str) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bundle");
    let mut cli = vec!["import", "nerf-pytorch", "--checkpoint", s(checkpoint), "--out", s(&out)];
    if let Some(a) = args {
        cli.extend(["--args", s(a)]);
    }
    if let Some(d) = data {
        cli.extend(["--data", s(d)]);
    }
    let (ok, text) = nerf(&cli);
    assert!(!ok, "import of {} should fail", checkpoint.display());
    assert!(text.contains(expect), "expected {expect:?} in:\n{text}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "something was written:\n{text}");
}

/// The fixture `run`'s args.txt with `key`'s line replaced by `line`, in `dir`.
fn run_args_with(dir: &Path, run: &str, key: &str, line: &str) -> PathBuf {
    let text = std::fs::read_to_string(fixture(run).join("args.txt")).unwrap();
    let prefix = format!("{key} = ");
    assert!(text.lines().any(|l| l.starts_with(&prefix)), "fixture args.txt has no {key}");
    let new: Vec<&str> = text.lines().map(|l| if l.starts_with(&prefix) { line } else { l }).collect();
    let path = dir.join(format!("args-{run}-{key}.txt"));
    std::fs::write(&path, new.join("\n")).unwrap();
    path
}

/// The trained fixture's args.txt with `key`'s line replaced by `line`, in `dir`.
fn args_with(dir: &Path, key: &str, line: &str) -> PathBuf {
    run_args_with(dir, "trained", key, line)
}

#[test]
fn bad_input_gets_a_clear_error_and_no_bundle() {
    let lego = lego();
    let tmp = tempfile::tempdir().unwrap();
    let trained = fixture("trained/001000.tar");
    let args = fixture("trained/args.txt");

    // A truncated checkpoint.
    let bytes = std::fs::read(&trained).unwrap();
    let truncated = tmp.path().join("truncated.tar");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    import_fails(&truncated, Some(&args), Some(&lego), "not a readable PyTorch checkpoint");
    // A PyTorch file that is not nerf-pytorch's, and a file that is not PyTorch's at all.
    import_fails(&fixture("foreign.pt"), Some(&args), Some(&lego), "no network_fn_state_dict: not a nerf-pytorch checkpoint (its tensors: 0.bias");
    import_fails(&args, Some(&args), Some(&lego), "not a readable PyTorch checkpoint");

    // args.txt that disagrees with the checkpoint, or is not one.
    import_fails(&trained, Some(&args_with(tmp.path(), "netwidth", "netwidth = 128")), Some(&lego), "netwidth = 128 but pts_linears.0 has 64 outputs");
    import_fails(&trained, Some(&args_with(tmp.path(), "netdepth_fine", "netdepth_fine = 8")), Some(&lego), "netdepth_fine = 8 but the checkpoint has 6 pts_linears");
    import_fails(&trained, Some(&args_with(tmp.path(), "multires", "multires = 6")), Some(&lego), "multires = 6");
    import_fails(&trained, Some(&args_with(tmp.path(), "use_viewdirs", "use_viewdirs = False")), Some(&lego), "use_viewdirs = False but the checkpoint has rgb_linear");
    let wants_fine = run_args_with(tmp.path(), "coarse-only", "N_importance", "N_importance = 32");
    import_fails(&fixture("coarse-only/000000.tar"), Some(&wants_fine), Some(&lego), "N_importance = 32 but the checkpoint has no network_fine_state_dict");
    let garbage = tmp.path().join("garbage.txt");
    std::fs::write(&garbage, "{\"lr\": 0.001}\n").unwrap();
    import_fails(&trained, Some(&garbage), Some(&lego), "not an args.txt or config.txt of a nerf-pytorch run");
    import_fails(&trained, Some(&args_with(tmp.path(), "netdepth", "netdepth = four")), Some(&lego), "netdepth = four: not a non-negative integer");

    // Settings a bundle cannot express.
    import_fails(&trained, Some(&args_with(tmp.path(), "i_embed", "i_embed = -1")), Some(&lego), "i_embed = -1 is not supported");
    let sphere = run_args_with(tmp.path(), "llff", "spherify", "spherify = True");
    import_fails(&fixture("llff/001500.tar"), Some(&sphere), Some(&lego), "spherify = True is not supported");
    // An LLFF run given a Blender scene: the missing file is named.
    import_fails(&trained, Some(&args_with(tmp.path(), "dataset_type", "dataset_type = llff")), Some(&lego), "poses_bounds.npy");

    // No dataset: say what to give.
    let no_data = args_with(tmp.path(), "datadir", "datadir = /nonexistent/lego");
    import_fails(&trained, Some(&no_data), None, "give --data <scene dir>");
    import_fails(&trained, Some(&args), Some(&tmp.path().join("nowhere")), "transforms_test.json");
}
