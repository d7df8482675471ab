//! `nerf-render --export-site DIR`: the viewer and one bundle as a folder that any static host
//! serves, no server of ours. DIR holds exactly what `--serve` serves ([`Site`]: the viewer's
//! files, the bundle's `scene.json` and the files it names under `bundle/`), each at its request
//! path. A static host sends no cross-origin isolation headers, which onnxruntime-web's threads
//! need; the viewer's service worker ([`SERVICE_WORKER`]) adds them to the site's responses and
//! the page reloads once under it (docs/viewer.md).

use crate::error::{Result, RuntimeError};
use crate::serve::Site;
use nerf_core::io::atomic::write_dir_atomic;
use std::path::Path;

/// The viewer's service worker, at the site's root (its scope is the whole site).
pub const SERVICE_WORKER: &str = "isolation-sw.js";

/// What [`export_site`] wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Exported {
    /// Files written.
    pub files: usize,
    /// Their bytes.
    pub bytes: u64,
    /// Whether the viewer has [`SERVICE_WORKER`] (a viewer built before it runs one thread on
    /// a static host).
    pub service_worker: bool,
}

/// Writes `site`'s files into `dir`, each at its request path, all at once: into a temporary
/// sibling first, renamed into place when every file is there (a failure leaves no `dir`). A
/// `dir` that exists must be an empty folder: nothing is written over other files.
pub fn export_site(site: &Site, dir: &Path) -> Result<Exported> {
    check_target(dir)?;
    let files = site.files();
    let service_worker = files.iter().any(|(path, _)| path.strip_prefix('/') == Some(SERVICE_WORKER));
    let bytes = write_dir_atomic(dir, |tmp| {
        let mut bytes = 0;
        for (path, source) in &files {
            // Request paths are made of plain names (serve::plain), so this stays inside `tmp`.
            let target = tmp.join(path.trim_start_matches('/'));
            if let Some(parent) = target.parent() {
                std::fs::create_dir_all(parent).map_err(|e| nerf_core::Error::io(parent, e))?;
            }
            bytes += std::fs::copy(source, &target).map_err(|e| nerf_core::Error::io(source, e))?;
        }
        Ok(bytes)
    })?;
    Ok(Exported { files: files.len(), bytes, service_worker })
}

/// `dir` may be written: it does not exist, or it is an empty folder.
fn check_target(dir: &Path) -> Result<()> {
    let refuse = |problem: &str| Err(RuntimeError::bundle(dir, format!("{problem}: the site is written to a new or empty folder")));
    match std::fs::symlink_metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(nerf_core::Error::io(dir, e).into()),
        Ok(meta) if !meta.is_dir() => refuse("exists and is not a folder"),
        Ok(_) => match std::fs::read_dir(dir).map_err(|e| nerf_core::Error::io(dir, e))?.next() {
            None => Ok(()),
            Some(_) => refuse("exists and is not empty"),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A viewer (index.html, a nested asset, the service worker) and a bundle of one file.
    fn site(root: &Path) -> Site {
        let viewer = root.join("viewer");
        std::fs::create_dir_all(viewer.join("assets")).unwrap();
        std::fs::write(viewer.join("index.html"), "<!doctype html>").unwrap();
        std::fs::write(viewer.join("assets/app.js"), "export {};").unwrap();
        std::fs::write(viewer.join(SERVICE_WORKER), "// sw").unwrap();
        std::fs::write(root.join("scene.json"), "{}").unwrap();
        Site::new(&viewer, vec![("scene.json".into(), root.join("scene.json"))]).unwrap()
    }

    #[test]
    fn writes_each_served_file_at_its_path_and_refuses_a_folder_with_files() {
        let root = tempfile::tempdir().unwrap();
        let site = site(root.path());
        let out = root.path().join("out");
        let exported = export_site(&site, &out).unwrap();
        assert_eq!(exported, Exported { files: 4, bytes: 15 + 10 + 5 + 2, service_worker: true });
        assert_eq!(std::fs::read_to_string(out.join("assets/app.js")).unwrap(), "export {};");
        assert_eq!(std::fs::read_to_string(out.join("bundle/scene.json")).unwrap(), "{}");
        // Nothing beside `out` is left from the temporary folder.
        let names: Vec<_> = std::fs::read_dir(root.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names.len(), 3, "{names:?}");

        let err = export_site(&site, &out).unwrap_err().to_string();
        assert!(err.contains("exists and is not empty"), "{err}");
        let file = root.path().join("scene.json");
        let err = export_site(&site, &file).unwrap_err().to_string();
        assert!(err.contains("exists and is not a folder"), "{err}");
        // An empty folder is filled.
        let empty = root.path().join("empty");
        std::fs::create_dir(&empty).unwrap();
        assert_eq!(export_site(&site, &empty).unwrap().files, 4);
    }
}
