//! Writing files and directories so that a reader never sees them half-written, even if the
//! writer is killed (SIGKILL) at any moment: everything goes to a temporary sibling on the same
//! filesystem first, is flushed to disk, and is then renamed (a file) or swapped (a directory)
//! into place. Checkpoints, scene bundles, run files and frames all go through here.

use crate::error::{Error, Result};
use std::fs::File;
use std::path::{Path, PathBuf};

/// Writes `bytes` to `path` through a temporary file in the same directory and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = temp_sibling(path, "tmp");
    let written = std::fs::write(&tmp, bytes).and_then(|_| File::open(&tmp)?.sync_all());
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::io(&tmp, e));
    }
    std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
}

/// Writes `path` through a temporary file in the same directory and a rename, streaming: `fill`
/// writes the content. If `fill` fails, nothing is left behind and `path` is untouched.
pub fn write_atomic_with(path: &Path, fill: impl FnOnce(&mut std::io::BufWriter<File>) -> std::io::Result<()>) -> Result<()> {
    let tmp = temp_sibling(path, "tmp");
    let written = File::create(&tmp).and_then(|file| {
        let mut out = std::io::BufWriter::new(file);
        fill(&mut out)?;
        out.into_inner().map_err(|e| e.into_error())?.sync_all()
    });
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::io(&tmp, e));
    }
    std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
}

/// Creates the directory `dir` (replacing an existing one) in one atomic step: `fill` writes
/// the new content into a temporary sibling directory, which is then swapped with `dir`
/// (`renameat2(RENAME_EXCHANGE)`, or two renames where the filesystem lacks it) and the old
/// content removed. Readers of `dir` see the old directory or the new one, never a mix; if
/// `fill` fails, `dir` is untouched. Leftovers of writers that were killed are cleaned up first
/// (and a directory caught between the two fallback renames is put back).
pub fn write_dir_atomic<T>(dir: &Path, fill: impl FnOnce(&Path) -> Result<T>) -> Result<T> {
    let parent = parent_of(dir);
    std::fs::create_dir_all(&parent).map_err(|e| Error::io(&parent, e))?;
    recover_dir(dir)?;
    let tmp = temp_sibling(dir, "tmp");
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).map_err(|e| Error::io(&tmp, e))?;
    let filled = fill(&tmp).and_then(|value| sync_dir_tree(&tmp).map(|_| value));
    let value = match filled {
        Ok(value) => value,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    if dir.exists() {
        if exchange(&tmp, dir).is_ok() {
            // `tmp` now holds the old content.
            let _ = std::fs::remove_dir_all(&tmp);
        } else {
            let old = temp_sibling(dir, "old");
            std::fs::rename(dir, &old).map_err(|e| Error::io(dir, e))?;
            std::fs::rename(&tmp, dir).map_err(|e| Error::io(dir, e))?;
            let _ = std::fs::remove_dir_all(&old);
        }
    } else {
        std::fs::rename(&tmp, dir).map_err(|e| Error::io(dir, e))?;
    }
    sync_dir(&parent);
    Ok(value)
}

/// `dir/.name.<kind>-<pid>` beside `path`: same filesystem, so the final rename is atomic.
/// With `kind` ending in `tmp` (`parts.tmp`), [`remove_stale_temporaries`] knows it.
pub fn temp_sibling(path: &Path, kind: &str) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.{kind}-{}", std::process::id()))
}

fn parent_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// The writer process a temporary sibling `.name.<kind>-<pid>` belongs to, if `file_name` is
/// one: `(name, kind, pid)`.
fn temporary_owner(file_name: &str) -> Option<(&str, &str, u32)> {
    let rest = file_name.strip_prefix('.')?;
    let (stem, pid) = rest.rsplit_once('-')?;
    let (name, kind) = stem.rsplit_once('.')?;
    let pid = pid.parse().ok()?;
    matches!(kind, "tmp" | "old").then_some((name, kind, pid))
}

/// Whether process `pid` is gone (so what it was writing will never be finished).
fn writer_is_gone(pid: u32) -> bool {
    pid != std::process::id() && !Path::new(&format!("/proc/{pid}")).exists()
}

/// Remove every temporary sibling in `dir` (`.name.tmp-<pid>`, `.name.old-<pid>`, files or
/// directories) whose writer process is gone: what writers that were killed left behind.
pub fn remove_stale_temporaries(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let file_name = entry.file_name().to_string_lossy().into_owned();
        if temporary_owner(&file_name).is_some_and(|(_, _, pid)| writer_is_gone(pid)) {
            let path = entry.path();
            let _ = if path.is_dir() { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) };
        }
    }
}

/// Clean up after writers of `dir` that died: if one died between the fallback's two renames
/// (`dir` missing, `.name.old-<pid>` present), put the old directory back; then remove the
/// stale temporaries.
fn recover_dir(dir: &Path) -> Result<()> {
    let parent = parent_of(dir);
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    if !dir.exists() {
        let entries = std::fs::read_dir(&parent).map_err(|e| Error::io(&parent, e))?;
        for entry in entries.flatten() {
            let file_name = entry.file_name().to_string_lossy().into_owned();
            if temporary_owner(&file_name).is_some_and(|(n, kind, pid)| n == name && kind == "old" && writer_is_gone(pid)) {
                std::fs::rename(entry.path(), dir).map_err(|e| Error::io(dir, e))?;
                break;
            }
        }
    }
    remove_stale_temporaries(&parent);
    Ok(())
}

