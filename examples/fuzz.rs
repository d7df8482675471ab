//! Fuzz every parser of a user-supplied file (see `tests/fuzzing/`): mutated and truncated
//! valid files and random bytes, from a fixed seed.
//!
//! ```sh
//! cargo run --release --example fuzz -- --minutes 10            # every harness, 10 min each
//! cargo run --release --example fuzz -- --only scene,onnx --seed 7 --execs 100000
//! ```
//! Crashing and slow inputs go to `fuzz-crashes/<harness>/`; the process exits with status 1
//! when anything was found.

#[path = "../tests/fuzzing/mod.rs"]
mod fuzzing;

use clap::Parser;
use std::path::PathBuf;
use std::time::Duration;

#[derive(Parser)]
#[command(about = "Fuzz the parsers of every file a user hands the NeRF tools")]
struct Args {
    /// Minutes per harness.
    #[arg(long, default_value_t = 1.0)]
    minutes: f64,
    /// Run only these harnesses (comma-separated or repeated); `--list` names them.
    #[arg(long, value_delimiter = ',')]
    only: Vec<String>,
    /// Seed of the mutation stream.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Stop each harness after this many executions (whichever of time and count comes first).
    #[arg(long)]
    execs: Option<u64>,
    /// Where crashing, slow and in-flight inputs are written.
    #[arg(long, default_value = "fuzz-crashes")]
    crash_dir: PathBuf,
    /// An execution longer than this many seconds counts as slow.
    #[arg(long, default_value_t = 2.0)]
    slow_s: f64,
    /// An execution longer than this many seconds is a hang: the process stops and names it.
    #[arg(long, default_value_t = 60.0)]
    hang_s: f64,
    /// List the harnesses and exit.
    #[arg(long)]
    list: bool,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    if args.list {
        for h in &fuzzing::harnesses::ALL {
            println!("{:<18} {}", h.name, h.file);
        }
        return Ok(());
    }
    let names: Vec<&str> = fuzzing::harnesses::ALL.iter().map(|h| h.name).collect();
    if let Some(unknown) = args.only.iter().find(|n| !names.contains(&n.as_str())) {
        anyhow::bail!("unknown harness {unknown:?} (harnesses: {})", names.join(", "));
    }
    let settings = fuzzing::Settings {
        seed: args.seed,
        time: Duration::from_secs_f64(args.minutes * 60.0),
        max_execs: args.execs,
        crash_dir: args.crash_dir,
        slow: Duration::from_secs_f64(args.slow_s),
        hang: Duration::from_secs_f64(args.hang_s),
        regressions: Some(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz-regressions")),
    };
    let mut reports = Vec::new();
    for def in fuzzing::harnesses::ALL.iter().filter(|h| args.only.is_empty() || args.only.iter().any(|n| n == h.name)) {
        eprintln!(
            "fuzzing {} ({}), seed {}; if the process dies, the input it was running is {}",
            def.name,
            def.file,
            settings.seed,
            settings.crash_dir.join(def.name).join("current-input").display()
        );
        let report = fuzzing::run(def, &settings).map_err(anyhow::Error::msg)?;
        println!("{}", report.summary());
        for example in &report.unnamed_examples {
            println!("    error not naming the file: {example}");
        }
        reports.push(report);
    }
    println!("\nsummary (seed {}):", settings.seed);
    for r in &reports {
        println!("{}", r.summary());
        for (key, path) in &r.unique_crashes {
            println!("    crash {key}\n      input {}", path.display());
        }
    }
    let found: u64 = reports.iter().map(|r| r.crashes + r.slow).sum();
    if found > 0 {
        std::process::exit(1);
    }
    Ok(())
}
