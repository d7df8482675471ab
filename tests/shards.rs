//! Renders split across processes (`--shard i/n`, `--skip-existing`, `--merge`): three shard
//! processes and a merge write byte for byte the frames, GIF, metrics.json and contact sheet of
//! one process, through `nerf-render` and `nerf render`; a shard killed mid-render resumes; bad
//! shard options and incomplete merges are refused without writing anything; the Slurm,
//! Kubernetes and Ray examples in examples/ run their shards and merge the same way: Slurm's
//! submit.sh through a stand-in `sbatch`, the Kubernetes Jobs checked against Kubernetes' schema,
//! the Ray script on a local Ray cluster the test starts (Ray, PyYAML and kubernetes-validate
//! from `$NERF_PYTHON`, which `scripts/setup.sh` provides: without them these tests fail).

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

/// A stand-in for Slurm's `sbatch`: records each call's arguments (one a line) in
/// `$SBATCH_CALLS/<n>` and the `BUNDLE` and `OUT` it was given in `<n>.env`, and answers with
/// job id 4000 + n as the real one does: `<id>;<cluster>` with `--parsable`, a sentence without.
const SBATCH: &str = r#"#!/bin/bash
set -eu
n=1
while [ -e "$SBATCH_CALLS/$n" ]; do n=$((n + 1)); done
printf 'BUNDLE=%s\nOUT=%s\n' "${BUNDLE-}" "${OUT-}" > "$SBATCH_CALLS/$n.env"
printf '%s\n' "$@" > "$SBATCH_CALLS/$n"
case " $* " in
  *" --parsable "*) echo "$((4000 + n));test-cluster" ;;
  *) echo "Submitted batch job $((4000 + n))" ;;
esac
"#;