/// Atomically swap two directories (Linux `renameat2` with `RENAME_EXCHANGE`).
#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;
    let c = |p: &Path| CString::new(p.as_os_str().as_bytes()).map_err(|_| std::io::Error::from(std::io::ErrorKind::InvalidInput));
    let (a, b) = (c(a)?, c(b)?);
    // SAFETY: both paths are valid NUL-terminated strings; AT_FDCWD resolves them relative to
    // the working directory like rename(2).
    let rc = unsafe { libc::renameat2(libc::AT_FDCWD, a.as_ptr(), libc::AT_FDCWD, b.as_ptr(), libc::RENAME_EXCHANGE) };
    if rc == 0 { Ok(()) } else { Err(std::io::Error::last_os_error()) }
}

#[cfg(not(target_os = "linux"))]
fn exchange(_: &Path, _: &Path) -> std::io::Result<()> {
    Err(std::io::Error::from(std::io::ErrorKind::Unsupported))
}

/// Flush every file directly in `dir`, then `dir` itself.
fn sync_dir_tree(dir: &Path) -> Result<()> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_file() {
            File::open(&path).and_then(|f| f.sync_all()).map_err(|e| Error::io(&path, e))?;
        }
    }
    sync_dir(dir);
    Ok(())
}

/// Flush a directory's entries (best effort: not every filesystem allows it).
fn sync_dir(dir: &Path) {
    if let Ok(f) = File::open(dir) {
        let _ = f.sync_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_directory_is_replaced_whole_or_not_at_all() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("bundle");
        write_dir_atomic(&dir, |tmp| {
            std::fs::write(tmp.join("a"), b"old a").unwrap();
            std::fs::write(tmp.join("b"), b"old b").unwrap();
            Ok(())
        })
        .unwrap();
        // A failing writer leaves the old directory as it was and no temporary behind.
        let err = write_dir_atomic(&dir, |tmp| {
            std::fs::write(tmp.join("a"), b"new a").unwrap();
            Err::<(), _>(Error::Argument("disk full".into()))
        });
        assert!(err.is_err());
        assert_eq!(std::fs::read(dir.join("a")).unwrap(), b"old a");
        let names = |p: &Path| {
            let mut v: Vec<String> = std::fs::read_dir(p).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
            v.sort();
            v
        };
        assert_eq!(names(root.path()), vec!["bundle"]);
        // A successful one replaces every file, and drops the ones it does not write.
        let n = write_dir_atomic(&dir, |tmp| {
            std::fs::write(tmp.join("a"), b"new a").unwrap();
            Ok(7)
        })
        .unwrap();
        assert_eq!(n, 7);
        assert_eq!(names(&dir), vec!["a"]);
        assert_eq!(std::fs::read(dir.join("a")).unwrap(), b"new a");
        assert_eq!(names(root.path()), vec!["bundle"]);
    }

    #[test]
    fn leftovers_of_a_killed_writer_are_cleaned_and_a_half_swap_is_undone() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("run");
        // PID 0 never names a live writer here: both look like a writer killed between the
        // fallback's renames (old content moved aside, new content not yet in place).
        std::fs::create_dir_all(root.path().join(".run.old-0")).unwrap();
        std::fs::write(root.path().join(".run.old-0/x"), b"kept").unwrap();
        std::fs::create_dir_all(root.path().join(".run.tmp-0")).unwrap();
        recover_dir(&dir).unwrap();
        assert_eq!(std::fs::read(dir.join("x")).unwrap(), b"kept");
        assert!(!root.path().join(".run.tmp-0").exists());
    }

    #[test]
    fn temporary_names_and_their_writers() {
        assert_eq!(temporary_owner(".step-0000010.tmp-4242"), Some(("step-0000010", "tmp", 4242)));
        assert_eq!(temporary_owner(".latest.tmp-7"), Some(("latest", "tmp", 7)));
        assert_eq!(temporary_owner(".lego.old-12"), Some(("lego", "old", 12)));
        assert_eq!(temporary_owner("step-0000010"), None);
        assert_eq!(temporary_owner(".hidden.txt"), None);
        assert!(!writer_is_gone(std::process::id()), "this process is alive");
        let root = tempfile::tempdir().unwrap();
        std::fs::write(root.path().join(".latest.tmp-0"), b"step-0000001").unwrap();
        std::fs::write(root.path().join(format!(".mine.tmp-{}", std::process::id())), b"").unwrap();
        remove_stale_temporaries(root.path());
        let left: Vec<_> = std::fs::read_dir(root.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(left.len(), 1, "only the live writer's file stays: {left:?}");
    }

    #[test]
    fn a_streamed_file_is_written_whole_or_not_at_all() {
        use std::io::Write;
        let root = tempfile::tempdir().unwrap();
        let path = root.path().join("mesh.ply");
        write_atomic_with(&path, |out| out.write_all(b"ply\n")).unwrap();
        let err = write_atomic_with(&path, |out| {
            out.write_all(b"half")?;
            Err(std::io::Error::other("disk full"))
        })
        .unwrap_err();
        assert!(err.to_string().contains("disk full"), "{err}");
        assert_eq!(std::fs::read(&path).unwrap(), b"ply\n");
        assert_eq!(std::fs::read_dir(root.path()).unwrap().count(), 1, "no temporary left");
    }

    #[test]
    fn files_are_written_whole() {
        let root = tempfile::tempdir().unwrap();
        let path = root.path().join("f.json");
        write_atomic(&path, b"{}").unwrap();
        write_atomic(&path, b"{\"a\": 1}").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"{\"a\": 1}");
        assert_eq!(std::fs::read_dir(root.path()).unwrap().count(), 1);
    }
}
