//! A small fuzzer on stable Rust, shared by `examples/fuzz.rs` (long runs) and `tests/fuzz.rs`
//! (a short seeded run of every harness).
//!
//! A harness makes valid files with the project's own writers (its seed corpus), then feeds
//! mutated copies to the real parser through the file the parser reads. Each execution runs
//! under `catch_unwind`: a panic is a crash, saved to `<crash dir>/<harness>/<hash>`. Slow
//! executions (over [`Settings::slow`]) are saved as `slow-<hash>`; a watchdog ends the process
//! when one runs past [`Settings::hang`], naming the harness and the input. Before every
//! execution the input is written to `<crash dir>/<harness>/current-input`, so if the process
//! dies (an allocation failure aborts rather than panics) the input that killed it is there.
//!
//! Inputs that once crashed a parser are kept in `tests/fuzz-regressions/<harness>/` and
//! replayed after the seeds on every run.
//!
//! Besides crashes, the runner checks what every rejection says: an error must name the file
//! (it contains the harness's work directory). Messages that do not are counted and shown.

#![allow(dead_code)]

pub mod harnesses;
pub mod mutate;

use nerf_core::Rng;
use std::collections::BTreeMap;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

pub use mutate::Format;

/// A parser under test, with its seed files.
pub trait Harness {
    /// Valid files (made by the project's writers) that mutations start from.
    fn seeds(&self) -> &[Vec<u8>];
    /// Which structure-aware mutations apply.
    fn format(&self) -> Format;
    /// Writes `input` to the file the parser reads and runs the parser: `Ok` when it accepted
    /// the file, `Err(message)` when it rejected it.
    fn execute(&mut self, input: &[u8]) -> Result<(), String>;
}

/// A named harness and how to build it in a fresh work directory.
pub struct HarnessDef {
    /// Name used by `--only` and for the crash directory.
    pub name: &'static str,
    /// The file it mutates, for the report.
    pub file: &'static str,
    /// Builds the seed corpus and the parser's surroundings inside the given directory.
    pub setup: fn(&Path) -> Result<Box<dyn Harness>, String>,
}

/// How long and where to fuzz.
#[derive(Debug, Clone)]
pub struct Settings {
    /// Seed of the mutation stream (mixed with the harness name).
    pub seed: u64,
    /// Stop after this long per harness.
    pub time: Duration,
    /// Stop after this many executions per harness.
    pub max_execs: Option<u64>,
    /// Where crashing and slow inputs are saved (`<dir>/<harness>/...`).
    pub crash_dir: PathBuf,
    /// An execution longer than this is reported as slow and its input saved.
    pub slow: Duration,
    /// An execution longer than this ends the process (a hang).
    pub hang: Duration,
    /// Inputs that once crashed, replayed after the seeds: `<dir>/<harness>/*`.
    pub regressions: Option<PathBuf>,
}

/// The files in `dir`, sorted by name (none when it does not exist).
fn regression_inputs(dir: &Path) -> Result<Vec<Vec<u8>>, String> {
    let Ok(entries) = std::fs::read_dir(dir) else { return Ok(vec![]) };
    let mut paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.is_file()).collect();
    paths.sort();
    paths.iter().map(|p| std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()))).collect()
}

/// What one harness run found.
#[derive(Debug, Clone, Default)]
pub struct Report {
    /// Harness name.
    pub name: String,
    /// Executions, seeds included.
    pub execs: u64,
    /// Seeds (run first, unmutated).
    pub seeds: u64,
    /// Inputs the parser accepted.
    pub accepted: u64,
    /// Wall time of the run (mutating, writing and parsing).
    pub elapsed: Duration,
    /// Executions that panicked.
    pub crashes: u64,
    /// Distinct panic messages, with the first input saved for each.
    pub unique_crashes: BTreeMap<String, PathBuf>,
    /// The slowest execution and its index.
    pub slowest: (Duration, u64),
    /// Executions over [`Settings::slow`].
    pub slow: u64,
    /// Rejections whose message does not name the file, and one example of each (up to 5).
    pub unnamed_errors: u64,
    /// Examples of messages that do not name the file.
    pub unnamed_examples: Vec<String>,
}

impl Report {
    /// Executions per second.
    pub fn execs_per_s(&self) -> f64 {
        self.execs as f64 / self.elapsed.as_secs_f64().max(1e-9)
    }

    /// One line: executions, rate, crashes, slowest execution.
    pub fn summary(&self) -> String {
        format!(
            "{:<18} {:>8} execs {:>8.1}/s {:>6} accepted {:>4} crashes ({} distinct) {:>3} slow, slowest {:.3} s (exec {}), {} errors not naming the file",
            self.name,
            self.execs,
            self.execs_per_s(),
            self.accepted,
            self.crashes,
            self.unique_crashes.len(),
            self.slow,
            self.slowest.0.as_secs_f64(),
            self.slowest.1,
            self.unnamed_errors,
        )
    }
}

/// FNV-1a, 64 bits: names saved inputs by content.
pub fn hash(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ b as u64).wrapping_mul(0x100_0000_01b3))
}

/// The message and location of the last panic (set by the hook [`run`] installs).
static LAST_PANIC: Mutex<Option<(String, String)>> = Mutex::new(None);

