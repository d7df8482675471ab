//! Decoding a dataset's images, the same way for every format: straight RGBA in `[0, 1]`,
//! area-downscaled by an integer factor, then composited on the configured background
//! (reference `load_blender_data` order: average first, composite after).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::io::image::load_rgba;
use image::ImageEncoder;

/// What transparent pixels show: the colour RGBA images are composited on, and the colour a
/// render adds where its rays see nothing (`white_background` in a run's configuration).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Background {
    /// `rgb·a + (1 − a)`: the Blender convention (`white_bkgd`).
    White,
    /// `rgb·a`.
    Black,
    /// Training only (instant-ngp's default): every ray sees a new random colour, so whatever
    /// the field leaves transparent is wrong, and opaque photos teach full opacity. Images load
    /// premultiplied (`rgb·a`) with their alpha kept ([`Decoded`]).
    Random,
}

impl Background {
    /// White when `white` is set, else black.
    pub fn from_white(white: bool) -> Self {
        if white { Background::White } else { Background::Black }
    }

    /// A straight RGBA pixel on this background.
    ///
    /// Example: (1, 0.5, 0, 0.25) → white (0.25·1 + 0.75, 0.125 + 0.75, 0.75), black (0.25, 0.125, 0).
    pub fn composite(self, p: [f32; 4]) -> [f32; 3] {
        let fill = match self {
            Background::White => 1.0 - p[3],
            Background::Black | Background::Random => 0.0,
        };
        [0, 1, 2].map(|c| p[c] * p[3] + fill)
    }
}

/// An error naming `path` when `width × height` is not divisible by `downscale`.
pub fn check_divisible(path: &Path, width: u32, height: u32, downscale: u32) -> Result<()> {
    if !width.is_multiple_of(downscale) || !height.is_multiple_of(downscale) {
        return Err(Error::invalid(
            path,
            format!("image is {width}×{height}, not divisible by the downscale factor {downscale}"),
        ));
    }
    Ok(())
}

/// A decoded image.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded {
    /// Full-resolution width.
    pub width: u32,
    /// Full-resolution height.
    pub height: u32,
    /// Downscaled pixels, composited on the background (premultiplied for `Random`).
    pub rgb: Vec<[f32; 3]>,
    /// Downscaled alpha, kept for `Random` when some pixel is not opaque (`None`: opaque).
    pub alpha: Option<Vec<f32>>,
}

/// Decodes one image and returns its full-resolution size with the downscaled RGB pixels
/// composited on `background`.
/// The copy of `path` already shrunk by `downscale` ([`prescaled_path`]) is read instead when
/// it exists with exactly the shrunk size.
pub fn load_image(path: &Path, downscale: u32, background: Background) -> Result<Decoded> {
    let (width, height, small) = match prescaled(path, downscale)? {
        Some((width, height, small)) => (width, height, load_rgba(&small)?.2),
        None => {
            let (width, height, rgba) = load_rgba(path)?;
            check_divisible(path, width, height, downscale)?;
            (width, height, downscale_area(&rgba, width as usize, height as usize, downscale as usize))
        }
    };
    let alpha = (background == Background::Random && small.iter().any(|p| p[3] < 1.0)).then(|| small.iter().map(|p| p[3]).collect());
    Ok(Decoded { width, height, rgb: small.into_iter().map(|p| background.composite(p)).collect(), alpha })
}

/// Where a copy of `path` shrunk by `factor` is kept, as LLFF captures and nerfstudio's
/// `process-data` keep them: beside the image folder, with the factor in its name, as PNG
/// (`scene/images/0001.jpg` → `scene/images_4/0001.png`).
pub fn prescaled_path(path: &Path, factor: u32) -> Option<PathBuf> {
    let folder = path.parent()?;
    let name = format!("{}_{factor}", folder.file_name()?.to_str()?);
    Some(folder.with_file_name(name).join(Path::new(path.file_name()?).with_extension("png")))
}

/// The full size of `path` and its shrunk copy, when `factor > 1` and that copy exists with
/// exactly the full size divided by `factor` (a copy of another size was made some other way,
/// and is not used).
fn prescaled(path: &Path, factor: u32) -> Result<Option<(u32, u32, PathBuf)>> {
    let Some(small) = prescaled_path(path, factor).filter(|p| factor > 1 && p.is_file()) else {
        return Ok(None);
    };
    let (width, height) = image::image_dimensions(path).map_err(|source| Error::Image { path: path.to_path_buf(), source })?;
    let fits = width.is_multiple_of(factor)
        && height.is_multiple_of(factor)
        && image::image_dimensions(&small).is_ok_and(|size| size == (width / factor, height / factor));
    Ok(fits.then_some((width, height, small)))
}

