//! Image input and output: PNG and JPEG decoding to `f32` RGBA, PNG/GIF encoding (written atomically),
//! and a viewable colouring of depth maps.
//!
//! Pixel buffers are row-major: pixel (column `i`, row `j`) is at index `j·W + i`.

use std::path::Path;

use image::codecs::gif::{GifEncoder, Repeat};
use image::codecs::png::PngEncoder;
use image::{DynamicImage, ExtendedColorType, ImageEncoder, ImageReader};

use crate::io::atomic::write_atomic;
use crate::error::{Error, Result};

/// Quantises linear `[0, 1]` colours to 8 bits per channel: clamp to `[0, 1]`, ×255, round.
/// The output is `3·n` bytes, RGBRGB…; a NaN becomes 0.
pub fn rgb_to_rgb8(rgb: &[[f32; 3]]) -> Vec<u8> {
    rgb.iter().flat_map(|p| p.map(to_u8)).collect()
}

/// Quantises RGBA colours like [`rgb_to_rgb8`]: `4·n` bytes, RGBARGBA….
pub fn rgba_to_rgba8(rgba: &[[f32; 4]]) -> Vec<u8> {
    rgba.iter().flat_map(|p| p.map(to_u8)).collect()
}

fn to_u8(v: f32) -> u8 {
    // `as u8` saturates and maps NaN to 0.
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

fn check_len(path: &Path, width: u32, height: u32, len: usize) -> Result<()> {
    let expected = width as usize * height as usize;
    if width == 0 || height == 0 || len != expected {
        return Err(Error::invalid(
            path,
            format!(
                "cannot write a {width}×{height} image from {len} pixels (expected {expected}, non-empty)"
            ),
        ));
    }
    Ok(())
}

fn encode_png(
    path: &Path,
    width: u32,
    height: u32,
    bytes: &[u8],
    color: ExtendedColorType,
) -> Result<()> {
    let mut buf = Vec::new();
    PngEncoder::new(&mut buf)
        .write_image(bytes, width, height, color)
        .map_err(|source| Error::Image {
            path: path.to_path_buf(),
            source,
        })?;
    write_atomic(path, &buf)
}

/// Writes an 8-bit RGB PNG (encoded in memory, then written atomically: a reader never sees a
/// half-written file). `rgb` must hold `width·height` pixels.
pub fn save_png(path: &Path, width: u32, height: u32, rgb: &[[f32; 3]]) -> Result<()> {
    check_len(path, width, height, rgb.len())?;
    encode_png(
        path,
        width,
        height,
        &rgb_to_rgb8(rgb),
        ExtendedColorType::Rgb8,
    )
}

/// Writes an 8-bit RGB PNG from bytes already quantised (RGBRGB…, `3·width·height` of them),
/// atomically, like [`save_png`].
pub fn save_png_rgb8(path: &Path, width: u32, height: u32, rgb8: &[u8]) -> Result<()> {
    if !rgb8.len().is_multiple_of(3) {
        return Err(Error::invalid(path, format!("{} bytes are not whole RGB pixels", rgb8.len())));
    }
    check_len(path, width, height, rgb8.len() / 3)?;
    encode_png(path, width, height, rgb8, ExtendedColorType::Rgb8)
}

/// Writes an 8-bit RGBA PNG (straight, not premultiplied, alpha), atomically.
pub fn save_png_rgba(path: &Path, width: u32, height: u32, rgba: &[[f32; 4]]) -> Result<()> {
    check_len(path, width, height, rgba.len())?;
    encode_png(
        path,
        width,
        height,
        &rgba_to_rgba8(rgba),
        ExtendedColorType::Rgba8,
    )
}

/// Decodes an image file (any PNG: gray, gray+alpha, RGB, RGBA, 8 or 16 bits; a baseline or
/// progressive JPEG, gray or RGB; or a GIF's first frame; the format is read from the content,
/// not the extension) to straight RGBA in `[0, 1]`, returning `(width, height, pixels)`. Gray is replicated
/// to RGB; a missing alpha channel reads as 1. Values are not colour-managed (raw code values
/// divided by 255 or 65535, as the reference loaders do).
pub fn load_rgba(path: &Path) -> Result<(u32, u32, Vec<[f32; 4]>)> {
    let image_err = |source| Error::Image {
        path: path.to_path_buf(),
        source,
    };
    let reader = ImageReader::open(path).map_err(|e| Error::io(path, e))?;
    let reader = reader
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?;
    let img = reader.decode().map_err(image_err)?;
    let (w, h) = (img.width(), img.height());
    // Division (not multiplication by a reciprocal) so that 8-bit values read back exactly as
    // `v / 255.0`, like numpy's `imread(...) / 255.`.
    let u8f = |v: u8| v as f32 / 255.0;
    let u16f = |v: u16| v as f32 / 65535.0;
    let pixels: Vec<[f32; 4]> = match &img {
        DynamicImage::ImageLuma8(b) => b.pixels().map(|p| grey(u8f(p.0[0]), 1.0)).collect(),
        DynamicImage::ImageLumaA8(b) => {
            b.pixels().map(|p| grey(u8f(p.0[0]), u8f(p.0[1]))).collect()
        }
        DynamicImage::ImageRgb8(b) => b.pixels().map(|p| rgb1(p.0.map(u8f))).collect(),
        DynamicImage::ImageRgba8(b) => b.pixels().map(|p| p.0.map(u8f)).collect(),
        DynamicImage::ImageLuma16(b) => b.pixels().map(|p| grey(u16f(p.0[0]), 1.0)).collect(),
        DynamicImage::ImageLumaA16(b) => b
            .pixels()
            .map(|p| grey(u16f(p.0[0]), u16f(p.0[1])))
            .collect(),
        DynamicImage::ImageRgb16(b) => b.pixels().map(|p| rgb1(p.0.map(u16f))).collect(),
        DynamicImage::ImageRgba16(b) => b.pixels().map(|p| p.0.map(u16f)).collect(),
        DynamicImage::ImageRgb32F(b) => b.pixels().map(|p| rgb1(p.0)).collect(),
        DynamicImage::ImageRgba32F(b) => b.pixels().map(|p| p.0).collect(),
        other => other.to_rgba32f().pixels().map(|p| p.0).collect(),
    };
    if pixels.len() != w as usize * h as usize {
        return Err(Error::invalid(
            path,
            "decoded pixel count does not match the image size",
        ));
    }
    Ok((w, h, pixels))
}

fn grey(v: f32, a: f32) -> [f32; 4] {
    [v, v, v, a]
}

fn rgb1(p: [f32; 3]) -> [f32; 4] {
    [p[0], p[1], p[2], 1.0]
}

/// The "turbo" colormap (Google, 2019) through its published polynomial approximation;
/// `x` is clamped to `[0, 1]` (0 → dark blue, 0.5 → green, 1 → dark red).
pub fn turbo(x: f32) -> [f32; 3] {
    let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    let (x2, x3) = (x * x, x * x * x);
    let (x4, x5) = (x2 * x2, x3 * x2);
    let poly = |c: [f32; 6]| {
        (c[0] + c[1] * x + c[2] * x2 + c[3] * x3 + c[4] * x4 + c[5] * x5).clamp(0.0, 1.0)
    };
    [
        poly([
            0.135_721_38,
            4.615_392_6,
            -42.660_32,
            132.131_08,
            -152.942_39,
            59.286_38,
        ]),
        poly([
            0.091_402_61,
            2.194_188_4,
            4.842_966_6,
            -14.185_033,
            4.277_298_6,
            2.829_566,
        ]),
        poly([
            0.106_673_3,
            12.641_946,
            -60.582_05,
            110.362_77,
            -89.903_11,
            27.348_25,
        ]),
    ]
}

/// A viewable depth map: depth is normalised from `[near, far]` to `[0, 1]` (clamped; a
/// non-finite depth counts as `far`), coloured with [`turbo`], then faded to white where the
/// accumulated opacity is low: `c·acc + (1 − acc)` with `acc` clamped to `[0, 1]`.
///
/// # Panics
/// If `depth` and `acc` differ in length.
pub fn depth_to_rgb(depth: &[f32], acc: &[f32], near: f32, far: f32) -> Vec<[f32; 3]> {
    assert_eq!(
        depth.len(),
        acc.len(),
        "depth_to_rgb: depth and acc lengths differ"
    );
    let span = (far - near).abs().max(1e-8) * if far < near { -1.0 } else { 1.0 };
    depth
        .iter()
        .zip(acc)
        .map(|(&d, &a)| {
            let x = if d.is_finite() {
                (d - near) / span
            } else {
                1.0
            };
            let a = if a.is_nan() { 0.0 } else { a.clamp(0.0, 1.0) };
            turbo(x).map(|c| c * a + (1.0 - a))
        })
        .collect()
}

/// Writes an animated GIF that loops forever, each frame shown `delay_ms` milliseconds
/// (encoded in memory, then written atomically). Every frame must hold `width·height` pixels.
/// Colours are quantised to 8 bits ([`rgb_to_rgb8`]), then to a 256-colour palette per frame.
pub fn save_gif(
    path: &Path,
    width: u32,
    height: u32,
    frames: &[Vec<[f32; 3]>],
    delay_ms: u16,
) -> Result<()> {
    for (k, frame) in frames.iter().enumerate() {
        check_len(path, width, height, frame.len())
            .map_err(|e| Error::invalid(path, format!("frame {k}: {}", strip_path(&e, path))))?;
    }
    let bytes = encode_gif_rgb8(path, width, height, frames.len(), delay_ms, |k| {
        Ok(rgb_to_rgb8(&frames[k]))
    })?;
    write_atomic(path, &bytes)
}

/// The bytes of an animated GIF that loops forever: `count` frames of 8-bit RGB
/// (`3·width·height` bytes, RGBRGB…), frame `k` from `frame(k)`, asked for one at a time (so a
/// long video's frames need not all be in memory), each shown `delay_ms` milliseconds. Colours
/// are quantised to a 256-colour palette per frame. `path` only names the file in errors.
///
/// The same 8-bit frames give the same bytes, whether they come from a render
/// ([`rgb_to_rgb8`]) or from the PNG it was saved to ([`load_rgb8`]).
pub fn encode_gif_rgb8(
    path: &Path,
    width: u32,
    height: u32,
    count: usize,
    delay_ms: u16,
    mut frame: impl FnMut(usize) -> Result<Vec<u8>>,
) -> Result<Vec<u8>> {
    if count == 0 {
        return Err(Error::invalid(path, "cannot write a GIF without frames"));
    }
    if width > u16::MAX as u32 || height > u16::MAX as u32 {
        return Err(Error::invalid(
            path,
            format!("{width}×{height} is too large for a GIF"),
        ));
    }
    let image_err = |source| Error::Image {
        path: path.to_path_buf(),
        source,
    };
    let mut buf = Vec::new();
    {
        // Speed 10: the gif crate's recommended quality/speed trade-off for NeuQuant.
        let mut encoder = GifEncoder::new_with_speed(&mut buf, 10);
        encoder.set_repeat(Repeat::Infinite).map_err(image_err)?;
        let delay = image::Delay::from_numer_denom_ms(delay_ms as u32, 1);
        for k in 0..count {
            let rgb = frame(k)?;
            let expected = 3 * width as usize * height as usize;
            if rgb.len() != expected || expected == 0 {
                return Err(Error::invalid(
                    path,
                    format!("frame {k}: {} bytes for a {width}×{height} frame (expected {expected}, non-empty)", rgb.len()),
                ));
            }
            let rgba: Vec<u8> = rgb.chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect();
            let buffer = image::RgbaImage::from_raw(width, height, rgba)
                .ok_or_else(|| Error::invalid(path, "frame buffer has the wrong size"))?;
            encoder
                .encode_frame(image::Frame::from_parts(buffer, 0, 0, delay))
                .map_err(image_err)?;
        }
    }
    Ok(buf)
}

/// Decodes an image to 8-bit RGB bytes: `(width, height, 3·width·height bytes)`. An 8-bit RGB
/// PNG (what [`save_png`] writes) reads back exactly as written; alpha is dropped.
pub fn load_rgb8(path: &Path) -> Result<(u32, u32, Vec<u8>)> {
    let reader = ImageReader::open(path).map_err(|e| Error::io(path, e))?;
    let reader = reader.with_guessed_format().map_err(|e| Error::io(path, e))?;
    let img = reader.decode().map_err(|source| Error::Image { path: path.to_path_buf(), source })?;
    let rgb = img.to_rgb8();
    Ok((rgb.width(), rgb.height(), rgb.into_raw()))
}

fn strip_path(e: &Error, path: &Path) -> String {
    match e {
        Error::Invalid { problem, .. } => problem.clone(),
        other => other
            .to_string()
            .replacen(&format!("{}: ", path.display()), "", 1),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::AnimationDecoder;

    #[test]
    fn rgb8_quantisation_clamps_and_rounds() {
        let bytes = rgb_to_rgb8(&[[0.0, 1.0, 0.5], [-0.3, 2.0, 0.1], [f32::NAN, 0.002, 0.998]]);
        // 0.5·255 = 127.5 → 128; 0.1·255 = 25.5 → 26; 0.002·255 = 0.51 → 1; 0.998·255 = 254.49 → 254.
        assert_eq!(bytes, vec![0, 255, 128, 0, 255, 26, 0, 1, 254]);
    }

    #[test]
    fn png_round_trip_matches_after_quantisation() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.png");
        let (w, h) = (3u32, 2u32);
        let rgb: Vec<[f32; 3]> = vec![
            [0.0, 0.1, 0.2],
            [0.3, 0.4, 0.5],
            [0.6, 0.7, 0.8],
            [0.9, 1.0, 1.5],
            [0.25, 0.5, 0.75],
            [-1.0, 0.0, 1.0],
        ];
        save_png(&path, w, h, &rgb).unwrap();
        let (rw, rh, back) = load_rgba(&path).unwrap();
        assert_eq!((rw, rh), (3, 2));
        for (p, q) in rgb.iter().zip(&back) {
            for c in 0..3 {
                let expected = (p[c].clamp(0.0, 1.0) * 255.0).round() / 255.0;
                assert_eq!(q[c], expected, "{p:?} vs {q:?}");
            }
            assert_eq!(q[3], 1.0);
        }
        // 0.1 → round(25.5) = 26 → 26/255.
        assert_eq!(back[0][1], 26.0 / 255.0);
        // No temporary file is left behind.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        // Wrong pixel count is an error naming the file, not a panic.
        let err = save_png(&path, 4, 4, &rgb).unwrap_err().to_string();
        assert!(err.contains("a.png") && err.contains("4×4"), "{err}");
    }

    #[test]
    fn rgb8_png_keeps_bytes_and_refuses_partial_pixels() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.png");
        save_png_rgb8(&path, 2, 1, &[0, 128, 255, 10, 20, 30]).unwrap();
        let (w, h, back) = load_rgba(&path).unwrap();
        assert_eq!((w, h), (2, 1));
        assert_eq!(back[1], [10.0 / 255.0, 20.0 / 255.0, 30.0 / 255.0, 1.0]);
        let err = save_png_rgb8(&dir.path().join("c.png"), 2, 1, &[0; 5]).unwrap_err().to_string();
        assert!(err.contains("c.png") && err.contains("5 bytes"), "{err}");
        let err = save_png_rgb8(&dir.path().join("c.png"), 2, 2, &[0; 6]).unwrap_err().to_string();
        assert!(err.contains("2×2"), "{err}");
        assert!(!dir.path().join("c.png").exists());
    }

    #[test]
    fn load_rgba_reads_16_bit_and_grey_alpha() {
        let dir = tempfile::tempdir().unwrap();
        let p16 = dir.path().join("rgba16.png");
        let img = image::ImageBuffer::<image::Rgba<u16>, _>::from_raw(
            1,
            1,
            vec![65535u16, 0, 32768, 13107],
        )
        .unwrap();
        img.save(&p16).unwrap();
        let (_, _, px) = load_rgba(&p16).unwrap();
        assert_eq!(px[0][0], 1.0);
        assert_eq!(px[0][1], 0.0);
        assert!((px[0][2] - 32768.0 / 65535.0).abs() < 1e-7);
        assert!((px[0][3] - 0.2).abs() < 1e-7); // 13107/65535 = 0.2
        let pga = dir.path().join("ga.png");
        image::GrayAlphaImage::from_raw(1, 1, vec![51, 255])
            .unwrap()
            .save(&pga)
            .unwrap();
        let (_, _, px) = load_rgba(&pga).unwrap();
        assert_eq!(px[0], [0.2, 0.2, 0.2, 1.0]);
        let missing = dir.path().join("missing.png");
        let err = load_rgba(&missing).unwrap_err().to_string();
        assert!(err.contains("missing.png"), "{err}");
        let junk = dir.path().join("junk.png");
        std::fs::write(&junk, b"not a png").unwrap();
        let err = load_rgba(&junk).unwrap_err().to_string();
        assert!(err.contains("junk.png"), "{err}");
    }

    #[test]
    fn load_rgba_reads_jpeg_rgb_and_grey() {
        let dir = tempfile::tempdir().unwrap();
        // Flat colours survive JPEG at quality 100 to within a couple of code values.
        let rgb = dir.path().join("photo.jpg");
        let img = image::RgbImage::from_pixel(16, 8, image::Rgb([200, 100, 50]));
        let mut bytes = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 100).encode_image(&img).unwrap();
        std::fs::write(&rgb, &bytes).unwrap();
        let (w, h, px) = load_rgba(&rgb).unwrap();
        assert_eq!((w, h, px.len()), (16, 8, 128));
        for (c, v) in [200.0f32, 100.0, 50.0].iter().enumerate() {
            assert!((px[37][c] * 255.0 - v).abs() <= 2.0, "{:?}", px[37]);
        }
        assert_eq!(px[37][3], 1.0);
        // A grey JPEG under a .png name: decoded by content, grey replicated to RGB.
        let grey = dir.path().join("grey.png");
        let mut bytes = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 100)
            .encode_image(&image::GrayImage::from_pixel(4, 4, image::Luma([51])))
            .unwrap();
        std::fs::write(&grey, &bytes).unwrap();
        let (_, _, px) = load_rgba(&grey).unwrap();
        assert!((px[5][0] - 0.2).abs() < 0.01 && px[5][0] == px[5][2], "{:?}", px[5]);
        // A truncated JPEG is an error naming the file.
        std::fs::write(&rgb, &bytes[..bytes.len() / 3]).unwrap();
        let err = load_rgba(&rgb).unwrap_err().to_string();
        assert!(err.contains("photo.jpg"), "{err}");
    }

    #[test]
    fn gif_has_all_frames() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("orbit.gif");
        let (w, h) = (4u32, 3u32);
        let frames: Vec<Vec<[f32; 3]>> = (0..5)
            .map(|k| vec![[k as f32 / 4.0, 0.5, 1.0 - k as f32 / 4.0]; (w * h) as usize])
            .collect();
        save_gif(&path, w, h, &frames, 40).unwrap();
        let file = std::io::BufReader::new(std::fs::File::open(&path).unwrap());
        let decoded = image::codecs::gif::GifDecoder::new(file)
            .unwrap()
            .into_frames()
            .collect_frames()
            .unwrap();
        assert_eq!(decoded.len(), 5);
        assert_eq!(decoded[0].buffer().dimensions(), (4, 3));
        let (num, den) = decoded[2].delay().numer_denom_ms();
        assert_eq!(num as f32 / den as f32, 40.0);
        // Flat colour frames survive quantisation closely: frame 4 is (1, 0.5, 0).
        let px = decoded[4].buffer().get_pixel(1, 1).0;
        assert!(
            (px[0] as i32 - 255).abs() <= 2 && (px[1] as i32 - 128).abs() <= 2 && px[2] <= 2,
            "{px:?}"
        );
        let err = save_gif(&path, w, h, &[vec![[0.0; 3]; 5]], 40)
            .unwrap_err()
            .to_string();
        assert!(err.contains("frame 0"), "{err}");
        assert!(save_gif(&path, w, h, &[], 40).is_err());
    }

    #[test]
    fn a_gif_from_saved_pngs_equals_the_gif_from_the_renders() {
        // Every 8-bit value survives a PNG round trip, so the GIF a merge builds from the
        // frames' PNGs is byte for byte the one built from the floats.
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (16u32, 16u32);
        let frames: Vec<Vec<[f32; 3]>> = (0..3)
            .map(|f| (0..256).map(|k| [k as f32 / 255.0 + 0.001 * f as f32, (255 - k) as f32 / 251.0, 0.3]).collect())
            .collect();
        let direct = dir.path().join("direct.gif");
        save_gif(&direct, w, h, &frames, 100).unwrap();
        let pngs: Vec<_> = frames
            .iter()
            .enumerate()
            .map(|(k, f)| {
                let p = dir.path().join(format!("{k}.png"));
                save_png(&p, w, h, f).unwrap();
                p
            })
            .collect();
        for (p, f) in pngs.iter().zip(&frames) {
            assert_eq!(load_rgb8(p).unwrap(), (w, h, rgb_to_rgb8(f)), "{}", p.display());
        }
        let merged = encode_gif_rgb8(&direct, w, h, 3, 100, |k| Ok(load_rgb8(&pngs[k])?.2)).unwrap();
        assert_eq!(merged, std::fs::read(&direct).unwrap());
        // A frame of the wrong size is named.
        let err = encode_gif_rgb8(&direct, w, h, 2, 100, |k| Ok(vec![0; if k == 1 { 5 } else { 768 }])).unwrap_err();
        assert!(err.to_string().contains("frame 1: 5 bytes"), "{err}");
    }

    #[test]
    fn depth_colormap_endpoints_and_white_fade() {
        let c = depth_to_rgb(
            &[2.0, 6.0, 4.0, 9.0, f32::NAN],
            &[1.0, 1.0, 0.0, 1.0, 1.0],
            2.0,
            6.0,
        );
        // Near → turbo(0) ≈ (0.136, 0.091, 0.107) (dark blue); far → turbo(1) ≈ (0.566, 0.050, 0) (blue clamped from −0.026).
        let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 2e-3);
        assert!(close(c[0], [0.1357, 0.0914, 0.1067]), "{:?}", c[0]);
        assert!(close(c[1], [0.5659, 0.0504, 0.0]), "{:?}", c[1]);
        assert_ne!(c[0], c[1]);
        // acc = 0 → exactly white whatever the depth.
        assert_eq!(c[2], [1.0, 1.0, 1.0]);
        // Beyond far clamps to far; NaN depth counts as far.
        assert_eq!(c[3], c[1]);
        assert_eq!(c[4], c[1]);
        // Halfway: the colormap's green middle, and acc = 0.5 blends halfway to white.
        let mid = depth_to_rgb(&[4.0, 4.0], &[1.0, 0.5], 2.0, 6.0);
        assert!(
            mid[0][1] > mid[0][0] && mid[0][1] > mid[0][2],
            "{:?}",
            mid[0]
        );
        for (faded, full) in mid[1].iter().zip(mid[0]) {
            assert!((faded - (0.5 * full + 0.5)).abs() < 1e-6);
        }
    }
}
