//! The Blender synthetic format (`transforms_{split}.json` plus RGBA PNGs), loaded like the
//! reference `load_blender_data`: RGBA in `[0, 1]`, area-downscaled, then composited on white.

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{Split, SplitData, View};
use crate::camera::{Intrinsics, Pose};
use crate::camera::PinholeCamera;
use crate::error::{Error, Result};
use super::images::{Background, Decoded, check_divisible, load_image};

/// The contents of a `transforms_{split}.json` (other fields are ignored when reading).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Transforms {
    /// Horizontal field of view in radians.
    pub camera_angle_x: f32,
    /// The views.
    pub frames: Vec<Frame>,
}

/// One frame of a `transforms_{split}.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Frame {
    /// Image path relative to the dataset directory, usually without extension (`./train/r_0`).
    pub file_path: String,
    /// Camera-to-world matrix, 4 rows of 4.
    pub transform_matrix: [[f32; 4]; 4],
}

/// `dir/transforms_{split}.json`.
pub fn transforms_path(dir: &Path, split: Split) -> PathBuf {
    dir.join(format!("transforms_{}.json", split.name()))
}

/// The image file of a frame: `dir/<file_path>.png`, or `dir/<file_path>` when it already ends
/// in `.png`. A leading `./` is dropped.
pub fn image_path(dir: &Path, file_path: &str) -> PathBuf {
    let rel = file_path.strip_prefix("./").unwrap_or(file_path);
    if rel.to_ascii_lowercase().ends_with(".png") {
        dir.join(rel)
    } else {
        dir.join(format!("{rel}.png"))
    }
}

fn read_transforms(path: &Path) -> Result<Transforms> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    serde_json::from_str(&text).map_err(|source| Error::Json {
        path: path.to_path_buf(),
        source,
    })
}

/// Loads one split of a Blender-format dataset from `dir`.
///
/// The focal length comes from `camera_angle_x` at full resolution
/// (`0.5·W / tan(0.5·camera_angle_x)`); width, height and focal are then divided by
/// `downscale` (≥ 1; both sides must be divisible by it). With `images`, every PNG is decoded
/// (in parallel) to RGBA, reduced by averaging each `downscale × downscale` block (OpenCV's
/// INTER_AREA for an integer factor), then composited on white: `rgb·a + (1 − a)`. Without
/// `images`, no pixels are decoded; the size is read from the header of the first existing
/// image of this split, else of the train split.
///
/// Errors name the file: a missing or malformed JSON, no frames, a non-finite
/// `transform_matrix`, a missing or undecodable image, images of different sizes, a size not
/// divisible by `downscale`, or `downscale == 0`.
pub fn load_split(dir: &Path, split: Split, downscale: u32, images: bool) -> Result<SplitData> {
    load_blender(dir, split, downscale, images, Background::White)
}

/// [`load_split`] composited on `background` (the reference code's white, or black).
pub fn load_blender(
    dir: &Path,
    split: Split,
    downscale: u32,
    images: bool,
    background: Background,
) -> Result<SplitData> {
    let json_path = transforms_path(dir, split);
    if downscale == 0 {
        return Err(Error::Argument(format!(
            "downscale factor 0 for {}: it must be at least 1",
            json_path.display()
        )));
    }
    let transforms = read_transforms(&json_path)?;
    if transforms.frames.is_empty() {
        return Err(Error::invalid(&json_path, "\"frames\" is empty"));
    }
    let angle = transforms.camera_angle_x;
    if !(angle.is_finite() && angle > 0.0 && angle < std::f32::consts::PI) {
        return Err(Error::invalid(
            &json_path,
            format!("camera_angle_x {angle} is not in (0, π)"),
        ));
    }
    for (k, frame) in transforms.frames.iter().enumerate() {
        if !frame
            .transform_matrix
            .iter()
            .flatten()
            .all(|v| v.is_finite())
        {
            return Err(Error::invalid(
                &json_path,
                format!(
                    "frame {k} ({}): transform_matrix has a non-finite entry",
                    frame.file_path
                ),
            ));
        }
    }

    let (width, height, pixels) = if images {
        let decoded: Vec<Result<Decoded>> = transforms
            .frames
            .par_iter()
            .map(|frame| load_image(&image_path(dir, &frame.file_path), downscale, background))
            .collect();
        let mut size = None;
        let mut pixels = Vec::with_capacity(decoded.len());
        for (k, (frame, result)) in transforms.frames.iter().zip(decoded).enumerate() {
            // The image's own error names the image; say which frame of which file wants it.
            let Decoded { width: w, height: h, rgb, alpha } = result.map_err(|e| {
                Error::invalid(&json_path, format!("frame {k} (file_path {:?}): {e}", frame.file_path))
            })?;
            match size {
                None => size = Some((w, h, frame.file_path.clone())),
                Some((fw, fh, ref first)) if (w, h) != (fw, fh) => {
                    return Err(Error::invalid(
                        image_path(dir, &frame.file_path),
                        format!(
                            "image is {w}×{h} but the first image of the split ({first}) is {fw}×{fh}"
                        ),
                    ));
                }
                Some(_) => {}
            }
            pixels.push((Some(rgb), alpha));
        }
        let (w, h, _) = size.expect("frames is not empty");
        (w, h, pixels)
    } else {
        let (w, h, probed) = probe_size(dir, split, &transforms, &json_path)?;
        check_divisible(&probed, w, h, downscale)?;
        (w, h, vec![(None, None); transforms.frames.len()])
    };

    let full = Intrinsics::from_camera_angle_x(width, height, angle);
    let camera = PinholeCamera::from(Intrinsics {
        width: width / downscale,
        height: height / downscale,
        focal: full.focal / downscale as f32,
    });
    let views = transforms
        .frames
        .into_iter()
        .zip(pixels)
        .map(|(frame, (image, alpha))| View {
            name: Path::new(&frame.file_path)
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
            camera,
            pose: Pose::from_rows(frame.transform_matrix),
            file_path: frame.file_path,
            image,
            alpha,
        })
        .collect();
    Ok(SplitData { split: split.into(), views })
}

