//! `nerf plot`: runs' curves overlaid in one PNG, and clear errors (naming the file and the
//! line) that leave nothing written on bad input. The runs are made by hand (a `config.toml`
//! and a `curve.csv` are all a run directory needs to be plotted), so nothing trains here.

mod common;

use common::{nerf, s};
use std::path::{Path, PathBuf};

/// A run directory `name` under `dir` whose `curve.csv` is `curve`.
fn run_with_curve(dir: &Path, name: &str, curve: &str) -> PathBuf {
    let run = dir.join(name);
    std::fs::create_dir_all(&run).unwrap();
    std::fs::write(run.join("config.toml"), "").unwrap();
    std::fs::write(run.join("curve.csv"), curve).unwrap();
    run
}

const HEADER: &str = "step,minutes,train_psnr,val_psnr\n";

/// `nerf plot` with `args` fails, its message contains every needle, and `out` is not created.
fn refused(args: &[&str], out: &Path, needles: &[&str]) {
    let (ok, text) = nerf(args);
    assert!(!ok, "nerf {args:?} should fail:\n{text}");
    for n in needles {
        assert!(text.contains(n), "error for {args:?} should mention {n:?}:\n{text}");
    }
    assert!(!out.exists(), "nerf {args:?} wrote {}", out.display());
    let leftovers: Vec<_> = std::fs::read_dir(out.parent().unwrap()).map(|d| d.flatten().map(|e| e.file_name()).collect()).unwrap_or_default();
    assert!(leftovers.iter().all(|n| !n.to_string_lossy().contains(".tmp-")), "temporary files left: {leftovers:?}");
}

#[test]
fn runs_are_overlaid_in_one_png() {
    let dir = tempfile::tempdir().unwrap();
    let a = run_with_curve(dir.path(), "fast", &format!("{HEADER}1000,5.00,28.0,27.0\n2000,10.00,30.0,29.0\n"));
    let b = run_with_curve(dir.path(), "slow", &format!("{HEADER}500,5.00,26.0,25.0\n1000,10.00,28.0,27.5\n1500,15.00,29.0,28.0\n"));
    let out = dir.path().join("plots/compare.png");
    let (ok, text) = nerf(&["plot", s(&a), s(&b), "--out", s(&out)]);
    assert!(ok, "{text}");
    assert!(text.contains("2 runs plotted"), "{text}");
    let img = image::open(&out).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), nerf::plot::figure::SIZE);
    // Both runs' colours are drawn (the first two of the palette).
    for colour in [[31, 119, 180], [255, 127, 14]] {
        let n = img.pixels().filter(|p| p.0 == colour).count();
        assert!(n > 100, "{n} pixels of {colour:?}");
    }
    // One run alone: the same command, its own plot.
    let single = dir.path().join("single.png");
    let (ok, text) = nerf(&["plot", s(&a), "--out", s(&single)]);
    assert!(ok && single.is_file(), "{text}");
}

#[test]
fn bad_runs_and_curves_are_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let good = run_with_curve(dir.path(), "good", &format!("{HEADER}10,0.50,20.0,19.0\n"));
    let out = dir.path().join("out.png");
    let missing_column = run_with_curve(dir.path(), "no-val", "step,minutes,train_psnr\n10,0.5,20.0\n");
    refused(&["plot", s(&good), s(&missing_column), "--out", s(&out)], &out, &["no-val/curve.csv", "line 1", "no val_psnr column"]);
    let not_number = run_with_curve(dir.path(), "nan", &format!("{HEADER}10,0.50,20.0,19.0\n20,1.00,twenty,19.5\n"));
    refused(&["plot", s(&good), s(&not_number), "--out", s(&out)], &out, &["nan/curve.csv", "line 3", "train_psnr \"twenty\" is not a number"]);
    let header_only = run_with_curve(dir.path(), "fresh", HEADER);
    refused(&["plot", s(&header_only), "--out", s(&out)], &out, &["fresh/curve.csv", "no rows yet"]);
    let not_a_run = dir.path().join("empty");
    std::fs::create_dir_all(&not_a_run).unwrap();
    refused(&["plot", s(&not_a_run), "--out", s(&out)], &out, &["empty/config.toml", "training run directory"]);
    refused(&["plot", s(&dir.path().join("nowhere")), "--out", s(&out)], &out, &["nowhere", "not a directory"]);
    let jpg = dir.path().join("out.jpg");
    refused(&["plot", s(&good), "--out", s(&jpg)], &jpg, &["out.jpg", "ending in .png"]);
    let (ok, text) = nerf(&["plot", "--out", s(&out)]);
    assert!(!ok && text.contains("RUNS"), "no run given:\n{text}");
    let ten: Vec<PathBuf> = (0..10).map(|k| run_with_curve(dir.path(), &format!("r{k}"), &format!("{HEADER}10,0.50,20.0,19.0\n"))).collect();
    let mut args: Vec<&str> = vec!["plot"];
    args.extend(ten.iter().map(|p| s(p)));
    args.extend(["--out", s(&out)]);
    refused(&args, &out, &["10 runs given", "1 to 9"]);
    // An existing plot survives a refused redraw unchanged.
    let (ok, text) = nerf(&["plot", s(&good), "--out", s(&out)]);
    assert!(ok, "{text}");
    let before = std::fs::read(&out).unwrap();
    let (ok, _) = nerf(&["plot", s(&not_number), "--out", s(&out)]);
    assert!(!ok);
    assert_eq!(std::fs::read(&out).unwrap(), before, "the old plot is untouched");
}
