//! The external tools of `nerf process-data`: COLMAP (features, matching, incremental mapping,
//! run headless on the CPU) and ffmpeg (frames from a video). Each stage's log goes to a file,
//! with a spinner while it runs; a missing tool is named with how to install it.

use crate::error::{Error, Result};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// COLMAP's feature matchers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Matcher {
    /// Every pair of images: best for photos (quadratic in their number).
    Exhaustive,
    /// Each image with its neighbours in name order: videos.
    Sequential,
}

/// Camera models COLMAP estimates (one shared camera) that `process-data` converts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ColmapCamera {
    /// fx, fy, cx, cy, k1, k2, p1, p2 (the default: phones and most cameras).
    Opencv,
    /// fx, fy, cx, cy: undistorted images.
    Pinhole,
    /// f, cx, cy, k.
    SimpleRadial,
}

impl ColmapCamera {
    fn name(self) -> &'static str {
        match self {
            ColmapCamera::Opencv => "OPENCV",
            ColmapCamera::Pinhole => "PINHOLE",
            ColmapCamera::SimpleRadial => "SIMPLE_RADIAL",
        }
    }
}

const INSTALL_COLMAP: &str = "install COLMAP (Debian/Ubuntu: `apt-get install colmap`; others: https://colmap.github.io/install.html)";
const INSTALL_FFMPEG: &str = "install ffmpeg (Debian/Ubuntu: `apt-get install ffmpeg`)";

/// Run `program args` with its output in `log`, showing `stage` with a spinner; an error
/// quotes the end of the log.
fn stage(program: &str, args: &[&std::ffi::OsStr], log: &Path, what: &str, install: &str, progress: bool) -> Result<()> {
    let file = std::fs::File::create(log).map_err(|e| nerf_core::Error::io(log, e))?;
    let bar = if progress { ProgressBar::new_spinner() } else { ProgressBar::hidden() };
    bar.set_style(ProgressStyle::with_template("{spinner} {msg} {elapsed}").expect("a valid template"));
    bar.set_message(what.to_string());
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let status = Command::new(program)
        .args(args)
        .env("QT_QPA_PLATFORM", "offscreen")
        .stdin(Stdio::null())
        .stdout(file.try_clone().map_err(|e| nerf_core::Error::io(log, e))?)
        .stderr(file)
        .status();
    bar.finish_and_clear();
    let status = status.map_err(|e| Error::External {
        program: program.into(),
        problem: if e.kind() == std::io::ErrorKind::NotFound { format!("not found: {install}") } else { e.to_string() },
    })?;
    if !status.success() {
        let text = std::fs::read_to_string(log).unwrap_or_default();
        let tail: Vec<&str> = text.lines().rev().take(8).collect();
        let tail: Vec<&str> = tail.into_iter().rev().collect();
        return Err(Error::External { program: program.into(), problem: format!("{what} failed ({status}); the end of {}:\n{}", log.display(), tail.join("\n")) });
    }
    if progress {
        eprintln!("{what}: done");
    }
    Ok(())
}

/// Run COLMAP on `images` in `work` (database, logs, `sparse/N`); returns the sparse folder.
pub fn run_colmap(images: &Path, work: &Path, camera: ColmapCamera, matcher: Matcher, progress: bool) -> Result<PathBuf> {
    let db = work.join("database.db");
    let sparse = work.join("sparse");
    std::fs::create_dir_all(&sparse).map_err(|e| nerf_core::Error::io(&sparse, e))?;
    let os = |s: &str| std::ffi::OsString::from(s);
    let path = |p: &Path| p.as_os_str().to_os_string();
    let extract = [os("feature_extractor"), os("--database_path"), path(&db), os("--image_path"), path(images), os("--ImageReader.single_camera"), os("1"), os("--ImageReader.camera_model"), os(camera.name()), os("--SiftExtraction.use_gpu"), os("0")];
    let matching = match matcher {
        Matcher::Exhaustive => os("exhaustive_matcher"),
        Matcher::Sequential => os("sequential_matcher"),
    };
    let matching = [matching, os("--database_path"), path(&db), os("--SiftMatching.use_gpu"), os("0")];
    let map = [os("mapper"), os("--database_path"), path(&db), os("--image_path"), path(images), os("--output_path"), path(&sparse)];
    for (args, log, what) in [(&extract[..], "1-features.log", "COLMAP: features"), (&matching[..], "2-matching.log", "COLMAP: matching"), (&map[..], "3-mapping.log", "COLMAP: mapping")] {
        let args: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
        stage("colmap", &args, &work.join(log), what, INSTALL_COLMAP, progress)?;
    }
    Ok(sparse)
}

/// About `count` frames picked evenly over `video`, as JPEGs in `out` (ffmpeg).
pub fn extract_frames(video: &Path, count: usize, out: &Path, work: &Path, progress: bool) -> Result<()> {
    if !video.is_file() {
        return Err(nerf_core::Error::invalid(video, "no such video file").into());
    }
    std::fs::create_dir_all(out).map_err(|e| nerf_core::Error::io(out, e))?;
    let probe = Command::new("ffprobe")
        .args(["-v", "error", "-show_entries", "format=duration", "-of", "default=noprint_wrappers=1:nokey=1"])
        .arg(video)
        .output()
        .map_err(|e| Error::External { program: "ffprobe".into(), problem: if e.kind() == std::io::ErrorKind::NotFound { format!("not found: {INSTALL_FFMPEG}") } else { e.to_string() } })?;
    let duration: f64 = String::from_utf8_lossy(&probe.stdout).trim().parse().ok().filter(|d: &f64| d.is_finite() && *d > 0.0).ok_or_else(|| {
        nerf_core::Error::invalid(video, format!("ffprobe cannot read a duration: not a video ffmpeg reads? {}", String::from_utf8_lossy(&probe.stderr).trim()))
    })?;
    let fps = format!("fps={:.6}", count.max(1) as f64 / duration);
    let pattern = out.join("frame_%05d.jpg");
    let args = [std::ffi::OsStr::new("-nostdin"), "-i".as_ref(), video.as_os_str(), "-vf".as_ref(), fps.as_ref(), "-q:v".as_ref(), "2".as_ref(), pattern.as_os_str()];
    stage("ffmpeg", &args, &work.join("0-frames.log"), "ffmpeg: frames", INSTALL_FFMPEG, progress)
}