/// The full-resolution size from the first existing image of `split`, else of the train split.
fn probe_size(
    dir: &Path,
    split: Split,
    transforms: &Transforms,
    json_path: &Path,
) -> Result<(u32, u32, PathBuf)> {
    let header = |path: PathBuf| -> Result<(u32, u32, PathBuf)> {
        let (w, h) = image::image_dimensions(&path).map_err(|source| Error::Image {
            path: path.clone(),
            source,
        })?;
        Ok((w, h, path))
    };
    let first_existing = |t: &Transforms| {
        t.frames
            .iter()
            .map(|f| image_path(dir, &f.file_path))
            .find(|p| p.is_file())
    };
    if let Some(path) = first_existing(transforms) {
        return header(path);
    }
    if split != Split::Train {
        let train_json = transforms_path(dir, Split::Train);
        if let Ok(train) = read_transforms(&train_json)
            && let Some(path) = first_existing(&train)
        {
            return header(path);
        }
    }
    Err(Error::invalid(
        json_path,
        format!(
            "none of its images exists (the first is {}), nor any of the train split's, so the image size is unknown",
            image_path(dir, &transforms.frames[0].file_path).display()
        ),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    const ANGLE: f32 = 0.6911112;

    fn identity_rows(x: f32) -> [[f32; 4]; 4] {
        [
            [1.0, 0.0, 0.0, x],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 4.0],
            [0.0, 0.0, 0.0, 1.0],
        ]
    }

    fn write_json(dir: &Path, split: Split, text: &str) {
        std::fs::write(transforms_path(dir, split), text).unwrap();
    }

    fn frames_json(paths: &[&str]) -> String {
        let frames: Vec<String> = paths
            .iter()
            .enumerate()
            .map(|(k, p)| {
                format!(
                    r#"{{"file_path": "{p}", "rotation": 0.012, "transform_matrix": [[1,0,0,{k}],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}}"#
                )
            })
            .collect();
        format!(
            r#"{{"camera_angle_x": {ANGLE}, "frames": [{}]}}"#,
            frames.join(",")
        )
    }

    fn write_rgba8(path: &Path, w: u32, h: u32, f: impl Fn(u32, u32) -> [u8; 4]) {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        image::RgbaImage::from_fn(w, h, |i, j| image::Rgba(f(i, j)))
            .save(path)
            .unwrap();
    }

    #[test]
    fn paths_and_names() {
        let d = Path::new("/data/lego");
        assert_eq!(
            transforms_path(d, Split::Val),
            Path::new("/data/lego/transforms_val.json")
        );
        assert_eq!(
            image_path(d, "./train/r_0"),
            Path::new("/data/lego/train/r_0.png")
        );
        assert_eq!(
            image_path(d, "./train/r_0.png"),
            Path::new("/data/lego/train/r_0.png")
        );
        assert_eq!(
            image_path(d, "test/r_7"),
            Path::new("/data/lego/test/r_7.png")
        );
    }

    #[test]
    fn downscale_averages_rgba_then_composites_on_white() {
        let dir = tempfile::tempdir().unwrap();
        // 4×2 image. Block (0..2, 0..2): one opaque red pixel, three fully transparent black.
        // Area mean: (0.25, 0, 0, 0.25) → composite r = 0.25·0.25 + 0.75 = 0.8125,
        // g = b = 0.75. (Compositing first would give r = 1, g = b = 0.75.)
        // Block (2..4, 0..2): opaque (51, 102, 204) = (0.2, 0.4, 0.8) everywhere.
        write_rgba8(&dir.path().join("train/r_0.png"), 4, 2, |i, j| {
            if i >= 2 {
                [51, 102, 204, 255]
            } else if (i, j) == (0, 0) {
                [255, 0, 0, 255]
            } else {
                [0, 0, 0, 0]
            }
        });
        write_json(dir.path(), Split::Train, &frames_json(&["./train/r_0"]));
        let full = load_split(dir.path(), Split::Train, 1, true).unwrap();
        assert_eq!((full.camera().unwrap().width, full.camera().unwrap().height), (4, 2));
        let img = full.views[0].image.as_ref().unwrap();
        assert_eq!(img[0], [1.0, 0.0, 0.0]);
        assert_eq!(img[1], [1.0, 1.0, 1.0]); // transparent → exactly white
        let half = load_split(dir.path(), Split::Train, 2, true).unwrap();
        assert_eq!((half.camera().unwrap().width, half.camera().unwrap().height), (2, 1));
        let img = half.views[0].image.as_ref().unwrap();
        assert_eq!(img.len(), 2);
        let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
        assert!(close(img[0], [0.8125, 0.75, 0.75]), "{:?}", img[0]);
        assert!(close(img[1], [0.2, 0.4, 0.8]), "{:?}", img[1]);
        // focal: 0.5·4 / tan(0.3455556) = 2 / 0.36000002 = 5.5555552, halved.
        assert!(
            (full.camera().unwrap().fx - 5.555_555).abs() < 1e-4,
            "{}",
            full.camera().unwrap().fx
        );
        assert!((half.camera().unwrap().fx - full.camera().unwrap().fx / 2.0).abs() < 1e-6);
        assert_eq!(half.views[0].name, "r_0");
        assert_eq!(half.views[0].file_path, "./train/r_0");
        assert_eq!(half.views[0].pose, Pose::from_rows(identity_rows(0.0)));
    }

    #[test]
    fn decodes_rgb8_gray_and_16_bit_pngs() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(dir.path().join("train")).unwrap();
        image::RgbImage::from_raw(2, 2, vec![255, 0, 0, 0, 255, 0, 0, 0, 255, 51, 51, 51])
            .unwrap()
            .save(dir.path().join("train/a.png"))
            .unwrap();
        image::GrayImage::from_raw(2, 2, vec![0, 51, 102, 255])
            .unwrap()
            .save(dir.path().join("train/b.png"))
            .unwrap();
        // 16-bit RGBA: half-transparent black → 0·0.5 + 0.5 = 0.5 (to 1/65535).
        image::ImageBuffer::<image::Rgba<u16>, _>::from_raw(2, 2, [0u16, 0, 0, 32768].repeat(4))
            .unwrap()
            .save(dir.path().join("train/c.png"))
            .unwrap();
        write_json(
            dir.path(),
            Split::Train,
            &frames_json(&["./train/a", "./train/b.png", "train/c"]),
        );
        let data = load_split(dir.path(), Split::Train, 1, true).unwrap();
        let imgs: Vec<&Vec<[f32; 3]>> = data
            .views
            .iter()
            .map(|v| v.image.as_ref().unwrap())
            .collect();
        assert_eq!(imgs[0][1], [0.0, 1.0, 0.0]);
        assert_eq!(imgs[0][3], [0.2, 0.2, 0.2]);
        assert_eq!(imgs[1][1], [0.2, 0.2, 0.2]);
        assert!((imgs[2][0][0] - (1.0 - 32768.0 / 65535.0)).abs() < 1e-6);
        assert_eq!(data.views[1].name, "b");
        assert_eq!(data.views[2].pose.origin().x, 2.0);
    }

    #[test]
    fn size_without_images_from_split_or_train() {
        let dir = tempfile::tempdir().unwrap();
        write_rgba8(&dir.path().join("train/r_0.png"), 8, 6, |_, _| [0, 0, 0, 0]);
        write_json(dir.path(), Split::Train, &frames_json(&["./train/r_0"]));
        // The test split's images are not there: the size comes from the train split.
        write_json(
            dir.path(),
            Split::Test,
            &frames_json(&["./test/r_0", "./test/r_1"]),
        );
        let test = load_split(dir.path(), Split::Test, 2, false).unwrap();
        assert_eq!((test.camera().unwrap().width, test.camera().unwrap().height), (4, 3));
        assert_eq!(test.views.len(), 2);
        assert!(test.views.iter().all(|v| v.image.is_none()));
        assert_eq!(test.views[1].name, "r_1");
        // Its second image exists: the size comes from it.
        write_rgba8(&dir.path().join("test/r_1.png"), 10, 4, |_, _| {
            [0, 0, 0, 255]
        });
        let test = load_split(dir.path(), Split::Test, 1, false).unwrap();
        assert_eq!((test.camera().unwrap().width, test.camera().unwrap().height), (10, 4));
        // Loading test pixels needs all of them.
        let err = load_split(dir.path(), Split::Test, 1, true)
            .unwrap_err()
            .to_string();
        assert!(err.contains("r_0.png"), "{err}");
        // Not divisible: names the probed file.
        let err = load_split(dir.path(), Split::Test, 3, false)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("r_1.png") && err.contains("not divisible by the downscale factor 3"),
            "{err}"
        );
        // No image anywhere.
        std::fs::remove_file(dir.path().join("train/r_0.png")).unwrap();
        write_json(dir.path(), Split::Val, &frames_json(&["./val/r_0"]));
        let err = load_split(dir.path(), Split::Val, 1, false)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("transforms_val.json") && err.contains("image size is unknown"),
            "{err}"
        );
    }

    #[test]
    fn errors_name_the_file_and_problem() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let msg = |r: Result<SplitData>| r.unwrap_err().to_string();

        let err = msg(load_split(d, Split::Train, 1, true));
        assert!(err.contains("transforms_train.json"), "{err}");

        write_json(d, Split::Train, "{\"camera_angle_x\": 0.7, \"frames\": [");
        let err = msg(load_split(d, Split::Train, 1, true));
        assert!(
            err.contains("transforms_train.json") && err.contains("invalid JSON"),
            "{err}"
        );

        write_json(d, Split::Train, r#"{"frames": []}"#);
        let err = msg(load_split(d, Split::Train, 1, true));
        assert!(err.contains("camera_angle_x"), "{err}");

        write_json(
            d,
            Split::Train,
            r#"{"camera_angle_x": 0.7, "frames": [{"file_path": "./train/r_0", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0]]}]}"#,
        );
        let err = msg(load_split(d, Split::Train, 1, true));
        assert!(
            err.contains("transforms_train.json") && err.contains("invalid JSON"),
            "{err}"
        );

        write_json(d, Split::Train, r#"{"camera_angle_x": 0.7, "frames": []}"#);
        let err = msg(load_split(d, Split::Train, 1, true));
        assert!(err.contains("\"frames\" is empty"), "{err}");

        let mut text = frames_json(&["./train/r_0", "./train/r_1", "./train/r_2", "./train/r_3"]);
        text = text.replacen("[[1,0,0,3]", "[[1e300,0,0,3]", 1);
        write_json(d, Split::Train, &text);
        let err = msg(load_split(d, Split::Train, 1, true));
        assert!(
            err.contains("frame 3 (./train/r_3): transform_matrix has a non-finite entry"),
            "{err}"
        );
        assert!(err.contains("transforms_train.json"), "{err}");

        write_json(
            d,
            Split::Train,
            &frames_json(&["./train/r_0", "./train/r_1", "./train/r_2"]),
        );
        write_rgba8(&d.join("train/r_0.png"), 4, 4, |_, _| [0, 0, 0, 255]);
        write_rgba8(&d.join("train/r_2.png"), 4, 4, |_, _| [0, 0, 0, 255]);
        let err = msg(load_split(d, Split::Train, 1, true));
        assert!(err.contains("r_1.png"), "{err}");
        assert!(err.contains("transforms_train.json: frame 1 (file_path \"./train/r_1\")"), "the frame that names it: {err}");

        write_rgba8(&d.join("train/r_1.png"), 2, 2, |_, _| [0, 0, 0, 255]);
        let err = msg(load_split(d, Split::Train, 1, true));
        assert!(
            err.contains(
                "r_1.png: image is 2×2 but the first image of the split (./train/r_0) is 4×4"
            ),
            "{err}"
        );

        std::fs::write(d.join("train/r_1.png"), b"garbage").unwrap();
        let err = msg(load_split(d, Split::Train, 1, true));
        assert!(err.contains("r_1.png"), "{err}");

        write_rgba8(&d.join("train/r_1.png"), 4, 4, |_, _| [0, 0, 0, 255]);
        assert_eq!(
            load_split(d, Split::Train, 4, true)
                .unwrap()
                .camera()
                .unwrap()
                .width,
            1
        );
        let err = msg(load_split(d, Split::Train, 3, true));
        assert!(
            err.contains("r_0.png") && err.contains("not divisible"),
            "{err}"
        );
        let err = msg(load_split(d, Split::Train, 0, true));
        assert!(
            err.contains("downscale factor 0") && err.contains("transforms_train.json"),
            "{err}"
        );
    }
}
