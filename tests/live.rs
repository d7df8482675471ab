//! Live training (`nerf train --serve`, `nerf view RUN`): a run trained with `--serve` writes
//! snapshots of its field into `live/` (only the last one kept, none ever visible half-written
//! or half-removed under its name) and serves its status and the snapshot's files; the last
//! snapshot is the bundle `nerf export` makes of the run. `nerf view` on a run trained without
//! `--serve` exports a snapshot from its checkpoint, and again when a newer checkpoint appears.
//! A taken port, a folder that is not a run and a bad `--snapshot-every` are refused clearly.

mod common;

use common::{nerf, s, small_scene, tiny_config, trained_run};
use nerf::train::{TrainOptions, train};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// GET `path` from the server on `port`: (status code, body).
fn get(port: u16, path: &str) -> (u16, Vec<u8>) {
    let mut stream = TcpStream::connect(("127.0.0.1", port)).unwrap();
    write!(stream, "GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n").unwrap();
    let mut reply = Vec::new();
    stream.read_to_end(&mut reply).unwrap();
    let end = reply.windows(4).position(|w| w == b"\r\n\r\n").expect("a header");
    let head = String::from_utf8_lossy(&reply[..end]).into_owned();
    let code = head.split(' ').nth(1).and_then(|c| c.parse().ok()).expect("a status code");
    (code, reply[end + 4..].to_vec())
}

/// The server's `/live/status.json`.
fn status(port: u16) -> serde_json::Value {
    let (code, body) = get(port, "/live/status.json");
    assert_eq!(code, 200);
    serde_json::from_slice(&body).unwrap()
}

/// A `nerf` process that serves the viewer, killed when dropped.
struct Served {
    child: Child,
    port: u16,
}

