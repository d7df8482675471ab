//! A short seeded fuzz run of every parser of a user-supplied file (the long run is
//! `cargo run --release --example fuzz -- --minutes 10`): no input may panic or take seconds,
//! and every error names the file.

mod fuzzing;

use std::time::Duration;

#[test]
fn every_parser_survives_a_short_seeded_fuzz_run() {
    let settings = fuzzing::Settings {
        seed: 0,
        time: Duration::from_secs(3),
        max_execs: Some(400),
        crash_dir: std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz-crashes"),
        slow: Duration::from_secs(2),
        hang: Duration::from_secs(60),
        regressions: Some(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz-regressions")),
    };
    let mut failures = Vec::new();
    for def in &fuzzing::harnesses::ALL {
        let report = fuzzing::run(def, &settings).unwrap();
        println!("{}", report.summary());
        // A harness that rejects every mutation would not reach the parsers' inner checks.
        assert!(report.execs > report.seeds, "{}: no mutated input ran", def.name);
        if report.crashes > 0 || report.slow > 0 {
            failures.push(format!("{}: {} crashes {:?}, {} slow", def.name, report.crashes, report.unique_crashes, report.slow));
        }
        // Every refusal names the file it refuses (the user must know which one to fix).
        if report.unnamed_errors > 0 {
            failures.push(format!("{}: {} errors not naming the file, e.g. {:?}", def.name, report.unnamed_errors, report.unnamed_examples));
        }
    }
    assert!(failures.is_empty(), "fuzzing found:\n{}", failures.join("\n"));
}