/// examples/slurm/submit.sh with the stand-in `sbatch` on `PATH`, then what it queued run as
/// Slurm would: render.sbatch once per task of the array, with the arguments submit.sh gave it
/// (its `#SBATCH` lines are comments to bash), and merge.sbatch after them, which its `afterok`
/// dependency on the array must say. The same files as one process. Bad shard counts and a
/// missing BUNDLE are refused before anything is queued.
#[test]
fn the_slurm_example_submits_an_array_and_a_merge_after_it() {
    let dir = tempfile::tempdir().unwrap();
    let (_, _, bundle) = bundle(dir.path());
    let one = dir.path().join("one");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--orbit", "--frames", "5", "--out", s(&one)]);
    assert!(ok, "{text}");
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/slurm");
    let out = dir.path().join("slurm");
    let (bin, calls) = (dir.path().join("bin"), dir.path().join("calls"));
    std::fs::create_dir_all(&bin).unwrap();
    std::fs::create_dir_all(&calls).unwrap();
    std::fs::write(bin.join("sbatch"), SBATCH).unwrap();
    std::fs::set_permissions(bin.join("sbatch"), std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap());
    let submit = |args: &[&str], with_bundle: bool| {
        let mut c = Command::new("bash");
        c.arg(examples.join("submit.sh")).args(args).env("PATH", &path).env("SBATCH_CALLS", &calls).env("OUT", &out).env_remove("BUNDLE");
        if with_bundle {
            c.env("BUNDLE", &bundle);
        }
        let o = c.output().unwrap();
        (o.status.success(), format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr)))
    };
    for (args, needle) in [("0", "not '0'"), ("three", "not 'three'"), ("10001", "at most 10000")] {
        let (ok, text) = submit(&[args], true);
        assert!(!ok && text.contains(needle), "submit.sh {args}:\n{text}");
    }
    let (ok, text) = submit(&["3"], false);
    assert!(!ok && text.contains("set BUNDLE"), "{text}");
    assert_eq!(std::fs::read_dir(&calls).unwrap().count(), 0, "a refused submission called sbatch");

    let (ok, text) = submit(&["3", "--orbit", "--frames", "5"], true);
    assert!(ok, "{text}");
    // Call n: `sbatch [options] script [the script's arguments]`, and the environment it saw.
    let call = |n: u32| {
        let recorded = std::fs::read_to_string(calls.join(n.to_string())).unwrap_or_else(|e| panic!("sbatch call {n}: {e}\n{text}"));
        let args: Vec<String> = recorded.lines().map(String::from).collect();
        let k = args.iter().position(|a| !a.starts_with('-')).unwrap_or_else(|| panic!("sbatch call {n} names no script: {args:?}"));
        let env = std::fs::read_to_string(calls.join(format!("{n}.env"))).unwrap();
        (args[..k].to_vec(), PathBuf::from(&args[k]), args[k + 1..].to_vec(), env)
    };
    let option = |options: &[String], name: &str| options.iter().find_map(|o| o.strip_prefix(&format!("{name}=")).map(String::from));
    assert!(!calls.join("3").exists(), "submit.sh called sbatch more than twice");
    let (array_opts, render, render_args, array_env) = call(1);
    let (merge_opts, merge, merge_args, merge_env) = call(2);
    assert_eq!((&render, &merge), (&examples.join("render.sbatch"), &examples.join("merge.sbatch")));
    for opts in [&array_opts, &merge_opts] {
        assert!(["--parsable", "--export=ALL"].iter().all(|o| opts.iter().any(|a| a == o)), "{opts:?}");
    }
    let range = option(&array_opts, "--array").unwrap_or_else(|| panic!("the render is not a job array: {array_opts:?}"));
    assert_eq!(range, "0-2", "3 shards: the array's tasks 0 to 2");
    assert_eq!(option(&array_opts, "--dependency"), None);
    // The stand-in answered "4001;test-cluster": the dependency names the job id alone.
    assert_eq!(option(&merge_opts, "--dependency").as_deref(), Some("afterok:4001"), "{merge_opts:?}");
    assert_eq!(render_args, ["--orbit", "--frames", "5"]);
    assert!(merge_args.is_empty(), "{merge_args:?}");
    let exported = format!("BUNDLE={}\nOUT={}\n", bundle.display(), out.display());
    assert_eq!([&array_env, &merge_env], [&exported, &exported], "what --export=ALL hands the jobs");
    assert!(text.contains("render: job array 4001 (3 shards); merge: job 4002 after it"), "{text}");
    // Slurm's part: each task of the array, then the merge.
    let (first, last) = range.split_once('-').unwrap();
    let tasks = first.parse::<usize>().unwrap()..=last.parse::<usize>().unwrap();
    let count = tasks.clone().count();
    let run = |script: &Path, args: &[String], task: Option<usize>| {
        let mut c = Command::new("bash");
        c.arg(script).args(args).env("BUNDLE", &bundle).env("OUT", &out).env("NERF_RENDER", nerf_render_bin());
        if let Some(i) = task {
            c.env("SLURM_ARRAY_JOB_ID", "4001").env("SLURM_ARRAY_TASK_ID", i.to_string());
            c.env("SLURM_ARRAY_TASK_COUNT", count.to_string()).env("SLURM_CPUS_PER_TASK", "1");
        }
        let o = c.output().unwrap();
        let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
        assert!(o.status.success(), "{} (task {task:?}):\n{text}", script.display());
        text
    };
    for i in tasks {
        let text = run(&render, &render_args, Some(i));
        assert!(text.contains(&format!("shard {i}/3")), "{text}");
    }
    run(&merge, &merge_args, None);
    let n = assert_same_files(&one, &out);
    println!("slurm example: submit.sh queued --array={range} and the merge with --dependency=afterok:4001; {count} tasks + merge = one process, {n} files");
}

/// `$NERF_PYTHON` (scripts/env.sh), which must have `modules`: a test that needs them fails
/// without them, saying how to install them.
fn python_with(modules: &[&str]) -> String {
    let py = python();
    for module in modules {
        let ok = Command::new(&py).args(["-c", &format!("import {module}")]).output().is_ok_and(|o| o.status.success());
        assert!(
            ok,
            "{py} cannot import {module}: run `bash scripts/setup.sh` (it installs Ray, PyYAML and kubernetes-validate into the project's venv), then `. scripts/env.sh`"
        );
    }
    py
}

