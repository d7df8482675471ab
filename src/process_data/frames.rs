//! Choosing a video's frames: ffmpeg gives `window` candidates per wanted frame, evenly over
//! the video, and the sharpest candidate of each window is kept (a hand-held video blurs
//! whenever the camera moves fast, and a blurred frame gives COLMAP few features and the
//! field a smeared target). Sharpness is the variance of the Laplacian, the measure
//! instant-ngp's `colmap2nerf.py` records per frame.

use crate::error::Result;
use nerf_core::Error as CoreError;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Frames are measured at most this wide (shrunk by an integer factor): enough to see blur,
/// and a 4K frame costs no more than a 1K one.
const MEASURE_WIDTH: u32 = 1024;

/// The variance of the 4-neighbour Laplacian of the grey image, with grey in `[0, 255]`.
///
/// Example: a 3×3 grey image, 255 at the centre and 0 elsewhere, has one interior pixel with
/// Laplacian 4·255 − 0 = 1020; its variance over that one pixel is 0. A 4×3 image with
/// columns 0, 255, 0, 0 has interior Laplacians −510 (at column 1) and 255 (at column 2):
/// mean −127.5, variance 146,306.25.
pub fn laplacian_variance(grey: &image::GrayImage) -> f64 {
    let (w, h) = grey.dimensions();
    if w < 3 || h < 3 {
        return 0.0;
    }
    let at = |x: u32, y: u32| grey.get_pixel(x, y).0[0] as f64;
    let (mut sum, mut sum2, mut n) = (0.0, 0.0, 0.0);
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let l = at(x - 1, y) + at(x + 1, y) + at(x, y - 1) + at(x, y + 1) - 4.0 * at(x, y);
            sum += l;
            sum2 += l * l;
            n += 1.0;
        }
    }
    let mean = sum / n;
    (sum2 / n - mean * mean).max(0.0)
}

/// [`laplacian_variance`] of the image file at `path`, measured at most [`MEASURE_WIDTH`]
/// wide.
pub fn sharpness(path: &Path) -> Result<f64> {
    let img = image::open(path).map_err(|source| CoreError::Image { path: path.to_path_buf(), source })?;
    let factor = img.width().div_ceil(MEASURE_WIDTH).max(1);
    let img = if factor > 1 { img.resize_exact(img.width() / factor, img.height() / factor, image::imageops::FilterType::Triangle) } else { img };
    Ok(laplacian_variance(&img.to_luma8()))
}

/// The sharpest file of each run of `window` consecutive `files` (the last run may be
/// shorter), in order.
pub fn sharpest_of_windows(files: &[PathBuf], window: usize) -> Result<Vec<PathBuf>> {
    let scores: Vec<f64> = files.par_iter().map(|f| sharpness(f)).collect::<Result<_>>()?;
    let window = window.max(1);
    Ok((0..files.len())
        .step_by(window)
        .map(|start| {
            let end = (start + window).min(files.len());
            let best = (start..end).max_by(|&a, &b| scores[a].total_cmp(&scores[b])).expect("a window holds a file");
            files[best].clone()
        })
        .collect())
}

/// Moves the sharpest of each `window` of the frames in `candidates` (name order) into
/// `out` as `frame_00001.jpg`, …; returns how many.
pub fn keep_sharpest(candidates: &Path, window: usize, out: &Path) -> Result<usize> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(candidates)
        .map_err(|e| CoreError::io(candidates, e))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "jpg"))
        .collect();
    files.sort();
    let kept = sharpest_of_windows(&files, window)?;
    std::fs::create_dir_all(out).map_err(|e| CoreError::io(out, e))?;
    for (k, from) in kept.iter().enumerate() {
        let to = out.join(format!("frame_{:05}.jpg", k + 1));
        std::fs::rename(from, &to).map_err(|e| CoreError::io(&to, e))?;
    }
    Ok(kept.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn laplacian_variance_on_hand_values() {
        let dot = image::GrayImage::from_fn(3, 3, |x, y| image::Luma([if (x, y) == (1, 1) { 255 } else { 0 }]));
        assert_eq!(laplacian_variance(&dot), 0.0);
        let bar = image::GrayImage::from_fn(4, 3, |x, _| image::Luma([if x == 1 { 255 } else { 0 }]));
        assert!((laplacian_variance(&bar) - 146_306.25).abs() < 1e-6, "{}", laplacian_variance(&bar));
        let flat = image::GrayImage::from_pixel(5, 5, image::Luma([90]));
        assert_eq!(laplacian_variance(&flat), 0.0);
    }

    /// Three windows of two frames: the sharp frame of each wins over its blurred copy,
    /// wherever it stands in the window.
    #[test]
    fn the_sharp_frame_of_each_window_is_kept() {
        let dir = tempfile::tempdir().unwrap();
        let candidates = dir.path().join("candidates");
        std::fs::create_dir_all(&candidates).unwrap();
        let checker = image::RgbImage::from_fn(64, 48, |x, y| if (x / 4 + y / 4) % 2 == 0 { image::Rgb([240, 240, 240]) } else { image::Rgb([20, 20, 20]) });
        let blurred = image::imageops::blur(&checker, 3.0);
        let sharp_at = [1, 2, 5];
        for k in 0..6 {
            let img = if sharp_at.contains(&k) { &checker } else { &blurred };
            img.save(candidates.join(format!("c_{k:03}.jpg"))).unwrap();
        }
        let files: Vec<PathBuf> = (0..6).map(|k| candidates.join(format!("c_{k:03}.jpg"))).collect();
        let kept = sharpest_of_windows(&files, 2).unwrap();
        assert_eq!(kept, [1, 2, 5].map(|k| files[k].clone()));
        // Window 4 over six frames: the last window is the two left.
        assert_eq!(sharpest_of_windows(&files, 4).unwrap(), [files[2].clone(), files[5].clone()]);
        let out = dir.path().join("frames");
        assert_eq!(keep_sharpest(&candidates, 2, &out).unwrap(), 3);
        let sharp = sharpness(&candidates.join("c_000.jpg")).unwrap();
        assert!(sharpness(&out.join("frame_00001.jpg")).unwrap() > 2.0 * sharp);
        assert!(out.join("frame_00003.jpg").is_file() && !out.join("frame_00004.jpg").exists());
        // An unreadable file: an error naming it.
        std::fs::write(candidates.join("c_100.jpg"), "not an image").unwrap();
        let err = keep_sharpest(&candidates, 2, &dir.path().join("again")).unwrap_err().to_string();
        assert!(err.contains("c_100.jpg"), "{err}");
    }
}
