//! Plots of training and evaluation, drawn with plotters into memory and written as PNG
//! through a temporary file and a rename; text in a bundled font ([`font`]), so they draw
//! headless without system fonts.
//!
//! - `curve.png` beside a run's `curve.csv` ([`write_run_curve`], refreshed by `nerf train`
//!   after every val evaluation): val and train PSNR against minutes, steps along the top.
//! - `psnr_per_view.png` and `lpips_per_view.png` beside `nerf eval`'s `metrics.json`
//!   ([`write_view_psnr`], [`write_view_lpips`]).
//! - `nerf plot RUN... --out FILE.png` ([`plot_runs`]): several runs' curves on one plot.

pub mod curve;
pub mod curves;
pub mod figure;
pub mod font;
pub mod legend;
pub mod views;

pub use curve::{CurvePoint, read_curve};
pub use curves::{MAX_RUNS, RunCurve, draw_curves};
pub use figure::Figure;
pub use views::{ViewMetric, draw_view_metric, draw_view_psnr};

use crate::error::{Error, Result};
use crate::run_dir::RunDir;
use nerf_core::render::metrics::ImageMetrics;
use std::path::{Path, PathBuf};

/// File name of `nerf eval`'s per-view PSNR plot, beside `metrics.json`.
pub const VIEWS_FILE: &str = "psnr_per_view.png";
/// File name of `nerf eval`'s per-view LPIPS plot, beside `metrics.json` (when it has LPIPS).
pub const LPIPS_VIEWS_FILE: &str = "lpips_per_view.png";

/// Draw `run`'s `curve.csv` into its `curve.png`; returns the PNG's path.
pub fn write_run_curve(run: &RunDir) -> Result<PathBuf> {
    let points = read_curve(&run.curve_path())?;
    if points.is_empty() {
        return Err(Error::invalid(&run.curve_path(), "no rows yet: nothing to plot"));
    }
    let drawn = draw_curves(&[RunCurve { label: run_label(run.root()), points }])?;
    let path = run.curve_plot_path();
    drawn.figure.save(&path)?;
    Ok(path)
}

/// `nerf plot`: the curves of the run directories `runs` (each labelled by its directory's
/// name) on one plot at `out`, a `.png`. Every run is read and the plot drawn before anything
/// is written; a bad run or curve is an error naming its file, and `out` is then untouched.
pub fn plot_runs(runs: &[PathBuf], out: &Path) -> Result<()> {
    if !out.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
        return Err(Error::Config(format!("--out {}: the plot is a PNG; give a file name ending in .png", out.display())));
    }
    if runs.is_empty() || runs.len() > MAX_RUNS {
        return Err(Error::Config(format!("{} runs given: `nerf plot` takes 1 to {MAX_RUNS} run directories (one colour each)", runs.len())));
    }
    let labels = distinct_labels(runs);
    let mut curves = Vec::with_capacity(runs.len());
    for (dir, label) in runs.iter().zip(labels) {
        if !dir.is_dir() {
            return Err(Error::invalid(dir, "not a directory: give run directories written by `nerf train`"));
        }
        let curve = RunDir::open(dir)?.curve_path();
        if !curve.is_file() {
            return Err(Error::invalid(&curve, "no such file: the run has not reached its first evaluation"));
        }
        let points = read_curve(&curve)?;
        if points.is_empty() {
            return Err(Error::invalid(&curve, "no rows yet: the run has not reached its first evaluation"));
        }
        curves.push(RunCurve { label, points });
    }
    let drawn = draw_curves(&curves)?;
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    drawn.figure.save(out)
}

/// Plot the PSNR of `views` under `title` at `path` (`nerf eval`'s [`VIEWS_FILE`]).
pub fn write_view_psnr(title: &str, views: &[ImageMetrics], path: &Path) -> Result<()> {
    draw_view_psnr(title, views)?.save(path)
}

/// Plot the LPIPS of `views` under `title` at `path` (`nerf eval`'s [`LPIPS_VIEWS_FILE`]).
pub fn write_view_lpips(title: &str, views: &[ImageMetrics], path: &Path) -> Result<()> {
    draw_view_metric(title, views, ViewMetric::Lpips)?.save(path)
}

/// A run's name for a plot: its directory's name (of the absolute path for `.` and the like).
pub fn run_label(dir: &Path) -> String {
    let named = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
    named(dir).or_else(|| std::fs::canonicalize(dir).ok().and_then(|p| named(&p))).unwrap_or_else(|| dir.display().to_string())
}

/// Labels for `runs`: their directories' names, or the paths as given where two names are the
/// same (`a/run` and `b/run`).
fn distinct_labels(runs: &[PathBuf]) -> Vec<String> {
    let names: Vec<String> = runs.iter().map(|r| run_label(r)).collect();
    names
        .iter()
        .zip(runs)
        .map(|(name, run)| if names.iter().filter(|n| *n == name).count() > 1 { run.display().to_string() } else { name.clone() })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_are_directory_names_unless_they_clash() {
        assert_eq!(run_label(Path::new("/work/runs/q60")), "q60");
        assert_eq!(run_label(Path::new("runs/q60/")), "q60");
        let runs = [PathBuf::from("a/run"), PathBuf::from("b/run"), PathBuf::from("c/other")];
        assert_eq!(distinct_labels(&runs), ["a/run", "b/run", "other"]);
    }
}
