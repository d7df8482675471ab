//! Limits on what a file or an option may ask for, and the checks that enforce them.
//!
//! Bundles (`scene.json`, `occupancy.bin`), run directories (`config.toml`, `camera.json`,
//! `checkpoints/latest`) and command-line options come from other people. Every value that
//! sizes an allocation or a loop is checked here against a documented bound before anything is
//! allocated, and every file name read from a file must be a plain name inside its directory.
//! The bounds are far above anything a CPU renders in reasonable time; they exist so that a
//! wrong or hostile number gives an error at once instead of an out-of-memory kill or a render
//! that never ends. The Python package reads bundles within the same limits: its table,
//! `python/nerf_bundle/_limits.py`, is checked against these constants both ways
//! (`runtime/tests/cli.rs`, `python_limits_match_the_core`).

use crate::camera::PinholeCamera;
use crate::error::{Error, Result};
use crate::sample::stratified::SamplingConfig;
use std::path::{Component, Path, PathBuf};

/// Largest image side in pixels (width or height).
pub const MAX_IMAGE_SIDE: u32 = 16_384;
/// Most pixels in one frame: 4096² (a frame's outputs then take ≈ 320 MB as f32).
pub const MAX_FRAME_PIXELS: u64 = 4096 * 4096;
/// Most frames one command renders (orbit length, poses in `scene.json`).
pub const MAX_FRAMES: usize = 10_000;
/// Most samples per ray, coarse + fine (the paper uses 64 + 128).
pub const MAX_SAMPLES_PER_RAY: usize = 4096;
/// Most rays per network call (`--chunk`, `chunk` in `config.toml`).
pub const MAX_CHUNK: usize = 1 << 20;
/// Most points per network call: rays per call × samples per ray (the default 1024 × 192 is
/// ≈ 200k; the paper network's activations for 4M points are ≈ 4 GB per layer).
pub const MAX_POINTS_PER_CALL: usize = 1 << 22;
/// Most cells per axis of an occupancy grid: 512³ f32 cells are 512 MiB.
pub const MAX_GRID_RESOLUTION: usize = 512;
/// Most worker threads (`--threads`).
pub const MAX_THREADS: usize = 1024;
/// Largest JSON file read whole (`scene.json`, `camera.json`, `state.json`).
pub const MAX_JSON_BYTES: u64 = 64 << 20;
/// Largest network width (neurons per hidden layer).
pub const MAX_NETWORK_WIDTH: usize = 4096;
/// Most hidden layers in a network.
pub const MAX_NETWORK_DEPTH: usize = 64;
/// Most positional-encoding frequencies (2ᵏ overflows f32 long before k = 128).
pub const MAX_FREQUENCIES: usize = 64;
/// Most weights per network description (the paper network has 593,408): 256 MB of f32.
pub const MAX_NETWORK_WEIGHTS: usize = 1 << 26;

/// Where a checked value came from, so the error names it: a field of a file, or a
/// command-line option.
#[derive(Debug, Clone, Copy)]
pub enum Origin<'a> {
    /// `field` (dotted path, e.g. `camera.width`) of `file`.
    Field(&'a Path, &'a str),
    /// A command-line option such as `--width`.
    Option(&'a str),
    /// A key of a configuration not (yet) tied to a file; the caller prefixes the file.
    Key(&'a str),
}

impl Origin<'_> {
    /// The error for `problem` with this value.
    pub fn error(&self, problem: impl std::fmt::Display) -> Error {
        match self {
            Origin::Field(file, field) => Error::invalid(*file, format!("{field}: {problem}")),
            Origin::Option(name) | Origin::Key(name) => Error::Argument(format!("{name}: {problem}")),
        }
    }

    /// The error for `problem` with sub-field `name` (`camera` → `camera.focal`).
    fn sub_error(&self, name: &str, problem: impl std::fmt::Display) -> Error {
        match self {
            Origin::Field(file, field) => Error::invalid(*file, format!("{field}.{name}: {problem}")),
            Origin::Key(field) => Error::Argument(format!("{field}.{name}: {problem}")),
            Origin::Option(option) => Error::Argument(format!("{option}: {name}: {problem}")),
        }
    }
}

/// `value` must be in `1..=max`; `what` names the unit in the error (`frames`, `rays`).
pub fn check_count(value: usize, max: usize, what: &str, at: Origin) -> Result<()> {
    if value == 0 {
        return Err(at.error(format!("must be at least 1 (got 0 {what})")));
    }
    if value > max {
        return Err(at.error(format!("{value} {what} is more than the limit of {max}")));
    }
    Ok(())
}