impl Served {
    /// Start `nerf args` and read the port from its `viewer: http://…/` line.
    fn start(args: &[&str]) -> Served {
        let mut child = Command::new(env!("CARGO_BIN_EXE_nerf")).args(args).stdout(Stdio::piped()).stderr(Stdio::inherit()).spawn().unwrap();
        let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
        let line = lines.next().expect("a line from nerf").unwrap();
        let port = line.strip_prefix("viewer: http://127.0.0.1:").and_then(|r| r.trim_end_matches('/').parse().ok()).unwrap_or_else(|| panic!("not the viewer's line: {line}"));
        // Keep reading, so that the process never blocks on a full pipe.
        std::thread::spawn(move || lines.for_each(|l| println!("nerf: {}", l.unwrap_or_default())));
        Served { child, port }
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Poll the status until `ready` holds (failing after two minutes).
fn wait_for(port: u16, what: &str, ready: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
    let start = Instant::now();
    loop {
        let st = status(port);
        if ready(&st) {
            return st;
        }
        assert!(start.elapsed() < Duration::from_secs(120), "no {what} after two minutes: {st}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// A viewer folder the server accepts (an index.html).
fn viewer(dir: &Path) -> PathBuf {
    let viewer = dir.join("viewer");
    std::fs::create_dir_all(&viewer).unwrap();
    std::fs::write(viewer.join("index.html"), "<!doctype html>").unwrap();
    viewer
}

/// The folder names in `run/live/`, sorted.
fn live_names(run: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(run.join("live")).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    names.sort();
    names
}

/// `nerf export --tables f16` of `run` equals the snapshot in `snapshot`: the same files, byte
/// for byte.
fn assert_is_the_runs_export(run: &Path, snapshot: &Path, dir: &Path) {
    let export = dir.join("export");
    let (ok, text) = nerf(&["export", "--run", s(run), "--out", s(&export), "--tables", "f16"]);
    assert!(ok, "{text}");
    let files = |d: &Path| {
        let mut f: Vec<(String, Vec<u8>)> = std::fs::read_dir(d).unwrap().map(|e| e.unwrap()).map(|e| (e.file_name().into_string().unwrap(), std::fs::read(e.path()).unwrap())).collect();
        f.sort();
        f
    };
    let (a, b) = (files(&export), files(snapshot));
    assert_eq!(a.iter().map(|f| &f.0).collect::<Vec<_>>(), b.iter().map(|f| &f.0).collect::<Vec<_>>());
    for ((name, x), (_, y)) in a.iter().zip(&b) {
        assert!(x == y, "{name} differs between the snapshot and nerf export");
    }
    // And it loads: nerf-render's server takes it as a bundle.
    nerf_runtime::serve::bundle_files(snapshot).unwrap();
}

#[test]
fn train_serve_writes_atomic_snapshots_keeps_the_last_and_serves_its_status_and_files() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene(dir.path());
    let run = dir.path().join("run");
    let config = dir.path().join("tiny.toml");
    std::fs::write(&config, tiny_config().to_toml()).unwrap();
    let viewer = viewer(dir.path());

    // A reader that looks at live/ as fast as it can while training goes: every folder under a
    // snapshot's name must load as a bundle, unless it is gone by the time it is looked at again.
    let stop = Arc::new(AtomicBool::new(false));
    let watcher = {
        let (live, stop) = (run.join("live"), stop.clone());
        std::thread::spawn(move || {
            let (mut seen, mut broken) = (std::collections::BTreeSet::new(), Vec::new());
            while !stop.load(Ordering::Relaxed) {
                for entry in std::fs::read_dir(&live).into_iter().flatten().flatten() {
                    let name = entry.file_name().into_string().unwrap();
                    if name.starts_with('.') {
                        continue;
                    }
                    match nerf_runtime::serve::bundle_files(&entry.path()) {
                        Ok(_) => {
                            seen.insert(name);
                        }
                        Err(e) if entry.path().exists() => broken.push(format!("{name}: {e}")),
                        Err(_) => {}
                    }
                }
                std::thread::sleep(Duration::from_millis(1));
            }
            (seen, broken)
        })
    };
    let served = Served::start(&[
        "train", "--data", s(&scene), "--out", s(&run), "--config", s(&config), "--iters", "60",
        "--serve", "--port", "0", "--viewer", s(&viewer), "--snapshot-every", "0.2",
    ]);
    let st = wait_for(served.port, "finished run", |st| st["progress"]["done"] == true);
    stop.store(true, Ordering::Relaxed);
    let (seen, broken) = watcher.join().unwrap();
    println!("snapshots seen while training: {seen:?}; final status {st}");
    assert!(broken.is_empty(), "snapshot folders visible half-written or half-removed: {broken:?}");
    assert!(seen.len() >= 2, "only {seen:?} seen: the test needs snapshots during training, not only the last");

    // The status: the step, the last snapshot, the run's progress; only that snapshot is kept.
    assert_eq!(st["snapshot"], "60");
    assert_eq!(st["progress"]["step"], 60);
    assert_eq!(st["progress"]["iters"], 60);
    assert_eq!(st["progress"]["snapshots"], true);
    assert!(st["progress"]["elapsed_s"].as_f64().unwrap() > 0.0);
    assert_eq!(st["curve"].as_array().unwrap().last().unwrap()["step"], 60, "the curve from curve.csv");
    assert_eq!(live_names(&run), ["60"]);
    // The snapshot's own files, and nothing else, under /live/60/.
    let bundle = run.join("live/60");
    let (code, scene_json) = get(served.port, "/live/60/scene.json");
    assert_eq!((code, scene_json), (200, std::fs::read(bundle.join("scene.json")).unwrap()));
    for file in nerf_runtime::serve::bundle_files(&bundle).unwrap() {
        assert_eq!(get(served.port, &format!("/live/60/{}", file.0)).0, 200, "{}", file.0);
    }
    assert_eq!(get(served.port, "/live/59/scene.json").0, 404);
    assert_eq!(get(served.port, "/live/60/../../config.toml").0, 404);
    assert_eq!(get(served.port, "/").0, 200);
    assert_is_the_runs_export(&run, &bundle, dir.path());
}

#[test]
fn nerf_view_exports_a_snapshot_from_the_checkpoint_of_a_run_trained_without_serve_and_follows_newer_ones() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, run) = trained_run(dir.path());
    assert!(!run.join("live").exists(), "a run trained without --serve writes no snapshot");
    let viewer = viewer(dir.path());
    let served = Served::start(&["view", s(&run), "--port", "0", "--viewer", s(&viewer)]);
    let st = wait_for(served.port, "snapshot", |st| st["snapshot"] == "20");
    // progress.json is written by every `nerf train`.
    assert_eq!((st["progress"]["step"].as_u64(), st["progress"]["done"].as_bool(), st["progress"]["snapshots"].as_bool()), (Some(20), Some(true), Some(false)));
    assert_eq!(get(served.port, "/live/20/scene.json").0, 200);
    assert_is_the_runs_export(&run, &run.join("live/20"), dir.path());

    // Training goes on (another process): `nerf view` follows its next checkpoint.
    let mut config = tiny_config();
    config.iters = 20;
    train(&TrainOptions { format: None, data: scene, run: run.clone(), config, ndc: None, contract: None, downscale: 1, time_budget_min: None, iters: Some(30), progress: false }).unwrap();
    let st = wait_for(served.port, "newer snapshot", |st| st["snapshot"] == "30");
    assert_eq!(st["progress"]["step"], 30);
    assert_eq!(live_names(&run), ["30"]);
    assert_eq!(get(served.port, "/live/20/scene.json").0, 404, "the older snapshot is gone");
}

#[test]
fn a_taken_port_a_folder_that_is_not_a_run_and_a_bad_snapshot_interval_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let viewer = viewer(dir.path());
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port().to_string();
    let run = dir.path().join("run");
    let (ok, text) = nerf(&["train", "--data", s(dir.path()), "--out", s(&run), "--serve", "--port", &port, "--viewer", s(&viewer)]);
    assert!(!ok && text.contains(&format!("cannot listen on 127.0.0.1:{port}")), "{text}");
    assert!(!run.exists(), "nothing is written when the port is taken");
    let (ok, text) = nerf(&["view", s(dir.path()), "--port", "0", "--viewer", s(&viewer)]);
    assert!(!ok && text.contains("config.toml") && text.contains("training run directory"), "{text}");
    let (ok, text) = nerf(&["train", "--data", s(dir.path()), "--out", s(&run), "--serve", "--port", "0", "--snapshot-every", "0"]);
    assert!(!ok && text.contains("--snapshot-every 0: give seconds > 0"), "{text}");
    let (ok, text) = nerf(&["train", "--data", s(dir.path()), "--out", s(&run), "--port", "0"]);
    assert!(!ok && text.contains("--serve"), "--port without --serve: {text}");
}