/// The execution in progress, for the watchdog: (harness, index, start).
type Current = Arc<Mutex<Option<(String, u64, Instant)>>>;

/// Ends the process when an execution runs past `hang`, saying which one.
fn watchdog(current: Current, hang: Duration, input_file: PathBuf, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        while !stop.load(Ordering::Relaxed) {
            std::thread::sleep(Duration::from_millis(200));
            if let Some((name, index, start)) = current.lock().unwrap().as_ref()
                && start.elapsed() > hang
            {
                eprintln!(
                    "HANG: harness {name}, execution {index} has run for {:.0} s; its input is {}",
                    start.elapsed().as_secs_f64(),
                    input_file.display()
                );
                std::process::exit(3);
            }
        }
    })
}

fn save(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let path = dir.join(name);
    // Best effort: failing to save a finding must not stop the run (it is still counted).
    let _ = std::fs::create_dir_all(dir).and_then(|_| std::fs::write(&path, bytes));
    path
}

/// Fuzz one harness as `settings` say, printing each new distinct crash as it is found.
///
/// Errors (not findings): the harness could not be set up, or one of its seeds is rejected
/// (a harness whose valid files fail would test nothing).
pub fn run(def: &HarnessDef, settings: &Settings) -> Result<Report, String> {
    let work = tempfile::tempdir().map_err(|e| format!("work directory: {e}"))?;
    let mut harness = (def.setup)(work.path()).map_err(|e| format!("{}: setup failed: {e}", def.name))?;
    let seeds = harness.seeds().to_vec();
    for (k, seed) in seeds.iter().enumerate() {
        harness.execute(seed).map_err(|e| format!("{}: seed {k} is rejected: {e}", def.name))?;
    }
    let replayed = match &settings.regressions {
        Some(dir) => regression_inputs(&dir.join(def.name))?,
        None => vec![],
    };
    let crash_dir = settings.crash_dir.join(def.name);
    let input_file = crash_dir.join("current-input");
    std::fs::create_dir_all(&crash_dir).map_err(|e| format!("{}: {e}", crash_dir.display()))?;
    let work_name = work.path().to_string_lossy().into_owned();

    let current: Current = Arc::new(Mutex::new(None));
    let stop = Arc::new(AtomicBool::new(false));
    let dog = watchdog(current.clone(), settings.hang, input_file.clone(), stop.clone());
    let previous_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|info| {
        let message = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "(non-string panic)".into());
        let at = info.location().map(|l| format!("{}:{}", l.file(), l.line())).unwrap_or_default();
        *LAST_PANIC.lock().unwrap() = Some((message, at));
    }));

    let mut rng = Rng::new(settings.seed ^ hash(def.name.as_bytes()));
    let mut report = Report { name: def.name.into(), seeds: seeds.len() as u64, ..Default::default() };
    let start = Instant::now();
    while start.elapsed() < settings.time && settings.max_execs.is_none_or(|n| report.execs < n) {
        let index = report.execs;
        // The seeds themselves first, then the regression inputs, then mutations.
        let input = match seeds.iter().chain(&replayed).nth(index as usize) {
            Some(fixed) => fixed.clone(),
            None => mutate::mutate(&mut rng, &seeds, harness.format()),
        };
        let _ = std::fs::write(&input_file, &input);
        *current.lock().unwrap() = Some((def.name.into(), index, Instant::now()));
        let t0 = Instant::now();
        let outcome = catch_unwind(AssertUnwindSafe(|| harness.execute(&input)));
        let took = t0.elapsed();
        *current.lock().unwrap() = None;
        report.execs += 1;
        if took > report.slowest.0 {
            report.slowest = (took, index);
        }
        if took > settings.slow {
            report.slow += 1;
            let path = save(&crash_dir, &format!("slow-{:016x}", hash(&input)), &input);
            eprintln!("SLOW: {} execution {index} took {:.1} s; input saved to {}", def.name, took.as_secs_f64(), path.display());
        }
        match outcome {
            Ok(Ok(())) => report.accepted += 1,
            Ok(Err(message)) => {
                if !message.contains(&work_name) {
                    report.unnamed_errors += 1;
                    if report.unnamed_examples.len() < 5 && !report.unnamed_examples.contains(&message) {
                        report.unnamed_examples.push(message);
                    }
                }
            }
            Err(_) => {
                report.crashes += 1;
                let (message, at) = LAST_PANIC.lock().unwrap().take().unwrap_or_else(|| ("(no message)".into(), String::new()));
                // Distinct by place and message, without the numbers that vary per input.
                let key: String = format!("{at}: {}", message.chars().filter(|c| !c.is_ascii_digit()).collect::<String>());
                if !report.unique_crashes.contains_key(&key) {
                    let path = save(&crash_dir, &format!("{:016x}", hash(&input)), &input);
                    eprintln!("CRASH: {} execution {index} at {at}: {message}\n  input saved to {}", def.name, path.display());
                    report.unique_crashes.insert(key, path);
                }
            }
        }
    }
    report.elapsed = start.elapsed();
    std::panic::set_hook(previous_hook);
    stop.store(true, Ordering::Relaxed);
    let _ = dog.join();
    let _ = std::fs::remove_file(&input_file);
    Ok(report)
}
