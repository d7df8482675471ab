//! Live training: what a run writes so that the viewer can watch it train, and what a server
//! reads back (`nerf train --serve`, `nerf view`).
//!
//! - `progress.json` ([`Progress`]): step, time, remaining estimate, recent loss and PSNR,
//!   replaced every [`PROGRESS_EVERY_S`] seconds by every `nerf train` (a tiny file), so that a
//!   server in another process can report a run trained without `--serve`.
//! - `live/<step>/`: a bundle of the field at that step ([`write_snapshot`]), written whole then
//!   renamed into place, after which every other snapshot is removed (the last one kept).
//!   `nerf train --serve` writes one [`SnapshotOptions::first_after_s`] into training, then at
//!   intervals that double up to [`SnapshotOptions::every_s`] (the field changes fastest at
//!   first), at each validation and at the end; `nerf view` writes one from each new checkpoint
//!   of a run whose trainer writes none.
//! - [`LiveStatus`]: what the page polls, made from the two and `curve.csv`.

use crate::config::TrainConfig;
use crate::error::Result;
use crate::export::{RunScene, field_bundle};
use crate::field::{FieldTrainer, TrainedField};
use crate::run_dir::RunDir;
use nerf_core::PinholeCamera;
use nerf_core::io::atomic::{remove_stale_temporaries, temp_sibling, write_atomic};
use nerf_core::sample::occupancy::OccupancyGrid;
use nerf_export::{CompileOptions, TablePrecision, write_bundle};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::time::{Duration, Instant, SystemTime};

/// Seconds between two writes of `progress.json`.
pub const PROGRESS_EVERY_S: f64 = 2.0;

/// `nerf train`'s progress, as `progress.json` records it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Progress {
    /// Steps completed (including resumed ones).
    pub step: usize,
    /// The step count the run stops at.
    pub iters: usize,
    /// Seconds trained, across resumes.
    pub elapsed_s: f64,
    /// The time budget in seconds, when there is one.
    pub budget_s: Option<f64>,
    /// Seconds left: the budget's, or the steps left at this session's speed, whichever ends
    /// first (`None` before the speed is known).
    pub remaining_s: Option<f64>,
    /// Steps per second in this session.
    pub steps_per_s: f64,
    /// The last step's loss (`None` before a step of this session).
    pub loss: Option<f32>,
    /// Mean training-batch PSNR (dB) over the last steps.
    pub train_psnr: f32,
    /// The last quick validation PSNR (dB).
    pub val_psnr: Option<f32>,
    /// Whether this trainer writes live snapshots (`--serve`): `nerf view` then leaves them to it.
    pub snapshots: bool,
    /// Training has ended (budget or steps reached).
    pub done: bool,
}

/// Writes `progress.json` every [`PROGRESS_EVERY_S`] seconds.
pub(crate) struct ProgressLog {
    run: RunDir,
    snapshots: bool,
    next_s: f64,
    start: (usize, Instant),
}

impl ProgressLog {
    /// For a session that starts at `step`.
    pub(crate) fn new(run: &RunDir, snapshots: bool, step: usize) -> Self {
        ProgressLog { run: run.clone(), snapshots, next_s: 0.0, start: (step, Instant::now()) }
    }

    /// Whether a write is due at `seconds` (of training).
    pub(crate) fn due(&self, seconds: f64) -> bool {
        seconds >= self.next_s
    }

    /// The progress now.
    pub(crate) fn progress(&self, trainer: &dyn FieldTrainer, seconds: f64, budget_s: Option<f64>, loss: Option<f32>, train_psnr: f32, val_psnr: Option<f32>) -> Progress {
        let (step, iters) = (trainer.steps_done(), trainer.config().iters);
        let session_s = self.start.1.elapsed().as_secs_f64();
        let steps_per_s = if session_s > 0.0 { (step - self.start.0) as f64 / session_s } else { 0.0 };
        let by_steps = (steps_per_s > 0.0).then(|| iters.saturating_sub(step) as f64 / steps_per_s);
        let by_budget = budget_s.map(|b| (b - seconds).max(0.0));
        let remaining_s = match (by_steps, by_budget) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        Progress { step, iters, elapsed_s: seconds, budget_s, remaining_s, steps_per_s, loss, train_psnr, val_psnr, snapshots: self.snapshots, done: false }
    }

    /// Record `progress` at `seconds`. A file that cannot be written is a warning: training
    /// matters more.
    pub(crate) fn write(&mut self, progress: &Progress, seconds: f64) {
        self.next_s = seconds + PROGRESS_EVERY_S;
        let path = self.run.progress_path();
        let json = serde_json::to_vec_pretty(progress).expect("progress serialises");
        if let Err(e) = write_atomic(&path, &json) {
            eprintln!("warning: {} not updated: {e}", path.display());
        }
    }
}