/// An image size: both sides positive, at most [`MAX_IMAGE_SIDE`], at most
/// [`MAX_FRAME_PIXELS`] pixels in all.
pub fn check_image_size(width: u64, height: u64, at: Origin) -> Result<()> {
    if width == 0 || height == 0 {
        return Err(at.error(format!("{width}×{height} pixels: both sides must be positive")));
    }
    if width > MAX_IMAGE_SIDE as u64 || height > MAX_IMAGE_SIDE as u64 {
        return Err(at.error(format!("{width}×{height} pixels: a side is more than the limit of {MAX_IMAGE_SIDE}")));
    }
    if width * height > MAX_FRAME_PIXELS {
        return Err(at.error(format!("{width}×{height} pixels is more than the limit of {MAX_FRAME_PIXELS} pixels per frame")));
    }
    Ok(())
}

/// A camera: [`check_image_size`], finite positive focal lengths, a finite principal point
/// and finite distortion coefficients.
pub fn check_camera(c: &PinholeCamera, at: Origin) -> Result<()> {
    check_image_size(c.width as u64, c.height as u64, at)?;
    for (name, f) in [("fx", c.fx), ("fy", c.fy)] {
        if !(f.is_finite() && f > 0.0) {
            return Err(at.sub_error(name, format!("{f} is not a positive finite focal length")));
        }
    }
    for (name, v) in [("cx", c.cx), ("cy", c.cy)] {
        if !v.is_finite() {
            return Err(at.sub_error(name, format!("{v} is not a finite principal point")));
        }
    }
    if let Some(d) = c.distortion
        && ![d.k1, d.k2, d.p1, d.p2].iter().all(|v| v.is_finite())
    {
        return Err(at.sub_error("distortion", format!("{d:?} has a non-finite coefficient")));
    }
    Ok(())
}

/// Sampling: finite 0 < near < far (NDC rays: 0 ≤ near < far ≤ 1 and a projection with
/// positive finite values), at least one coarse sample, at most [`MAX_SAMPLES_PER_RAY`]
/// samples per ray in all.
pub fn check_sampling(s: &SamplingConfig, at: Origin) -> Result<()> {
    match &s.ndc {
        None if !(s.near.is_finite() && s.far.is_finite() && s.near > 0.0 && s.far > s.near) => {
            return Err(at.error(format!("need finite 0 < near < far, got near {} far {}", s.near, s.far)));
        }
        Some(_) if !(s.near >= 0.0 && s.far > s.near && s.far <= 1.0) => {
            return Err(at.error(format!("NDC rays need 0 <= near < far <= 1, got near {} far {}", s.near, s.far)));
        }
        Some(ndc) if !ndc.is_valid() => {
            return Err(at.sub_error("ndc", format!("{ndc:?} needs positive finite width, height, fx, fy and near")));
        }
        _ => {}
    }
    if s.n_coarse == 0 {
        return Err(at.sub_error("n_coarse", "must be at least 1"));
    }
    let total = s.n_coarse.saturating_add(s.n_fine);
    if total > MAX_SAMPLES_PER_RAY {
        return Err(at.error(format!(
            "n_coarse + n_fine = {total} samples per ray is more than the limit of {MAX_SAMPLES_PER_RAY}"
        )));
    }
    Ok(())
}

/// Rays per network call: at most [`MAX_CHUNK`], and with `samples_per_ray` at most
/// [`MAX_POINTS_PER_CALL`] points.
pub fn check_chunk(chunk: usize, samples_per_ray: usize, at: Origin) -> Result<()> {
    check_count(chunk, MAX_CHUNK, "rays", at)?;
    let points = chunk.saturating_mul(samples_per_ray.max(1));
    if points > MAX_POINTS_PER_CALL {
        return Err(at.error(format!(
            "{chunk} rays × {samples_per_ray} samples = {points} points per network call is more than the limit of {MAX_POINTS_PER_CALL}"
        )));
    }
    Ok(())
}

/// An occupancy grid's cells per axis: `1..=`[`MAX_GRID_RESOLUTION`].
pub fn check_grid_resolution(resolution: usize, at: Origin) -> Result<()> {
    check_count(resolution, MAX_GRID_RESOLUTION, "cells per axis", at)
}

/// A file name read from a file must name a file directly inside its directory: not empty,
/// not absolute, no `..` or `.`, no path separator, no NUL.
pub fn check_plain_file_name(name: &str, at: Origin) -> Result<()> {
    let plain = !name.is_empty()
        && !name.contains(['/', '\\', '\0'])
        && matches!(Path::new(name).components().collect::<Vec<_>>()[..], [Component::Normal(_)]);
    if !plain {
        return Err(at.error(format!("{name:?} is not a plain file name inside the directory (no paths, no \"..\")")));
    }
    Ok(())
}

