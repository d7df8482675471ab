//! Renders split across processes (`--shard i/n`, `--skip-existing`, `--merge`): three shard
//! processes and a merge write byte for byte the frames, GIF, metrics.json and contact sheet of
//! one process, through `nerf-render` and `nerf render`; a shard killed mid-render resumes; bad
//! shard options and incomplete merges are refused without writing anything; the Slurm,
//! Kubernetes and Ray examples in examples/ run their shards and merge the same way (Ray and
//! PyYAML from `$NERF_RAY_PYTHON`, else `$NERF_PYTHON`: those two tests skip when missing).

mod common;

use common::{nerf, nerf_render, python, s, trained_run};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The `nerf-render` binary beside the test (as `common::nerf_render` finds it).
fn nerf_render_bin() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    exe.parent().and_then(Path::parent).unwrap().join("nerf-render")
}

/// `a` then `b`.
fn cat<'a>(a: &[&'a str], b: &[&'a str]) -> Vec<&'a str> {
    [a, b].concat()
}

/// Start a binary with `args`, output captured.
fn spawn(bin: &Path, args: &[&str]) -> Child {
    Command::new(bin).args(args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("start the renderer")
}

/// Wait for `child`: its success and output.
fn finish(child: Child) -> (bool, String) {
    let out = child.wait_with_output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(!text.contains("panicked"), "panicked:\n{text}");
    (out.status.success(), text)
}

/// The files directly in `dir` (not the shards' manifests), by name.
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap()))
        .collect()
}

/// `a` and `b` hold the same files with the same bytes; returns how many.
fn assert_same_files(a: &Path, b: &Path) -> usize {
    let (fa, fb) = (files(a), files(b));
    assert_eq!(fa.keys().collect::<Vec<_>>(), fb.keys().collect::<Vec<_>>(), "{} vs {}", a.display(), b.display());
    for (name, bytes) in &fa {
        assert!(bytes == &fb[name], "{name} differs between {} and {}", a.display(), b.display());
    }
    fa.len()
}

/// A trained run, its bundle and its scene: (scene, run, bundle).
fn bundle(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let (scene, run) = trained_run(dir);
    let bundle = dir.join("bundle");
    let (ok, text) = nerf(&["export", "--run", s(&run), "--out", s(&bundle)]);
    assert!(ok, "{text}");
    (scene, run, bundle)
}

#[test]
fn three_shard_processes_and_a_merge_write_the_bytes_of_one_process() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, run, bundle) = bundle(dir.path());
    // nerf-render: 7 training views with ground truth (metrics.json, the contact sheet), and a
    // 7-frame orbit (orbit.gif); three shard processes at once, then the merge.
    let ort = nerf_render_bin();
    let jobs: [(&str, Vec<&str>); 2] = [
        ("views", vec!["--bundle", s(&bundle), "--split", "train", "--data", s(&scene), "--limit", "7", "--npy"]),
        ("orbit", vec!["--bundle", s(&bundle), "--orbit", "--frames", "7", "--npy"]),
    ];
    for (name, args) in &jobs {
        let (one, split) = (dir.path().join(format!("{name}-one")), dir.path().join(format!("{name}-split")));
        let (ok, text) = nerf_render(&cat(args, &["--out", s(&one)]));
        assert!(ok, "{text}");
        let shards: Vec<String> = (0..3).map(|i| format!("{i}/3")).collect();
        let children: Vec<Child> = shards.iter().map(|sh| spawn(&ort, &cat(args, &["--out", s(&split), "--shard", sh]))).collect();
        for child in children {
            let (ok, text) = finish(child);
            assert!(ok && text.contains("assemble them with --merge"), "{text}");
        }
        assert!(!split.join("metrics.json").exists() && !split.join("orbit.gif").exists(), "a shard wrote what the merge writes");
        let (ok, text) = nerf_render(&["--merge", "--out", s(&split)]);
        assert!(ok, "{text}");
        let n = assert_same_files(&one, &split);
        println!("nerf-render {name}: 3 shards + merge = one process, {n} files byte for byte");
    }
    assert!(dir.path().join("views-one/metrics.json").is_file() && dir.path().join("views-one/contact_sheet.png").is_file());
    assert!(dir.path().join("orbit-one/orbit.gif").is_file());
    // nerf render (burn): a 5-frame orbit, merged by nerf render.
    let (one, split) = (dir.path().join("burn-one"), dir.path().join("burn-split"));
    let orbit = ["render", "--run", s(&run), "--orbit", "--frames", "5", "--npy"];
    let (ok, text) = nerf(&cat(&orbit, &["--out", s(&one)]));
    assert!(ok, "{text}");
    for i in 0..3 {
        let sh = format!("{i}/3");
        let (ok, text) = nerf(&cat(&orbit, &["--out", s(&split), "--shard", &sh]));
        assert!(ok, "{text}");
    }
    let (ok, text) = nerf(&["render", "--merge", "--out", s(&split)]);
    assert!(ok && text.contains("orbit.gif"), "{text}");
    let n = assert_same_files(&one, &split);
    println!("nerf render orbit: 3 shards + merge = one process, {n} files byte for byte");
}