/// The Kubernetes Indexed Job and the merge Job checked against Kubernetes' Job schema, strictly
/// (kubernetes-validate: what `kubectl apply --dry-run=client` checks; unknown fields refused,
/// as broken copies of the manifest show), then their container commands run as each pod would
/// run them (`JOB_COMPLETION_INDEX` = 0 … completions − 1, the volume's paths mapped to a
/// temporary directory, `VIEWS` a smaller orbit than the manifest's to keep the test short):
/// the same files as one process.
#[test]
fn the_kubernetes_example_renders_shards_and_merges() {
    let py = python_with(&["yaml", "kubernetes_validate"]);
    let dir = tempfile::tempdir().unwrap();
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/kubernetes");
    let validate = |files: &[&Path]| {
        let o = Command::new(&py).args(["-m", "kubernetes_validate", "--strict"]).args(files).output().unwrap();
        (o.status.success(), format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr)))
    };
    let (render_file, merge_file) = (examples.join("render-job.yaml"), examples.join("merge-job.yaml"));
    let (ok, text) = validate(&[&render_file, &merge_file]);
    assert!(ok && text.matches("passed for resource job/").count() == 2, "{text}");
    let manifest = std::fs::read_to_string(&render_file).unwrap();
    let breaks = [
        ("backoffLimit: 8", "backofLimit: 8", "'backofLimit' was unexpected"),
        ("completions: 8", "completions: \"three\"", "'three' is not of type 'integer'"),
        ("volumeMounts:", "volumeMount:", "'volumeMount' was unexpected"),
    ];
    for (from, to, needle) in breaks {
        assert!(manifest.contains(from), "render-job.yaml has no {from:?} to break");
        let broken = dir.path().join("broken.yaml");
        std::fs::write(&broken, manifest.replacen(from, to, 1)).unwrap();
        let (ok, text) = validate(&[&broken]);
        assert!(!ok && text.contains(needle), "{to:?} in place of {from:?} was not refused as {needle:?}:\n{text}");
    }

    let (_, _, bundle) = bundle(dir.path());
    let read = |file: &Path| -> serde_json::Value {
        let code = "import json, sys, yaml; print(json.dumps(yaml.safe_load(open(sys.argv[1]))))";
        let o = Command::new(&py).args(["-c", code]).arg(file).output().unwrap();
        assert!(o.status.success(), "{}: {}", file.display(), String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let (render, merge) = (read(&render_file), read(&merge_file));
    assert_eq!((render["kind"].as_str(), render["spec"]["completionMode"].as_str()), (Some("Job"), Some("Indexed")));
    let claim = |job: &serde_json::Value| job["spec"]["template"]["spec"]["volumes"][0]["persistentVolumeClaim"]["claimName"].clone();
    assert_eq!(claim(&render), claim(&merge), "the merge mounts the shards' volume");
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
    println!("kubernetes example: both Jobs valid (kubernetes-validate --strict), {} broken copies refused; {shards} pods + merge = one process, {n} files", breaks.len());
}

/// Processes started for a test in a process group of their own (the leader's, which what it
/// starts inherits): killed whole when dropped, so a failing test leaves nothing running.
struct Group {
    leader: Child,
    killed: bool,
}

impl Group {
    /// Start `cmd` as the leader of a new group.
    fn spawn(cmd: &mut Command) -> Group {
        use std::os::unix::process::CommandExt;
        Group { leader: cmd.process_group(0).spawn().unwrap_or_else(|e| panic!("start {cmd:?}: {e}")), killed: false }
    }

    /// The group's live (not zombie) processes, from /proc.
    fn members(&self) -> Vec<u32> {
        let group = self.leader.id().to_string();
        let Ok(entries) = std::fs::read_dir("/proc") else { return Vec::new() };
        entries
            .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
            .filter(|pid| {
                // /proc/<pid>/stat: pid (comm) state ppid pgrp …, comm may hold spaces.
                let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
                let fields: Vec<&str> = stat.rsplit_once(')').map_or("", |(_, rest)| rest).split_whitespace().collect();
                fields.len() > 2 && fields[0] != "Z" && fields[2] == group
            })
            .collect()
    }

    /// Wait (at most `limit`) until the group has no live process left: how many are left.
    fn drained(&self, limit: Duration) -> usize {
        let start = Instant::now();
        while !self.members().is_empty() && start.elapsed() < limit {
            std::thread::sleep(Duration::from_millis(50));
        }
        self.members().len()
    }

    /// Kill the whole group (SIGKILL: Ray's own shutdown drains for up to 30 s); how many of its
    /// processes are left after 10 s.
    fn kill(&mut self) -> usize {
        if !self.killed && !self.members().is_empty() {
            // SAFETY: kill(2) on the group this test started, which still has members.
            unsafe { libc::kill(-(self.leader.id() as libc::pid_t), libc::SIGKILL) };
        }
        self.killed = true;
        let _ = self.leader.wait();
        self.drained(Duration::from_secs(10))
    }

    /// Wait for the leader (at most `limit`, then the group is killed and the test fails):
    /// its success.
    fn wait(&mut self, limit: Duration, what: &str, log: &Path) -> bool {
        let start = Instant::now();
        loop {
            if let Some(status) = self.leader.try_wait().unwrap() {
                return status.success();
            }
            if start.elapsed() > limit {
                self.kill();
                panic!("{what} still running after {limit:?}, killed:\n{}", std::fs::read_to_string(log).unwrap_or_default());
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for Group {
    fn drop(&mut self) {
        self.kill();
    }
}

/// `cmd` with stdout and stderr going to the file `log`.
fn logged<'a>(cmd: &'a mut Command, log: &Path) -> &'a mut Command {
    let file = std::fs::File::create(log).unwrap();
    cmd.stdin(Stdio::null()).stdout(file.try_clone().unwrap()).stderr(file)
}

/// `cmd` with Ray's token authentication on and a token of the test's own (32 random hex
/// digits, the same for a cluster and its drivers): left to itself, `ray start` takes
/// ~/.ray/auth_token when there is one, but a driver given an address does not.
fn ray_auth<'a>(cmd: &'a mut Command, token: &str) -> &'a mut Command {
    cmd.env("RAY_AUTH_MODE", "token").env("RAY_AUTH_TOKEN", token).env_remove("RAY_AUTH_TOKEN_PATH")
}

/// A fresh token for [`ray_auth`].
fn ray_token() -> String {
    use std::io::Read;
    let mut bytes = [0u8; 16];
    std::fs::File::open("/dev/urandom").and_then(|mut f| f.read_exact(&mut bytes)).unwrap();
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// A Ray head node started for a test: `ray start --head --block` with `cpus` CPUs, its
/// temporary files (and so its logs and sockets) in `dir`, ports the system says are free.
/// Returns the group, the cluster's address and the head's node id once it takes drivers.
fn ray_head(py: &str, dir: &Path, cpus: usize, token: &str) -> (Group, String, String) {
    let listeners: Vec<_> = (0..3).map(|_| std::net::TcpListener::bind("127.0.0.1:0").unwrap()).collect();
    let ports: Vec<String> = listeners.iter().map(|l| l.local_addr().unwrap().port().to_string()).collect();
    drop(listeners);
    let log = dir.join("head.log");
    let mut cmd = Command::new(py);
    cmd.args(["-m", "ray.scripts.scripts", "start", "--head", "--block", "--disable-usage-stats", "--include-dashboard=false"])
        .args(["--num-cpus", &cpus.to_string(), "--object-store-memory", "100000000", "--temp-dir", s(dir)])
        .args(["--port", &ports[0], "--dashboard-port", &ports[1], "--dashboard-agent-listen-port", &ports[2]]);
    let mut head = Group::spawn(logged(ray_auth(&mut cmd, token), &log));
    // Ready once it has written its address (to ray_current_cluster in its temporary directory).
    let start = Instant::now();
    let address = loop {
        let address = std::fs::read_to_string(dir.join("ray_current_cluster")).unwrap_or_default();
        if !address.trim().is_empty() {
            break address.trim().to_string();
        }
        let exited = head.leader.try_wait().unwrap();
        assert!(exited.is_none() && start.elapsed() < Duration::from_secs(180), "ray start --head: not started ({exited:?}):\n{}", std::fs::read_to_string(&log).unwrap());
        std::thread::sleep(Duration::from_millis(100));
    };
    // The head names its session's port files after its node id.
    let session = dir.join("session_latest");
    let node = std::fs::read_dir(&session)
        .unwrap()
        .find_map(|e| e.unwrap().file_name().to_str()?.strip_prefix("gcs_server_port_").map(String::from))
        .unwrap_or_else(|| panic!("{}: no gcs_server_port_<node id>", session.display()));
    println!("ray: head node {node} at {address} ready after {:.1} s", start.elapsed().as_secs_f64());
    (head, address, node)
}

/// examples/ray/render.py twice: on a Ray cluster the test started (`RAY_ADDRESS`; 3 CPUs, one
/// task per shard), where the shards must have run as Ray tasks of that cluster (the head's node
/// id, worker processes other than the driver, at least two of them, each with its worker log in
/// the cluster's log directory), and on a local cluster the script starts and stops itself. Each
/// time the same files as one process.
#[test]
fn the_ray_example_renders_shards_as_ray_tasks() {
    let py = python_with(&["ray"]);
    let dir = tempfile::tempdir().unwrap();
    let (_, _, bundle) = bundle(dir.path());
    let one = dir.path().join("one");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--orbit", "--frames", "6", "--out", s(&one)]);
    assert!(ok, "{text}");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/ray/render.py");
    let token = ray_token();
    let render = |out: &Path, extra: &[&str]| {
        let mut cmd = Command::new(&py);
        cmd.arg(&script).args(["--bundle", s(&bundle), "--out", s(out), "--shards", "3", "--nerf-render", s(&nerf_render_bin())]);
        cmd.args(extra).args(["--", "--orbit", "--frames", "6"]).env("RAY_USAGE_STATS_ENABLED", "0").env_remove("RAY_ADDRESS");
        ray_auth(&mut cmd, &token);
        cmd
    };

    // Ray keeps Unix sockets under its temporary directory, and their paths may not exceed 107
    // bytes: short directories in /tmp, whatever TMPDIR says.
    let cluster = tempfile::Builder::new().prefix("ray").tempdir_in("/tmp").unwrap();
    let (mut head, address, node) = ray_head(&py, cluster.path(), 3, &token);
    let (out, log) = (dir.path().join("joined"), dir.path().join("joined.log"));
    // RAY_TMPDIR too, so that a script that started a cluster of its own would leave no /tmp/ray.
    let mut cmd = render(&out, &[]);
    cmd.env("RAY_ADDRESS", &address).env("RAY_TMPDIR", cluster.path());
    let mut driver = Group::spawn(logged(&mut cmd, &log));
    let ok = driver.wait(Duration::from_secs(300), "render.py on the test's cluster", &log);
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(ok, "{text}");
    let line = |prefix: &str| text.lines().find(|l| l.starts_with(prefix)).unwrap_or_else(|| panic!("no {prefix:?} line:\n{text}"));
    let joined = line("ray: joined the cluster at ");
    assert!(joined.starts_with(&format!("ray: joined the cluster at {address} (1 nodes, 3 CPUs), driver pid ")), "{joined}");
    let driver_pid: u32 = joined.rsplit(' ').next().unwrap().parse().unwrap();
    // "shard i/3 on HOST (node ID, worker pid PID) in …"
    let logs: Vec<String> = std::fs::read_dir(cluster.path().join("session_latest/logs")).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    let mut pids = Vec::new();
    for i in 0..3 {
        let shard = line(&format!("shard {i}/3 on "));
        let (_, rest) = shard.split_once(" (node ").unwrap_or_else(|| panic!("{shard}"));
        let (shard_node, rest) = rest.split_once(", worker pid ").unwrap_or_else(|| panic!("{shard}"));
        let pid: u32 = rest.split_once(')').unwrap().0.parse().unwrap();
        assert_eq!(shard_node, node, "shard {i}/3 ran on another node than the test's head: {shard}");
        assert_ne!(pid, driver_pid, "shard {i}/3 ran in the driver: {shard}");
        assert!(logs.iter().any(|f| f.starts_with("python-core-worker-") && f.ends_with(&format!("_{pid}.log"))), "worker {pid} has no log in the test cluster's logs: {logs:?}");
        pids.push(pid);
    }
    pids.sort();
    pids.dedup();
    assert!(pids.len() >= 2, "every shard ran in one worker ({pids:?}): no fan-out");
    assert!(text.contains("merged"), "{text}");
    let n = assert_same_files(&one, &out);
    assert_eq!(head.kill(), 0, "processes of the test's Ray cluster survived SIGKILL");
    println!("ray example on the test's cluster at {address}: 3 shards as Ray tasks in workers {pids:?} (driver {driver_pid}), merged = one process, {n} files");

    // Its own cluster, in a temporary directory of its own (RAY_TMPDIR), gone when it exits.
    let own = tempfile::Builder::new().prefix("ray").tempdir_in("/tmp").unwrap();
    let (out, log) = (dir.path().join("own"), dir.path().join("own.log"));
    let mut driver = Group::spawn(logged(render(&out, &["--num-cpus", "2"]).env("RAY_TMPDIR", own.path()), &log));
    let ok = driver.wait(Duration::from_secs(300), "render.py on its own cluster", &log);
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(ok, "{text}");
    assert!(text.lines().any(|l| l.starts_with("ray: started a local cluster at ") && l.contains("(1 nodes, 2 CPUs)")), "{text}");
    assert!(own.path().join("ray/session_latest").exists(), "no Ray session in RAY_TMPDIR:\n{text}");
    assert_eq!(driver.drained(Duration::from_secs(30)), 0, "the script's own Ray cluster outlived it by 30 s");
    let n = assert_same_files(&one, &out);
    println!("ray example on its own cluster: 3 shards + merge = one process, {n} files");
}