/// `dir/name` for a `name` read from a file, after [`check_plain_file_name`]. When the entry
/// exists it must be a regular file (not a FIFO or device that would block or never end), and
/// if it is a symbolic link it must resolve to a file inside `dir`. A missing entry is left to
/// the reader, whose error names it.
pub fn file_in_dir(dir: &Path, name: &str, at: Origin) -> Result<PathBuf> {
    check_plain_file_name(name, at)?;
    let path = dir.join(name);
    let Ok(meta) = std::fs::symlink_metadata(&path) else { return Ok(path) };
    if meta.file_type().is_symlink() {
        let target = std::fs::canonicalize(&path).map_err(|e| Error::io(&path, e))?;
        let root = std::fs::canonicalize(dir).map_err(|e| Error::io(dir, e))?;
        if !target.starts_with(&root) {
            return Err(at.error(format!("{name:?} is a symbolic link to {}, outside {}", target.display(), dir.display())));
        }
    }
    if !std::fs::metadata(&path).is_ok_and(|m| m.is_file()) {
        return Err(at.error(format!("{name:?} is not a regular file")));
    }
    Ok(path)
}

/// Read a whole file of at most `max_bytes` (checked before reading), which must be a regular
/// file.
pub fn read_bounded(path: &Path, max_bytes: u64) -> Result<Vec<u8>> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(Error::invalid(path, "not a regular file"));
    }
    if meta.len() > max_bytes {
        return Err(Error::invalid(path, format!("{} bytes is more than the limit of {max_bytes} for this file", meta.len())));
    }
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