/// When `nerf train --serve` writes snapshots: after `first_after_s`, then at intervals of twice
/// the last one up to `every_s` (5, 15, 35, 75, 155, 245, … s by default), besides those at
/// each validation and at the end: 11 in a 10-minute run, which with a page attached made
/// 98.8% of the steps of the same run without `--serve` (docs/viewer.md).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SnapshotOptions {
    /// Seconds of stepping before the first one (small, so the page shows the field early).
    pub first_after_s: f64,
    /// The longest interval between two.
    pub every_s: f64,
}

impl Default for SnapshotOptions {
    fn default() -> Self {
        SnapshotOptions { first_after_s: 5.0, every_s: 90.0 }
    }
}

impl SnapshotOptions {
    /// The interval after one of `last` seconds.
    fn next_interval(&self, last: f64) -> f64 {
        (2.0 * last).min(self.every_s)
    }
}

/// Writes the trainer's field into `live/` as the options say.
pub(crate) struct Snapshots {
    run: RunDir,
    camera: PinholeCamera,
    scene: RunScene,
    options: SnapshotOptions,
    next_s: f64,
    /// The interval before `next_s`.
    interval_s: f64,
    /// Snapshots written, and the seconds they took on the training thread.
    written: usize,
    seconds: f64,
}

impl Snapshots {
    /// For a session whose stepping starts at `seconds` of training.
    pub(crate) fn new(run: &RunDir, options: SnapshotOptions, seconds: f64) -> Result<Self> {
        let scene = RunScene::read(run.read_source()?.as_ref());
        Ok(Snapshots { run: run.clone(), camera: run.read_camera()?, scene, options, next_s: seconds + options.first_after_s, interval_s: options.first_after_s, written: 0, seconds: 0.0 })
    }

    /// Whether one is due at `seconds`.
    pub(crate) fn due(&self, seconds: f64) -> bool {
        seconds >= self.next_s
    }

    /// Write the trainer's field now; the next one is due twice the last interval from
    /// `seconds`, at most `every_s`. A snapshot that cannot be written is a warning (`say`
    /// prints it): training goes on.
    pub(crate) fn write(&mut self, trainer: &dyn FieldTrainer, seconds: f64, say: &dyn Fn(String)) {
        self.interval_s = self.options.next_interval(self.interval_s);
        self.next_s = seconds + self.interval_s;
        let start = Instant::now();
        let field = trainer.snapshot();
        let written = write_snapshot(&self.run, trainer.steps_done(), field.as_ref(), trainer.config(), &self.camera, trainer.occupancy().cloned(), &self.scene);
        self.seconds += start.elapsed().as_secs_f64();
        match written {
            Ok(_) => self.written += 1,
            Err(e) => say(format!("warning: no live snapshot at step {}: {e}", trainer.steps_done())),
        }
    }

    /// What the snapshots cost, over `total_s` seconds of this session's training.
    pub(crate) fn summary(&self, total_s: f64) -> String {
        let each = self.seconds / self.written.max(1) as f64;
        format!("{} live snapshots, {each:.2} s each: {:.1}% of this session's {total_s:.0} s", self.written, 100.0 * self.seconds / total_s.max(1e-9))
    }
}

/// Write the bundle of `field` at `step` into `run`'s `live/<step>/` (whole, then renamed into
/// place; as `nerf export --tables f16` writes it), then remove every other snapshot; returns
/// the folder and the time it took.
pub fn write_snapshot(
    run: &RunDir,
    step: usize,
    field: &dyn TrainedField,
    config: &TrainConfig,
    camera: &PinholeCamera,
    occupancy: Option<OccupancyGrid>,
    scene: &RunScene,
) -> Result<(PathBuf, Duration)> {
    let start = Instant::now();
    let dir = run.live_dir().join(step.to_string());
    let mut bundle = field_bundle(field, config, camera, occupancy);
    scene.apply(&mut bundle.scene);
    // A float16 table: half the bytes to write and for the page to load, at well under 0.05 dB.
    write_bundle(&dir, &bundle, &CompileOptions { tables: TablePrecision::F16, ..CompileOptions::default() })?;
    prune_snapshots(run, step);
    Ok((dir, start.elapsed()))
}

/// Remove every snapshot but `keep`'s, and what writers that were killed left behind. Each is
/// renamed out of its name first, so a reader sees it whole or not at all.
fn prune_snapshots(run: &RunDir, keep: usize) {
    let live = run.live_dir();
    remove_stale_temporaries(&live);
    for (step, dir) in snapshots(run) {
        if step != keep {
            let old = temp_sibling(&dir, "old");
            if std::fs::rename(&dir, &old).is_ok() {
                let _ = std::fs::remove_dir_all(old);
            }
        }
    }
}

/// The snapshots in `run`'s `live/`: (step, folder), in no order.
fn snapshots(run: &RunDir) -> Vec<(usize, PathBuf)> {
    let Ok(entries) = std::fs::read_dir(run.live_dir()) else { return vec![] };
    entries
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            let step = snapshot_step(&name)?;
            e.file_type().ok()?.is_dir().then(|| (step, e.path()))
        })
        .collect()
}

