//! The core's error type: every failure names the file (or field) and the problem.

use std::path::PathBuf;

/// A failure of the NeRF core, with the file it concerns where there is one.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A JSON file is malformed or lacks a field.
    #[error("{path}: invalid JSON: {source}")]
    Json {
        /// The file.
        path: PathBuf,
        /// What serde said (with line and column).
        #[source]
        source: serde_json::Error,
    },
    /// An image could not be decoded or encoded.
    #[error("{path}: {source}")]
    Image {
        /// The file.
        path: PathBuf,
        /// The image crate's error.
        #[source]
        source: image::ImageError,
    },
    /// The content of a file is readable but wrong (a non-finite pose, mismatched sizes...).
    #[error("{path}: {problem}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        problem: String,
    },
    /// An argument is out of range (not tied to a file).
    #[error("{0}")]
    Argument(String),
}

/// `Result` with the core's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io { path: path.into(), source }
    }
    /// A content problem in `path`.
    pub fn invalid(path: impl Into<PathBuf>, problem: impl Into<String>) -> Self {
        Error::Invalid { path: path.into(), problem: problem.into() }
    }
}

/// Writes `bytes` to `path` through a temporary file in the same directory and a rename, so a
/// reader never sees a half-written file.
pub fn write_atomic(path: &std::path::Path, bytes: &[u8]) -> Result<()> {
    let tmp = temp_sibling(path);
    write_synced(&tmp, bytes)?;
    std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
}

/// Writes `bytes` to a new file `path` and flushes them to the disk before returning, so that a
/// rename that publishes the file after this can never expose it empty after a power cut.
pub fn write_synced(path: &std::path::Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let mut file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    file.write_all(bytes).and_then(|()| file.sync_all()).map_err(|e| Error::io(path, e))
}

/// Flushes a directory's entries (renames into it, new files) to the disk; best effort, as some
/// filesystems cannot sync a directory.
pub fn sync_dir(dir: &std::path::Path) {
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

/// Swaps the directory entries `a` and `b` in one atomic step (Linux `renameat2` with
/// `RENAME_EXCHANGE`): a reader sees one or the other at each name, never neither. `Ok(false)`
/// where the system or filesystem cannot exchange (the caller then renames twice).
pub fn exchange_paths(a: &std::path::Path, b: &std::path::Path) -> Result<bool> {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::ffi::OsStrExt;
        let c_path = |p: &std::path::Path| {
            std::ffi::CString::new(p.as_os_str().as_bytes())
                .map_err(|e| Error::io(p, std::io::Error::new(std::io::ErrorKind::InvalidInput, e)))
        };
        let (ca, cb) = (c_path(a)?, c_path(b)?);
        // SAFETY: both arguments are valid NUL-terminated paths that outlive the call.
        let r = unsafe { libc::renameat2(libc::AT_FDCWD, ca.as_ptr(), libc::AT_FDCWD, cb.as_ptr(), libc::RENAME_EXCHANGE) };
        if r == 0 {
            return Ok(true);
        }
        let e = std::io::Error::last_os_error();
        if matches!(e.raw_os_error(), Some(libc::EINVAL | libc::ENOSYS | libc::EOPNOTSUPP)) {
            return Ok(false);
        }
        Err(Error::io(b, e))
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = (a, b);
        Ok(false)
    }
}

/// `dir/.name.tmp-<pid>` beside `path`: same filesystem, so the final rename is atomic.
pub fn temp_sibling(path: &std::path::Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exchange_swaps_two_directories() {
        let tmp = tempfile::tempdir().unwrap();
        let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
        std::fs::create_dir(&a).unwrap();
        std::fs::create_dir(&b).unwrap();
        write_atomic(&a.join("f"), b"old").unwrap();
        write_synced(&b.join("f"), b"new").unwrap();
        if exchange_paths(&a, &b).unwrap() {
            assert_eq!(std::fs::read(a.join("f")).unwrap(), b"new");
            assert_eq!(std::fs::read(b.join("f")).unwrap(), b"old");
        }
        assert!(exchange_paths(&a, &tmp.path().join("missing")).is_err(), "a missing side is an error");
        let names: Vec<_> = std::fs::read_dir(&a).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names.len(), 1, "no temporary file left: {names:?}");
    }
}
