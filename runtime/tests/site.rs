//! `nerf-render --export-site DIR`: the folder holds exactly what `--serve` serves (the viewer's
//! files, `scene.json` and the files it names under `bundle/`, byte for byte), and nothing is
//! written for a DIR that exists with files in it, a folder that is not a loadable bundle or a
//! missing viewer, each refused with a clear error naming the folder.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// `nerf-render --bundle B --export-site DIR --viewer V`.
fn export(bundle: &Path, dir: &Path, viewer: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nerf-render"))
        .args(["--bundle", bundle.to_str().unwrap(), "--export-site", dir.to_str().unwrap(), "--viewer", viewer.to_str().unwrap()])
        .output()
        .expect("run nerf-render")
}

/// A viewer (with its service worker, a hidden file and a link, neither exported) and a copy
/// of models/spheres with files scene.json does not name.
fn fixtures(root: &Path) -> (PathBuf, PathBuf) {
    let viewer = root.join("viewer");
    std::fs::create_dir_all(viewer.join("assets")).unwrap();
    std::fs::write(viewer.join("index.html"), "<!doctype html><title>viewer</title>").unwrap();
    std::fs::write(viewer.join("isolation-sw.js"), "// sw").unwrap();
    std::fs::write(viewer.join("assets/app.js"), "export {};").unwrap();
    std::fs::write(viewer.join(".hidden"), "secret").unwrap();
    std::os::unix::fs::symlink(Path::new(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml"), viewer.join("link.txt")).unwrap();
    let bundle = root.join("bundle");
    std::fs::create_dir_all(&bundle).unwrap();
    for entry in std::fs::read_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/spheres")).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), bundle.join(entry.file_name())).unwrap();
    }
    std::fs::write(bundle.join("notes.txt"), "not exported").unwrap();
    (viewer, bundle)
}

/// Every file below `dir`, as relative paths, sorted.
fn tree(dir: &Path) -> Vec<String> {
    fn walk(dir: &Path, prefix: &str, out: &mut Vec<String>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let entry = entry.unwrap();
            let name = format!("{prefix}{}", entry.file_name().to_string_lossy());
            if entry.file_type().unwrap().is_dir() {
                walk(&entry.path(), &format!("{name}/"), out);
            } else {
                out.push(name);
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, "", &mut out);
    out.sort();
    out
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn writes_the_viewer_and_exactly_the_bundles_files() {
    let root = tempfile::tempdir().unwrap();
    let (viewer, bundle) = fixtures(root.path());
    let site = root.path().join("out/site");
    let out = export(&bundle, &site, &viewer);
    assert!(out.status.success(), "{}", stderr(&out));
    let expected = ["assets/app.js", "bundle/coarse.onnx", "bundle/fine.onnx", "bundle/occupancy.bin", "bundle/scene.json", "index.html", "isolation-sw.js"];
    assert_eq!(tree(&site), expected);
    for name in expected {
        let source = name.strip_prefix("bundle/").map_or_else(|| viewer.join(name), |b| bundle.join(b));
        assert!(std::fs::read(site.join(name)).unwrap() == std::fs::read(&source).unwrap(), "{name} differs from {}", source.display());
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("7 files") && stdout.contains("http.server"), "{stdout}");
    assert!(!stderr(&out).contains("warning"), "{}", stderr(&out));
    // No temporary folder left beside it.
    assert_eq!(tree(&root.path().join("out")), expected.map(|n| format!("site/{n}")));

    // An empty folder is filled; a viewer without the service worker is exported with a warning.
    std::fs::remove_file(viewer.join("isolation-sw.js")).unwrap();
    let empty = root.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let out = export(&bundle, &empty, &viewer);
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(tree(&empty).len(), expected.len() - 1);
    assert!(stderr(&out).contains("no isolation-sw.js") && stderr(&out).contains("one thread"), "{}", stderr(&out));
}

#[test]
fn refuses_a_folder_with_files_a_bad_bundle_and_a_missing_viewer_writing_nothing() {
    let root = tempfile::tempdir().unwrap();
    let (viewer, bundle) = fixtures(root.path());

    // DIR with a file in it: refused, the file untouched, nothing added.
    let taken = root.path().join("taken");
    std::fs::create_dir(&taken).unwrap();
    std::fs::write(taken.join("keep.txt"), "mine").unwrap();
    let out = export(&bundle, &taken, &viewer);
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(err.contains(&format!("{}: exists and is not empty", taken.display())), "{err}");
    assert_eq!(tree(&taken), ["keep.txt"]);
    assert_eq!(std::fs::read_to_string(taken.join("keep.txt")).unwrap(), "mine");
    // A file where the folder would go.
    let out = export(&bundle, &taken.join("keep.txt"), &viewer);
    assert!(stderr(&out).contains("exists and is not a folder"), "{}", stderr(&out));
    assert_eq!(std::fs::read_to_string(taken.join("keep.txt")).unwrap(), "mine");

    let site = root.path().join("site");
    // Not a bundle: a folder without scene.json, a bundle missing a graph, no such folder.
    let plain = root.path().join("plain");
    std::fs::create_dir(&plain).unwrap();
    std::fs::write(plain.join("notes.txt"), "hello").unwrap();
    let broken = root.path().join("broken");
    std::fs::create_dir(&broken).unwrap();
    for name in ["scene.json", "coarse.onnx", "occupancy.bin"] {
        std::fs::copy(bundle.join(name), broken.join(name)).unwrap();
    }
    for (folder, why) in [(&plain, "scene.json"), (&broken, "fine.onnx"), (&root.path().join("nowhere"), "no such bundle directory")] {
        let out = export(folder, &site, &viewer);
        assert!(!out.status.success(), "{}", folder.display());
        let err = stderr(&out);
        assert!(err.contains(&folder.display().to_string()) && err.contains(why), "{err}");
        assert!(!err.contains("panicked"), "{err}");
        assert!(!site.exists(), "{} written for {}", site.display(), folder.display());
    }

    // No viewer there.
    let out = export(&bundle, &site, &root.path().join("no-viewer"));
    assert!(stderr(&out).contains("no viewer at") && stderr(&out).contains("scripts/setup.sh"), "{}", stderr(&out));
    assert!(!site.exists());
    // Nothing but what the test made.
    let mut names: Vec<_> = std::fs::read_dir(root.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    assert_eq!(names, ["broken", "bundle", "plain", "taken", "viewer"]);
}