/// The step of a snapshot folder's name: decimal digits as `usize` writes them (so `007`, `+7`
/// or a temporary `.7.tmp-…` are not snapshots).
fn snapshot_step(name: &str) -> Option<usize> {
    name.parse::<usize>().ok().filter(|s| s.to_string() == name)
}

/// The newest snapshot of `run`: (step, folder).
pub fn latest_snapshot(run: &RunDir) -> Option<(usize, PathBuf)> {
    snapshots(run).into_iter().max_by_key(|(step, _)| *step)
}

/// The folder of `run`'s snapshot named `id`, when it is there now.
pub fn snapshot_dir(run: &RunDir, id: &str) -> Option<PathBuf> {
    snapshot_step(id)?;
    let dir = run.live_dir().join(id);
    dir.is_dir().then_some(dir)
}

/// `run`'s `progress.json` and its age in seconds, when there is one that reads.
pub fn read_progress(run: &RunDir) -> Option<(Progress, f64)> {
    let path = run.progress_path();
    let bytes = nerf_core::io::limits::read_bounded(&path, nerf_core::io::limits::MAX_JSON_BYTES).ok()?;
    let progress = serde_json::from_slice(&bytes).ok()?;
    let age = std::fs::metadata(&path).and_then(|m| m.modified()).ok().and_then(|t| SystemTime::now().duration_since(t).ok()).map_or(0.0, |d| d.as_secs_f64());
    Some((progress, age))
}

/// One row of `curve.csv`, as the page draws it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CurveRow {
    /// Steps done.
    pub step: usize,
    /// Minutes trained.
    pub minutes: f64,
    /// Mean training-batch PSNR (dB).
    pub train_psnr: f32,
    /// Quick validation PSNR (dB), when measured.
    pub val_psnr: Option<f32>,
}

/// `/live/status.json`: what the page shows of a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LiveStatus {
    /// The newest snapshot's id (its folder name below `live/`), to load from `live/<id>/`.
    pub snapshot: Option<String>,
    /// The trainer's last `progress.json` (a run trained before it existed has none).
    pub progress: Option<Progress>,
    /// Seconds since it was written (a trainer that stopped without finishing stops updating it).
    pub progress_age_s: Option<f64>,
    /// `curve.csv`'s rows.
    pub curve: Vec<CurveRow>,
    /// What the server is doing or why there is no snapshot, for the page to show.
    pub note: Option<String>,
}

/// The status of `run` now, with the server's `note`.
pub fn status(run: &RunDir, note: Option<String>) -> LiveStatus {
    let (progress, progress_age_s) = match read_progress(run) {
        Some((p, age)) => (Some(p), Some(age)),
        None => (None, None),
    };
    let curve = crate::plot::curve::read_curve(&run.curve_path())
        .map(|rows| rows.into_iter().map(|r| CurveRow { step: r.step, minutes: r.minutes, train_psnr: r.train_psnr, val_psnr: r.val_psnr }).collect())
        .unwrap_or_default();
    LiveStatus { snapshot: latest_snapshot(run).map(|(step, _)| step.to_string()), progress, progress_age_s, curve, note }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn snapshots_come_5_s_in_then_at_doubling_intervals_up_to_every_s() {
        let options = SnapshotOptions::default();
        let mut times = vec![options.first_after_s];
        let mut interval = options.first_after_s;
        while times.len() < 7 {
            interval = options.next_interval(interval);
            times.push(times.last().unwrap() + interval);
        }
        assert_eq!(times, [5.0, 15.0, 35.0, 75.0, 155.0, 245.0, 335.0]);
        let every_2 = SnapshotOptions { first_after_s: 0.5, every_s: 2.0 };
        assert_eq!([0.5, 1.0, 2.0, 4.0].map(|i| every_2.next_interval(i)), [1.0, 2.0, 2.0, 2.0]);
    }

    #[test]
    fn a_snapshot_is_a_folder_named_by_its_step_in_usize_digits() {
        assert_eq!(snapshot_step("1200"), Some(1200));
        assert_eq!(snapshot_step("0"), Some(0));
        for name in ["", "007", "+7", "-1", ".7.tmp-12", "7a", "1e3", "99999999999999999999999"] {
            assert_eq!(snapshot_step(name), None, "{name:?}");
        }
    }

    #[test]
    fn the_latest_snapshot_is_the_highest_step_and_a_stray_name_is_none() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::create(dir.path()).unwrap();
        assert_eq!(latest_snapshot(&run), None);
        for name in ["90", "1000", "200", ".5000.tmp-1", "0300"] {
            std::fs::create_dir_all(run.live_dir().join(name)).unwrap();
        }
        std::fs::write(run.live_dir().join("7000"), "a file, not a snapshot").unwrap();
        assert_eq!(latest_snapshot(&run).map(|(s, _)| s), Some(1000));
        assert_eq!(snapshot_dir(&run, "200"), Some(run.live_dir().join("200")));
        for id in ["0300", "7000", "5", "../200"] {
            assert_eq!(snapshot_dir(&run, id), None, "{id}");
        }
    }
}