/// [`read_bounded`] with [`MAX_JSON_BYTES`], as text.
pub fn read_json_text(path: &Path) -> Result<String> {
    let bytes = read_bounded(path, MAX_JSON_BYTES)?;
    String::from_utf8(bytes).map_err(|e| Error::invalid(path, format!("not UTF-8 text: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(file: &Path) -> Origin<'_> {
        Origin::Field(file, "camera")
    }

    #[test]
    fn image_sizes() {
        let f = Path::new("scene.json");
        check_image_size(400, 400, at(f)).unwrap();
        check_image_size(16_384, 1024, at(f)).unwrap();
        let e = check_image_size(100_000_000, 100_000_000, at(f)).unwrap_err().to_string();
        assert!(e.starts_with("scene.json: camera: 100000000×100000000") && e.contains("16384"), "{e}");
        let e = check_image_size(16_384, 16_384, at(f)).unwrap_err().to_string();
        assert!(e.contains("16777216 pixels per frame"), "{e}");
        assert!(check_image_size(0, 5, at(f)).unwrap_err().to_string().contains("positive"));
        let k = crate::camera::Intrinsics { width: 4, height: 4, focal: 2.0 };
        let ok = PinholeCamera::from(k);
        check_camera(&ok, at(f)).unwrap();
        let e = check_camera(&PinholeCamera::from(crate::camera::Intrinsics { focal: f32::NAN, ..k }), at(f)).unwrap_err().to_string();
        assert!(e.starts_with("scene.json: camera.fx: NaN"), "{e}");
        let e = check_camera(&PinholeCamera { fy: -1.0, ..ok }, at(f)).unwrap_err().to_string();
        assert!(e.starts_with("scene.json: camera.fy: -1"), "{e}");
        let e = check_camera(&PinholeCamera { cy: f32::INFINITY, ..ok }, at(f)).unwrap_err().to_string();
        assert!(e.starts_with("scene.json: camera.cy: inf"), "{e}");
        let bad = crate::camera::OpenCvDistortion { k1: f32::NAN, k2: 0.0, p1: 0.0, p2: 0.0 };
        let e = check_camera(&PinholeCamera { distortion: Some(bad), ..ok }, at(f)).unwrap_err().to_string();
        assert!(e.starts_with("scene.json: camera.distortion"), "{e}");
        let e = check_image_size(0, 5, Origin::Option("--width")).unwrap_err().to_string();
        assert!(e.starts_with("--width: 0×5"), "{e}");
    }

    #[test]
    fn sampling_and_chunks() {
        let f = Path::new("config.toml");
        let at = Origin::Field(f, "sampling");
        check_sampling(&SamplingConfig::default(), at).unwrap();
        let s = SamplingConfig { n_coarse: 4000, n_fine: 97, ..Default::default() };
        assert!(check_sampling(&s, at).unwrap_err().to_string().contains("4097 samples per ray"));
        let s = SamplingConfig { n_coarse: usize::MAX, n_fine: usize::MAX, ..Default::default() };
        assert!(check_sampling(&s, at).is_err(), "no overflow");
        let s = SamplingConfig { n_coarse: 0, ..Default::default() };
        assert!(check_sampling(&s, at).unwrap_err().to_string().contains("sampling.n_coarse"));
        let s = SamplingConfig { far: f32::INFINITY, ..Default::default() };
        assert!(check_sampling(&s, at).unwrap_err().to_string().contains("near < far"));
        // NDC: near 0 is fine, far past 1 (infinity) or a broken projection is not.
        let ndc = crate::camera::ndc::Ndc::new(400, 300, 320.0, 1.0);
        check_sampling(&SamplingConfig { near: 0.0, far: 1.0, ndc: Some(ndc), ..Default::default() }, at).unwrap();
        let s = SamplingConfig { near: 0.0, far: 2.0, ndc: Some(ndc), ..Default::default() };
        assert!(check_sampling(&s, at).unwrap_err().to_string().contains("near < far <= 1"));
        let s = SamplingConfig { near: 0.0, far: 1.0, ndc: Some(crate::camera::ndc::Ndc { fx: f32::NAN, ..ndc }), ..Default::default() };
        assert!(check_sampling(&s, at).unwrap_err().to_string().contains("sampling.ndc"));
        check_chunk(1024, 192, Origin::Option("--chunk")).unwrap();
        // 21845 · 192 = 4,194,240 ≤ 2²² < 21846 · 192.
        check_chunk(21_845, 192, Origin::Option("--chunk")).unwrap();
        let e = check_chunk(21_846, 192, Origin::Option("--chunk")).unwrap_err().to_string();
        assert!(e.starts_with("--chunk: 21846 rays × 192 samples = 4194432 points"), "{e}");
        assert!(check_chunk(0, 192, Origin::Option("--chunk")).is_err());
        assert!(check_chunk(usize::MAX, usize::MAX, Origin::Option("--chunk")).is_err());
        check_grid_resolution(512, Origin::Key("occupancy.resolution")).unwrap();
        let e = check_grid_resolution(513, Origin::Key("occupancy.resolution")).unwrap_err().to_string();
        assert_eq!(e, "occupancy.resolution: 513 cells per axis is more than the limit of 512");
    }

    #[test]
    fn plain_names() {
        let f = Path::new("scene.json");
        let at = Origin::Field(f, "networks.coarse");
        for ok in ["coarse.onnx", "a..b", ".hidden", "step-0000010"] {
            check_plain_file_name(ok, at).unwrap();
        }
        for bad in ["", ".", "..", "/etc/hostname", "../x.onnx", "a/b", "a\\b", "a\0b", "./a"] {
            let e = check_plain_file_name(bad, at).unwrap_err().to_string();
            assert!(e.starts_with("scene.json: networks.coarse: ") && e.contains("not a plain file name"), "{bad:?}: {e}");
        }
    }

    #[cfg(unix)]
    #[test]
    fn files_in_a_directory() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("bundle");
        std::fs::create_dir(&dir).unwrap();
        std::fs::write(dir.join("coarse.onnx"), b"x").unwrap();
        std::fs::write(tmp.path().join("outside"), b"x").unwrap();
        let f = dir.join("scene.json");
        let at = Origin::Field(&f, "networks.coarse");
        assert_eq!(file_in_dir(&dir, "coarse.onnx", at).unwrap(), dir.join("coarse.onnx"));
        assert_eq!(file_in_dir(&dir, "missing.onnx", at).unwrap(), dir.join("missing.onnx"));
        std::os::unix::fs::symlink("coarse.onnx", dir.join("inside-link")).unwrap();
        file_in_dir(&dir, "inside-link", at).unwrap();
        std::os::unix::fs::symlink(tmp.path().join("outside"), dir.join("outside-link")).unwrap();
        let e = file_in_dir(&dir, "outside-link", at).unwrap_err().to_string();
        assert!(e.contains("symbolic link") && e.contains("outside"), "{e}");
        std::os::unix::fs::symlink("/dev/zero", dir.join("zero")).unwrap();
        assert!(file_in_dir(&dir, "zero", at).is_err());
        std::fs::create_dir(dir.join("sub")).unwrap();
        assert!(file_in_dir(&dir, "sub", at).unwrap_err().to_string().contains("not a regular file"));
        let big = dir.join("big.json");
        std::fs::write(&big, vec![b' '; 100]).unwrap();
        assert!(read_bounded(&big, 99).unwrap_err().to_string().contains("100 bytes is more than the limit of 99"));
        assert_eq!(read_bounded(&big, 100).unwrap().len(), 100);
        assert!(read_bounded(Path::new("/dev/zero"), 10).unwrap_err().to_string().contains("not a regular file"));
    }
}