/// Writes [`prescaled_path`]`(path, f)` for each factor `f`: the image area-averaged as
/// [`load_image`] does, as 8-bit PNG (RGB when opaque), each through a temporary file; the
/// image is decoded once. Returns the paths written.
pub fn write_prescaled(path: &Path, factors: &[u32]) -> Result<Vec<PathBuf>> {
    let (width, height, rgba) = load_rgba(path)?;
    let mut written = Vec::with_capacity(factors.len());
    for &factor in factors {
        let to = prescaled_path(path, factor).ok_or_else(|| Error::invalid(path, "not an image file in a folder"))?;
        check_divisible(path, width, height, factor)?;
        let small = downscale_area(&rgba, width as usize, height as usize, factor as usize);
        let byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
        let opaque = small.iter().all(|p| p[3] >= 1.0);
        let channels = if opaque { 3 } else { 4 };
        let bytes: Vec<u8> = small.iter().flat_map(|p| p.iter().take(channels).copied()).map(byte).collect();
        let colour = if opaque { image::ExtendedColorType::Rgb8 } else { image::ExtendedColorType::Rgba8 };
        let mut png = Vec::new();
        image::codecs::png::PngEncoder::new(&mut png)
            .write_image(&bytes, width / factor, height / factor, colour)
            .map_err(|source| Error::Image { path: to.clone(), source })?;
        let folder = to.parent().expect("a prescaled path has a folder");
        std::fs::create_dir_all(folder).map_err(|e| Error::io(folder, e))?;
        crate::io::atomic::write_atomic(&to, &png)?;
        written.push(to);
    }
    Ok(written)
}

/// Box-filter reduction by an integer `factor` (sides divisible by it): each output pixel is
/// the mean of its `factor × factor` block of RGBA values (OpenCV's INTER_AREA).
fn downscale_area(rgba: &[[f32; 4]], width: usize, height: usize, factor: usize) -> Vec<[f32; 4]> {
    if factor == 1 {
        return rgba.to_vec();
    }
    let (ow, oh) = (width / factor, height / factor);
    let scale = 1.0 / (factor * factor) as f32;
    let mut out = vec![[0.0f32; 4]; ow * oh];
    for j in 0..height {
        let orow = (j / factor) * ow;
        for i in 0..width {
            let o = &mut out[orow + i / factor];
            let p = rgba[j * width + i];
            for c in 0..4 {
                o[c] += p[c];
            }
        }
    }
    for o in &mut out {
        for v in o.iter_mut() {
            *v *= scale;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn composites_on_either_background() {
        let p = [1.0, 0.5, 0.0, 0.25];
        assert_eq!(Background::White.composite(p), [1.0, 0.875, 0.75]);
        assert_eq!(Background::Black.composite(p), [0.25, 0.125, 0.0]);
        // Opaque pixels are the same on both.
        let q = [0.2, 0.4, 0.6, 1.0];
        assert_eq!(Background::White.composite(q), Background::Black.composite(q));
        assert_eq!(Background::from_white(false), Background::Black);
        assert_eq!(serde_json::to_string(&Background::White).unwrap(), "\"white\"");
    }

    #[test]
    fn black_background_after_the_area_mean() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.png");
        // 2×2 block: one opaque red pixel and three transparent ones → mean (0.25, 0, 0, 0.25)
        // → on black 0.25·0.25 = 0.0625 red.
        image::RgbaImage::from_fn(2, 2, |i, j| image::Rgba(if (i, j) == (0, 0) { [255, 0, 0, 255] } else { [0, 0, 0, 0] }))
            .save(&path)
            .unwrap();
        let Decoded { width, height, rgb, alpha } = load_image(&path, 2, Background::Black).unwrap();
        assert_eq!((width, height, rgb.len(), alpha), (2, 2, 1, None));
        assert!((rgb[0][0] - 0.0625).abs() < 1e-7 && rgb[0][1] == 0.0, "{:?}", rgb[0]);
        // For random backgrounds: the same premultiplied colour, and the alpha kept.
        let random = load_image(&path, 2, Background::Random).unwrap();
        assert_eq!((random.rgb, random.alpha), (rgb, Some(vec![0.25])));
        let err = load_image(&path, 3, Background::Black).unwrap_err().to_string();
        assert!(err.contains("a.png") && err.contains("not divisible by the downscale factor 3"), "{err}");
    }

    #[test]
    fn a_prescaled_copy_is_read_when_it_has_the_shrunk_size() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("images/a.jpg");
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        image::RgbImage::from_fn(8, 4, |i, j| image::Rgb([(i * 30) as u8, (j * 60) as u8, 200])).save(&path).unwrap();
        assert_eq!(prescaled_path(&path, 4), Some(dir.path().join("images_4/a.png")));
        let direct = load_image(&path, 2, Background::White).unwrap();
        let written = write_prescaled(&path, &[2, 4]).unwrap();
        assert_eq!(written, [dir.path().join("images_2/a.png"), dir.path().join("images_4/a.png")]);
        assert_eq!(image::image_dimensions(&written[1]).unwrap(), (2, 1));
        let written = &written[0];
        assert_eq!(image::image_dimensions(written).unwrap(), (4, 2));
        let read = load_image(&path, 2, Background::White).unwrap();
        assert_eq!((read.width, read.height, read.rgb.len()), (8, 4, 8));
        // The copy holds the same area means, rounded to 8 bits.
        for (a, b) in read.rgb.iter().zip(&direct.rgb) {
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() <= 0.5 / 255.0 + 1e-6, "{a:?} vs {b:?}");
            }
        }
        // Proof that the copy is what was read: paint it black.
        image::RgbImage::new(4, 2).save(written).unwrap();
        assert_eq!(load_image(&path, 2, Background::White).unwrap().rgb[0], [0.0; 3]);
        // A copy of another size was made some other way: the original is shrunk instead.
        image::RgbImage::new(3, 2).save(written).unwrap();
        assert_eq!(load_image(&path, 2, Background::White).unwrap().rgb, direct.rgb);
        // Not divisible: a clear error, nothing written.
        let err = write_prescaled(&path, &[3]).unwrap_err().to_string();
        assert!(err.contains("a.jpg") && err.contains("not divisible"), "{err}");
        assert!(!dir.path().join("images_3").exists());
    }
}
