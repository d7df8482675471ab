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
    /// Each image with those a vocabulary tree (`--vocab-tree FILE`) finds most similar:
    /// hundreds of photos and more, where exhaustive matching is too slow.
    VocabTree,
}

/// How COLMAP runs.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapOptions {
    /// The camera model, one camera shared by all images.
    pub camera: ColmapCamera,
    /// The matcher.
    pub matcher: Matcher,
    /// COLMAP's vocabulary tree file, for [`Matcher::VocabTree`].
    pub vocab_tree: Option<PathBuf>,
}

impl ColmapOptions {
    /// The matcher's arguments to `colmap`, or an error when the vocabulary tree is missing.
    fn matching_args(&self) -> Result<Vec<std::ffi::OsString>> {
        let os = std::ffi::OsString::from;
        Ok(match self.matcher {
            Matcher::Exhaustive => vec![os("exhaustive_matcher")],
            Matcher::Sequential => vec![os("sequential_matcher")],
            Matcher::VocabTree => {
                let Some(tree) = &self.vocab_tree else {
                    return Err(Error::Config(format!("--matcher vocab-tree needs --vocab-tree FILE: {GET_VOCAB_TREE}")));
                };
                if !tree.is_file() {
                    return Err(nerf_core::Error::invalid(tree, format!("no such vocabulary tree file: {GET_VOCAB_TREE}")).into());
                }
                vec![os("vocab_tree_matcher"), os("--VocabTreeMatching.vocab_tree_path"), tree.as_os_str().to_os_string()]
            }
        })
    }
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
const GET_VOCAB_TREE: &str = "COLMAP's trees are at https://demuc.de/colmap/#download (vocab_tree_flickr100K_words32K.bin suits up to a few thousand images), or build one from a database of your own photos with `colmap vocab_tree_builder`";
const INSTALL_FFMPEG: &str = "install ffmpeg (Debian/Ubuntu: `apt-get install ffmpeg`)";

/// How far a stage is, read from a line of its log: COLMAP's `Processed file [i/n]`,
/// `Matching image [i/n]`, `Matching block [i/n, j/m]`, the mapper's `Registering image #id
/// (k)` (k images registered, of `images`), ffmpeg's `frame= k` (of `images` frames).
///
/// Example: `Matching block [2/3, 1/3]` → (4, 9); with 45 images, `Registering image #7 (12)`
/// → (12, 45).
pub fn progress_of(line: &str, images: u64) -> Option<(u64, u64)> {
    let fraction = |s: &str| -> Option<(u64, u64)> {
        let (a, b) = s.split_once('/')?;
        Some((a.trim().parse().ok()?, b.trim().parse().ok()?))
    };
    let line = line.trim();
    if let Some(rest) = line.strip_prefix("Matching block [") {
        let (outer, inner) = rest.split_once(']')?.0.split_once(',')?;
        let ((i, n), (j, m)) = (fraction(outer)?, fraction(inner)?);
        return Some(((i.max(1) - 1) * m + j, n * m));
    }
    if let Some(rest) = line.strip_prefix("Processed file [").or_else(|| line.strip_prefix("Matching image [")) {
        return fraction(rest.split_once(']')?.0);
    }
    if line.starts_with("Registering image #") {
        let k = line.rsplit_once('(')?.1.strip_suffix(')')?.parse().ok()?;
        return Some((k, images));
    }
    let k = line.strip_prefix("frame=")?.split_whitespace().next()?.parse().ok()?;
    Some((k, images))
}

/// The bytes of `path` from `offset` on (`None` if it cannot be read).
fn bytes_from(path: &Path, offset: usize) -> Option<Vec<u8>> {
    use std::io::{Read, Seek};
    let mut file = std::fs::File::open(path).ok()?;
    file.seek(std::io::SeekFrom::Start(offset as u64)).ok()?;
    let mut bytes = Vec::new();
    file.read_to_end(&mut bytes).ok()?;
    Some(bytes)
}

/// Run `program args` with its output in `log`, showing `what` with a progress bar fed by
/// the log ([`progress_of`]; `images`: the count a stage's own lines do not give); an error
/// quotes the end of the log.
fn stage(program: &str, args: &[&std::ffi::OsStr], log: &Path, what: &str, install: &str, images: u64, progress: bool) -> Result<()> {
    let file = std::fs::File::create(log).map_err(|e| nerf_core::Error::io(log, e))?;
    let bar = if progress { ProgressBar::new(images) } else { ProgressBar::hidden() };
    bar.set_style(ProgressStyle::with_template("{msg} {bar:30} {pos}/{len} {elapsed}").expect("a valid template"));
    bar.set_message(what.to_string());
    let started = std::time::Instant::now();
    let child = Command::new(program)
        .args(args)
        .env("QT_QPA_PLATFORM", "offscreen")
        .stdin(Stdio::null())
        .stdout(file.try_clone().map_err(|e| nerf_core::Error::io(log, e))?)
        .stderr(file)
        .spawn();
    let mut child = child.map_err(|e| Error::External {
        program: program.into(),
        problem: if e.kind() == std::io::ErrorKind::NotFound { format!("not found: {install}") } else { e.to_string() },
    })?;
    let mut read = 0usize;
    let status = loop {
        let done = child.try_wait().map_err(|e| Error::External { program: program.into(), problem: e.to_string() })?;
        // The log so far, from where the last look stopped (ffmpeg ends its lines with \r).
        if let Some(text) = bytes_from(log, read) {
            let fresh = String::from_utf8_lossy(&text).into_owned();
            if let Some(cut) = fresh.rfind(['\n', '\r']) {
                read += cut + 1;
                if let Some((k, n)) = fresh[..cut].split(['\n', '\r']).filter_map(|l| progress_of(l, images)).last() {
                    bar.set_length(n);
                    bar.set_position(k.min(n));
                }
            }
        }
        match done {
            Some(status) => break status,
            None => std::thread::sleep(std::time::Duration::from_millis(200)),
        }
    };
    bar.finish_and_clear();
    if !status.success() {
        let text = std::fs::read_to_string(log).unwrap_or_default();
        let tail: Vec<&str> = text.lines().rev().take(8).collect();
        let tail: Vec<&str> = tail.into_iter().rev().collect();
        return Err(Error::External { program: program.into(), problem: format!("{what} failed ({status}); the end of {}:\n{}", log.display(), tail.join("\n")) });
    }
    if progress {
        eprintln!("{what}: done in {:.0} s", started.elapsed().as_secs_f64());
    }
    Ok(())
}

/// Run COLMAP on `images` in `work` (database, logs, `sparse/N`); returns the sparse folder.
pub fn run_colmap(images: &Path, work: &Path, options: &ColmapOptions, progress: bool) -> Result<PathBuf> {
    let matching = options.matching_args()?;
    let images_count = super::image_files(images)?.len() as u64;
    let db = work.join("database.db");
    let sparse = work.join("sparse");
    std::fs::create_dir_all(&sparse).map_err(|e| nerf_core::Error::io(&sparse, e))?;
    let os = |s: &str| std::ffi::OsString::from(s);
    let path = |p: &Path| p.as_os_str().to_os_string();
    let extract = [os("feature_extractor"), os("--database_path"), path(&db), os("--image_path"), path(images), os("--ImageReader.single_camera"), os("1"), os("--ImageReader.camera_model"), os(options.camera.name()), os("--SiftExtraction.use_gpu"), os("0")];
    let matching = [matching, vec![os("--database_path"), path(&db), os("--SiftMatching.use_gpu"), os("0")]].concat();
    let map = [os("mapper"), os("--database_path"), path(&db), os("--image_path"), path(images), os("--output_path"), path(&sparse)];
    for (args, log, what) in [(&extract[..], "1-features.log", "COLMAP: features"), (&matching[..], "2-matching.log", "COLMAP: matching"), (&map[..], "3-mapping.log", "COLMAP: mapping")] {
        let args: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
        stage("colmap", &args, &work.join(log), what, INSTALL_COLMAP, images_count, progress)?;
    }
    // The mapper keeps the principal point at the image centre; one more bundle adjustment
    // refines it, as instant-ngp's colmap2nerf.py does (on the fox, the centre is 3 pixels
    // off, and training on the unrefined model loses about a dB).
    let mut models: Vec<PathBuf> = std::fs::read_dir(&sparse).map_err(|e| nerf_core::Error::io(&sparse, e))?.flatten().map(|e| e.path()).filter(|p| p.is_dir()).collect();
    models.sort();
    for (k, model) in models.iter().enumerate() {
        let args = [os("bundle_adjuster"), os("--input_path"), path(model), os("--output_path"), path(model), os("--BundleAdjustment.refine_principal_point"), os("1")];
        let args: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
        stage("colmap", &args, &work.join(format!("4-refining-{k}.log")), "COLMAP: refining", INSTALL_COLMAP, 0, progress)?;
    }
    Ok(sparse)
}

/// About `count` frames picked evenly over `video`, as JPEGs named in time order in `out`
/// (ffmpeg).
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
    stage("ffmpeg", &args, &work.join("0-frames.log"), "ffmpeg: frames", INSTALL_FFMPEG, count as u64, progress)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progress_is_read_from_the_tools_logs() {
        assert_eq!(progress_of("Processed file [12/45]", 45), Some((12, 45)));
        assert_eq!(progress_of("Matching image [3/40] in 0.688s", 40), Some((3, 40)));
        assert_eq!(progress_of("Matching block [2/3, 1/3] in 36.4s", 45), Some((4, 9)));
        assert_eq!(progress_of("Matching block [1/1, 1/1] in 36.425s", 45), Some((1, 1)));
        assert_eq!(progress_of("Registering image #14 (4)", 45), Some((4, 45)));
        assert_eq!(progress_of("frame=  120 fps=0.0 q=2.0 Lsize=N/A", 120), Some((120, 120)));
        for other in ["Elapsed time: 1.117 [minutes]", "  Features:       8192", "Registering image #14", ""] {
            assert_eq!(progress_of(other, 45), None, "{other}");
        }
    }
}