#[test]
fn a_shard_killed_mid_render_resumes_with_skip_existing() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, _, bundle) = bundle(dir.path());
    // The 20 training views with ground truth (their metrics must survive the kill), densely
    // sampled on one thread so that a shard takes long enough to be killed half way.
    let args = ["--bundle", s(&bundle), "--split", "train", "--data", s(&scene), "--dense", "--threads", "1", "--npy"];
    let one = dir.path().join("one");
    let (ok, text) = nerf_render(&cat(&args, &["--out", s(&one)]));
    assert!(ok, "{text}");
    assert!(!one.join(".shards").exists(), "a finished whole render leaves its manifest behind");
    // Kill shard 1/2 (frames 10..20) once it has recorded two frames.
    let split = dir.path().join("split");
    let manifest = split.join(".shards/shard-1-of-2.json");
    let mut child = spawn(&nerf_render_bin(), &cat(&args, &["--out", s(&split), "--shard", "1/2"]));
    let start = Instant::now();
    let recorded = || std::fs::read_to_string(&manifest).map(|t| t.matches("\"index\"").count()).unwrap_or(0);
    while recorded() < 2 && start.elapsed() < Duration::from_secs(60) && child.try_wait().unwrap().is_none() {
        std::thread::sleep(Duration::from_millis(2));
    }
    let killed = child.try_wait().unwrap().is_none();
    child.kill().unwrap();
    child.wait().unwrap();
    let done = recorded();
    assert!(killed && done < 10, "the shard finished ({done} frames) before it could be killed: render bigger frames");
    // No half-written frame: every PNG there decodes.
    for (name, _) in files(&split).iter().filter(|(n, _)| n.ends_with(".png")) {
        image::open(split.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    let (ok, text) = nerf_render(&["--merge", "--out", s(&split)]);
    assert!(!ok && text.contains("shard 0/2 has no manifest"), "{text}");
    let (ok, text) = nerf_render(&cat(&args, &["--out", s(&split), "--shard", "0/2"]));
    assert!(ok, "{text}");
    let (ok, text) = nerf_render(&["--merge", "--out", s(&split)]);
    assert!(!ok && text.contains("shard 1/2 has not finished"), "{text}");
    let (ok, text) = nerf_render(&cat(&args, &["--out", s(&split), "--shard", "1/2", "--skip-existing"]));
    assert!(ok && text.contains(&format!("({done} kept from an earlier run)")), "{text}");
    let (ok, text) = nerf_render(&["--merge", "--out", s(&split)]);
    assert!(ok, "{text}");
    assert_same_files(&one, &split);
    // A whole render asked to keep what is there keeps every frame, and its manifest for next time.
    let (ok, text) = nerf_render(&cat(&args, &["--out", s(&split), "--skip-existing"]));
    assert!(ok && text.contains("(20 kept from an earlier run)"), "{text}");
    assert!(split.join(".shards/shard-0-of-1.json").is_file());
    assert_same_files(&one, &split);
    println!("shard 1/2 killed after {done} frames, resumed and merged: identical to one process");
}

#[test]
fn bad_shard_options_and_incomplete_merges_are_refused_without_writing() {
    let dir = tempfile::tempdir().unwrap();
    let (_, run, bundle) = bundle(dir.path());
    let out = dir.path().join("out");
    let refused = |(ok, text): (bool, String), needles: &[&str]| {
        assert!(!ok, "accepted:\n{text}");
        for n in needles {
            assert!(text.contains(n), "the error should mention {n:?}:\n{text}");
        }
        assert!(!out.exists(), "wrote {}:\n{text}", out.display());
    };
    for shard in ["3/3", "1", "a/2", "0/0"] {
        let needle = if shard == "3/3" { "0 to 2" } else if shard == "0/0" { "1 to 10000 shards" } else { "give the shard as i/n" };
        refused(nerf_render(&["--bundle", s(&bundle), "--orbit", "--shard", shard, "--out", s(&out)]), &["--shard", needle]);
        refused(nerf(&["render", "--run", s(&run), "--orbit", "--shard", shard, "--out", s(&out)]), &["--shard", needle]);
    }
    refused(nerf_render(&["--merge", "--out", s(&out)]), &["out/.shards: no shard manifests"]);
    refused(nerf(&["render", "--merge", "--out", s(&out)]), &["out/.shards: no shard manifests"]);
    refused(nerf(&["render", "--merge", "--run", s(&run), "--out", s(&out)]), &["cannot be used with"]);
    // Two of three shards done: the merge names the third and writes nothing.
    for i in [0, 2] {
        let sh = format!("{i}/3");
        let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--orbit", "--frames", "4", "--shard", &sh, "--out", s(&out)]);
        assert!(ok, "{text}");
    }
    let before = files(&out);
    let (ok, text) = nerf_render(&["--merge", "--out", s(&out)]);
    assert!(!ok && text.contains("shard 1/3 has no manifest"), "{text}");
    assert_eq!(files(&out), before, "a failed merge changed the output");
    assert!(!out.join("orbit.gif").exists());
}

/// The Slurm job array's script run as Slurm would run each task (its `#SBATCH` lines are
/// comments to bash), then the merge script: the same files as one process.
#[test]
fn the_slurm_example_renders_shards_and_merges() {
    let dir = tempfile::tempdir().unwrap();
    let (_, _, bundle) = bundle(dir.path());
    let one = dir.path().join("one");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--orbit", "--frames", "5", "--out", s(&one)]);
    assert!(ok, "{text}");
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/slurm");
    let out = dir.path().join("slurm");
    let script = |name: &str, task: Option<usize>| {
        let mut c = Command::new("bash");
        c.arg(examples.join(name));
        c.env("BUNDLE", &bundle).env("OUT", &out).env("NERF_RENDER", nerf_render_bin());
        if let Some(i) = task {
            c.args(["--orbit", "--frames", "5"]);
            c.env("SLURM_ARRAY_TASK_ID", i.to_string()).env("SLURM_ARRAY_TASK_COUNT", "3").env("SLURM_CPUS_PER_TASK", "1");
        }
        let o = c.output().unwrap();
        let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
        assert!(o.status.success(), "{name} (task {task:?}):\n{text}");
        text
    };
    for i in 0..3 {
        assert!(script("render.sbatch", Some(i)).contains(&format!("shard {i}/3")));
    }
    script("merge.sbatch", None);
    assert_same_files(&one, &out);
}

/// A Python that has `module` (`$NERF_RAY_PYTHON`, else `$NERF_PYTHON`), or `None`.
fn python_with(module: &str) -> Option<String> {
    let py = std::env::var("NERF_RAY_PYTHON").unwrap_or_else(|_| python());
    let ok = Command::new(&py).args(["-c", &format!("import {module}")]).output().is_ok_and(|o| o.status.success());
    ok.then_some(py)
}

/// The Kubernetes Indexed Job's container command, taken from the manifest and run as each
/// pod would run it (`JOB_COMPLETION_INDEX` = 0 … completions − 1, the volume's paths mapped to
/// a temporary directory, `VIEWS` a smaller orbit than the manifest's to keep the test short),
/// then the merge Job's: the same files as one process. Skips without PyYAML.
#[test]
fn the_kubernetes_example_renders_shards_and_merges() {
    let Some(py) = python_with("yaml") else {
        eprintln!("skipped: no PyYAML in $NERF_RAY_PYTHON / $NERF_PYTHON");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (_, _, bundle) = bundle(dir.path());
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/kubernetes");
    let read = |file: &str| -> serde_json::Value {
        let code = "import json, sys, yaml; print(json.dumps(yaml.safe_load(open(sys.argv[1]))))";
        let o = Command::new(&py).args(["-c", code]).arg(examples.join(file)).output().unwrap();
        assert!(o.status.success(), "{file}: {}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let (render, merge) = (read("render-job.yaml"), read("merge-job.yaml"));
    assert_eq!((render["kind"].as_str(), render["spec"]["completionMode"].as_str()), (Some("Job"), Some("Indexed")));
    let shards = render["spec"]["completions"].as_u64().unwrap();
    let data = dir.path().join("data");
    std::fs::create_dir_all(&data).unwrap();
    std::os::unix::fs::symlink(&bundle, data.join("bundle")).unwrap();
    let bin = dir.path().join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    std::os::unix::fs::symlink(nerf_render_bin(), bin.join("nerf-render")).unwrap();
    let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap());
    // A container's environment, with the volume's mount mapped to `data`.
    let env = |job: &serde_json::Value| -> BTreeMap<String, String> {
        let c = &job["spec"]["template"]["spec"]["containers"][0];
        let mount = c["volumeMounts"][0]["mountPath"].as_str().unwrap().to_string();
        c["env"].as_array().into_iter().flatten().map(|e| (e["name"].as_str().unwrap().to_string(), e["value"].as_str().unwrap().replace(&mount, s(&data)))).collect()
    };
    let run_pod = |job: &serde_json::Value, index: Option<u64>| {
        let c = &job["spec"]["template"]["spec"]["containers"][0];
        let mut argv: Vec<&str> = c["command"].as_array().unwrap().iter().chain(c["args"].as_array().into_iter().flatten()).map(|v| v.as_str().unwrap()).collect();
        let mut cmd = Command::new(argv.remove(0));
        cmd.args(&argv).envs(env(job)).env("PATH", &path).env("VIEWS", VIEWS);
        if let Some(i) = index {
            cmd.env("JOB_COMPLETION_INDEX", i.to_string());
        }
        let o = cmd.output().unwrap();
        let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
        assert!(o.status.success(), "{argv:?} (index {index:?}):\n{text}");
    };
    const VIEWS: &str = "--orbit --frames 9 --width 16";
    let vars = env(&render);
    assert_eq!(vars["SHARDS"], shards.to_string(), "SHARDS must equal completions");
    assert_eq!(env(&merge)["OUT"], vars["OUT"], "the merge reads where the shards write");
    for i in 0..shards {
        run_pod(&render, Some(i));
    }
    run_pod(&merge, None);
    let one = dir.path().join("one");
    assert!(vars["VIEWS"].starts_with("--orbit"), "{}", vars["VIEWS"]);
    let views: Vec<&str> = VIEWS.split_whitespace().collect();
    let (ok, text) = nerf_render(&cat(&cat(&["--bundle", s(&bundle)], &views), &["--out", s(&one)]));
    assert!(ok, "{text}");
    let n = assert_same_files(&one, Path::new(&vars["OUT"]));
    println!("kubernetes example: {shards} pods + merge = one process, {n} files");
}

/// examples/ray/render.py on a local Ray cluster: Ray tasks run the shards, then the merge; the
/// same files as one process. Skips without Ray.
#[test]
fn the_ray_example_renders_shards_and_merges() {
    let Some(py) = python_with("ray") else {
        eprintln!("skipped: no Ray in $NERF_RAY_PYTHON / $NERF_PYTHON (pip install ray to run it)");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (_, _, bundle) = bundle(dir.path());
    let one = dir.path().join("one");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--orbit", "--frames", "6", "--out", s(&one)]);
    assert!(ok, "{text}");
    let out = dir.path().join("ray");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/ray/render.py");
    let o = Command::new(&py)
        .arg(&script)
        .args(["--bundle", s(&bundle), "--out", s(&out), "--shards", "3", "--nerf-render", s(&nerf_render_bin()), "--num-cpus", "2", "--", "--orbit", "--frames", "6"])
        .output()
        .unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "{text}");
    assert!(text.contains("merged"), "{text}");
    assert_same_files(&one, &out);
}
