//! The one entry point for `--data DIR`, used by every command: detect (or take) the format,
//! parse it (Blender `transforms_{split}.json`, instant-ngp/nerfstudio `transforms.json`, LLFF
//! `poses_bounds.npy`), place the poses in the field's frame (fitted when a run starts, the
//! run's recorded transform afterwards), and decode the split's images the same way for all.

use std::path::Path;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::blender::load_blender;
use super::capture::{Capture, CaptureFormat, CaptureSplit, detect_format};
use super::images::{Background, Decoded, check_divisible, load_image};
use super::instant_ngp::load_instant_ngp;
use super::llff::load_llff;
use super::scene_fit::{CameraPath, OrbitPath, SpiralPath, contracted_near_far, contraction_by_default, field_near_far, fit_contracted, fit_to_field};
use super::{Split, SplitData, View};
use crate::error::{Error, Result};
use crate::camera::ndc::Ndc;
use crate::camera::transform::SceneTransform;

/// Which frame the poses are returned in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SceneFrame {
    /// Fit the capture into the cube `[−bound, bound]³` ([`fit_to_field`]): a run starting.
    Fit {
        /// The field's half-size (the occupancy grid's bound).
        bound: f32,
        /// NDC rays: `Some(true)`/`Some(false)` as asked, `None` for LLFF captures whose
        /// cameras all face one way ([`Capture::forward_facing`]), as nerf-pytorch's default.
        ndc: Option<bool>,
        /// A contracted field ([`fit_contracted`]): no NDC, the cameras inside the inner cube.
        contraction: Option<crate::sample::Contraction>,
    },
    /// The transform a run or bundle recorded, from the file's world: everything after the
    /// run started (evaluation data never changes it).
    Recorded(SceneTransform),
}

/// How to read a dataset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoadOptions {
    /// The format; `None` detects it from the files ([`detect_format`]).
    pub format: Option<CaptureFormat>,
    /// Integer image downscale factor (area averaging); cameras scale to match.
    pub downscale: u32,
    /// Decode the images (else poses and cameras only).
    pub images: bool,
    /// What transparent pixels are composited on.
    pub background: Background,
    /// The frame of the returned poses.
    pub frame: SceneFrame,
}

/// What a run records about its data's placement (`source.json`, `scene.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScenePlacement {
    /// The format the data was read as.
    pub format: CaptureFormat,
    /// The file's world → the field's frame.
    pub transform: SceneTransform,
    /// Near and far for the field (captures; Blender keeps the configured 2, 6). With NDC
    /// rays, (0, 1).
    pub near_far: Option<(f32, f32)>,
    /// The camera path for renders of the capture (Blender keeps the reference orbit): a
    /// circle around the cameras, or a spiral in front of forward-facing ones.
    pub orbit: Option<CameraPath>,
    /// NDC rays (forward-facing captures): the projection, in the field's frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ndc: Option<Ndc>,
}

/// A loaded split and where its scene sits.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// The views of the split, poses in the field's frame.
    pub data: SplitData,
    /// The placement in force (with `Fit`: the one just decided).
    pub placement: ScenePlacement,
    /// Things skipped while parsing (missing images...), for the CLI to print.
    pub warnings: Vec<String>,
}

/// Loads `split` of the dataset in `dir` as `options` say.
///
/// Blender: the split's `transforms_{split}.json` (`all`: train, val and test in turn), poses
/// as written (its scenes are made for the cube) unless a recorded transform says otherwise.
/// instant-ngp and LLFF: test = every 8th frame (or the file's own lists), train = the rest,
/// val = test, all = every frame; frames whose image is missing are skipped with a warning.
///
/// Errors name the file: everything the parsers refuse, a size not divisible by `downscale`,
/// an image whose size differs from its camera's, a capture that cannot be fitted.
pub fn load_dataset(dir: &Path, split: CaptureSplit, options: &LoadOptions) -> Result<Dataset> {
    if options.downscale == 0 {
        return Err(Error::Argument(format!("downscale factor 0 for {}: it must be at least 1", dir.display())));
    }
    let format = match options.format {
        Some(f) => f,
        None => detect_format(dir)?,
    };
    match format {
        CaptureFormat::Blender => load_blender_dataset(dir, split, options),
        CaptureFormat::InstantNgp => load_capture_dataset(load_instant_ngp(dir)?, split, options),
        CaptureFormat::Llff => load_capture_dataset(load_llff(dir)?, split, options),
    }
}

/// Why a new run on the capture in `dir` (read as `format`, NDC as `ndc` asks) contracts its
/// world when not told either way ([`contraction_by_default`]); `None` keeps the cube, always
/// for Blender scenes. Reads the poses only.
pub fn default_contraction(dir: &Path, format: CaptureFormat, ndc: Option<bool>) -> Result<Option<String>> {
    let capture = match format {
        CaptureFormat::Blender => return Ok(None),
        CaptureFormat::InstantNgp => load_instant_ngp(dir)?,
        CaptureFormat::Llff => load_llff(dir)?,
    };
    Ok(contraction_by_default(&capture, trains_on_ndc(&capture, ndc)))
}

/// NDC rays as asked, else nerf-pytorch's default: LLFF captures whose cameras all face one way.
fn trains_on_ndc(capture: &Capture, ndc: Option<bool>) -> bool {
    ndc.unwrap_or(capture.format == CaptureFormat::Llff && capture.forward_facing)
}

fn load_blender_dataset(dir: &Path, split: CaptureSplit, options: &LoadOptions) -> Result<Dataset> {
    let splits: &[Split] = match split {
        CaptureSplit::Train => &[Split::Train],
        CaptureSplit::Val => &[Split::Val],
        CaptureSplit::Test => &[Split::Test],
        CaptureSplit::All => &Split::ALL,
    };
    let mut views = Vec::new();
    for &s in splits {
        views.extend(load_blender(dir, s, options.downscale, options.images, options.background)?.views);
    }
    let transform = match options.frame {
        SceneFrame::Fit { .. } => SceneTransform::identity(),
        SceneFrame::Recorded(t) => t,
    };
    if transform != SceneTransform::identity() {
        for v in &mut views {
            v.pose = transform.apply_pose(&v.pose);
        }
    }
    let placement = ScenePlacement { format: CaptureFormat::Blender, transform, near_far: None, orbit: None, ndc: None };
    Ok(Dataset { data: SplitData { split, views }, placement, warnings: vec![] })
}

fn load_capture_dataset(mut capture: Capture, split: CaptureSplit, options: &LoadOptions) -> Result<Dataset> {
    let placement = match options.frame {
        SceneFrame::Fit { ndc: Some(true), contraction: Some(_), .. } => {
            return Err(Error::invalid(&capture.source, "NDC rays and a contracted field exclude each other: train without --ndc or without --contract"));
        }
        SceneFrame::Fit { contraction: Some(_), .. } => {
            let fit = fit_contracted(&capture)?;
            capture.renormalise(&fit);
            let orbit = OrbitPath::around(&capture.poses()).map(CameraPath::Circle);
            ScenePlacement { format: capture.format, transform: capture.transform, near_far: Some(contracted_near_far(&capture)), orbit, ndc: None }
        }
        SceneFrame::Fit { ndc, .. } if trains_on_ndc(&capture, ndc) => {
            ndc_placement(&capture)?
        }
        SceneFrame::Fit { bound, .. } => {
            let fit = fit_to_field(&capture, bound)?;
            capture.renormalise(&fit);
            let orbit = OrbitPath::around(&capture.poses()).map(CameraPath::Circle);
            ScenePlacement { format: capture.format, transform: capture.transform, near_far: Some(field_near_far(&capture, bound)), orbit, ndc: None }
        }
        SceneFrame::Recorded(recorded) => {
            // From the parser's frame back to the file's world, then the recorded mapping.
            let parsed = capture.transform;
            for v in &mut capture.views {
                v.pose = recorded.apply_pose(&parsed.invert_pose(&v.pose));
            }
            ScenePlacement { format: capture.format, transform: recorded, near_far: None, orbit: None, ndc: None }
        }
    };
    let d = options.downscale;
    let chosen: Vec<_> = capture.split_indices(split).into_iter().map(|k| &capture.views[k]).collect();
    for v in &chosen {
        check_divisible(&v.image_path, v.camera.width, v.camera.height, d)?;
    }
    let images: Vec<(Option<Vec<[f32; 3]>>, Option<Vec<f32>>)> = if options.images {
        let decoded: Vec<Result<Decoded>> = chosen
            .par_iter()
            .map(|v| {
                let decoded = load_image(&v.image_path, d, options.background)?;
                if (decoded.width, decoded.height) != (v.camera.width, v.camera.height) {
                    let problem = format!("image is {}×{} but its camera is {}×{}", decoded.width, decoded.height, v.camera.width, v.camera.height);
                    return Err(Error::invalid(&v.image_path, problem));
                }
                Ok(decoded)
            })
            .collect();
        decoded.into_iter().map(|r| r.map(|d| (Some(d.rgb), d.alpha))).collect::<Result<_>>()?
    } else {
        vec![(None, None); chosen.len()]
    };
    let views = chosen
        .iter()
        .zip(images)
        .map(|(v, (image, alpha))| View {
            name: v.name.clone(),
            file_path: v.image_path.display().to_string(),
            camera: v.camera.resized(v.camera.width / d, v.camera.height / d),
            pose: v.pose,
            image,
            alpha,
        })
        .collect();
    Ok(Dataset { data: SplitData { split, views }, placement, warnings: capture.warnings })
}

/// NDC placement, as nerf-pytorch for LLFF: the poses stay in the parser's frame (recentred,
/// nearest bound at 1/0.75), the near plane is z = −1 in front of the average camera, the
/// projection is the first camera's, and rays sample t in [0, 1]. Needs the file's depth
/// bounds: without them nothing says where the near plane may go.
fn ndc_placement(capture: &Capture) -> Result<ScenePlacement> {
    let (Some((near, far)), Some(first)) = (capture.near_far, capture.views.first()) else {
        return Err(Error::invalid(&capture.source, "NDC rays need depth bounds (LLFF poses_bounds.npy) and at least one view; train without --ndc"));
    };
    let ndc = Ndc::for_camera(&first.camera, NDC_NEAR);
    if !(near > NDC_NEAR && ndc.is_valid()) {
        let problem = format!("NDC rays need all content beyond the near plane z = -{NDC_NEAR}, but the nearest bound is {near}; train without --ndc");
        return Err(Error::invalid(&capture.source, problem));
    }
    let orbit = SpiralPath::around(&capture.poses(), near, far).map(CameraPath::Spiral);
    Ok(ScenePlacement { format: capture.format, transform: capture.transform, near_far: Some((0.0, 1.0)), orbit, ndc: Some(ndc) })
}

/// nerf-pytorch's near plane for NDC rays (`ndc_rays(H, W, K[0][0], 1., rays_o, rays_d)`).
const NDC_NEAR: f32 = 1.0;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::{SyntheticSceneConfig, generate_scene};
    use glam::Vec3;

    fn options(frame: SceneFrame, downscale: u32, background: Background) -> LoadOptions {
        LoadOptions { format: None, downscale, images: true, background, frame }
    }

    /// A transforms.json of 10 frames on a ring of radius 3 about (5, 0, 0) looking at it,
    /// aabb_scale 2, 4×2 RGBA images (frame 3's image missing; half the paths without
    /// extension). Pixel (0, 0) of each image is half-transparent red.
    fn ngp_capture(dir: &Path) {
        let mut frames = Vec::new();
        for k in 0..10 {
            let a = k as f32 * std::f32::consts::TAU / 10.0;
            let o = Vec3::new(5.0 + 3.0 * a.cos(), 0.0, 3.0 * a.sin());
            let back = (o - Vec3::new(5.0, 0.0, 0.0)).normalize();
            let right = Vec3::Y.cross(back).normalize();
            let up = back.cross(right);
            let m = [[right.x, up.x, back.x, o.x], [right.y, up.y, back.y, o.y], [right.z, up.z, back.z, o.z], [0.0, 0.0, 0.0, 1.0]];
            let path = if k % 2 == 0 { format!("images/{k:02}.png") } else { format!("images/{k:02}") };
            frames.push(serde_json::json!({"file_path": path, "transform_matrix": m}));
            if k != 3 {
                std::fs::create_dir_all(dir.join("images")).unwrap();
                image::RgbaImage::from_fn(4, 2, |i, j| image::Rgba(if (i, j) == (0, 0) { [255, 0, 0, 128] } else { [0, 0, 255, 255] }))
                    .save(dir.join(format!("images/{k:02}.png")))
                    .unwrap();
            }
        }
        let file = serde_json::json!({"fl_x": 4.0, "fl_y": 3.0, "cx": 2.5, "cy": 1.0, "w": 4, "h": 2, "k1": 0.1, "aabb_scale": 2, "frames": frames});
        std::fs::write(dir.join("transforms.json"), file.to_string()).unwrap();
    }

    #[test]
    fn captures_split_every_eighth_skip_missing_images_and_composite() {
        let dir = tempfile::tempdir().unwrap();
        ngp_capture(dir.path());
        let fit = SceneFrame::Fit { bound: 1.5, ndc: None, contraction: None };
        let all = load_dataset(dir.path(), CaptureSplit::All, &options(fit, 1, Background::White)).unwrap();
        // 9 of 10 frames have an image; the missing one is named in a warning.
        assert_eq!(all.data.views.len(), 9);
        assert!(all.warnings.len() == 1 && all.warnings[0].contains("03"), "{:?}", all.warnings);
        assert_eq!(all.placement.format, CaptureFormat::InstantNgp);
        // A ring is not forward-facing: no NDC unless asked, and asked without depth bounds
        // it is refused naming the file.
        assert_eq!(all.placement.ndc, None);
        let forced = options(SceneFrame::Fit { bound: 1.5, ndc: Some(true), contraction: None }, 1, Background::White);
        let err = load_dataset(dir.path(), CaptureSplit::All, &forced).unwrap_err().to_string();
        assert!(err.contains("transforms.json") && err.contains("NDC rays need depth bounds"), "{err}");
        // Test = views 0 and 8 of the 9 (files 00 and 09), train the other 7, val = test.
        let test = load_dataset(dir.path(), CaptureSplit::Test, &options(fit, 1, Background::White)).unwrap();
        let names: Vec<&str> = test.data.views.iter().map(|v| v.name.as_str()).collect();
        assert_eq!(names, ["00", "09"]);
        let val = load_dataset(dir.path(), CaptureSplit::Val, &options(fit, 1, Background::White)).unwrap();
        assert_eq!(val.data.views, test.data.views);
        assert_eq!(load_dataset(dir.path(), CaptureSplit::Train, &options(fit, 1, Background::White)).unwrap().data.views.len(), 7);
        // Half-transparent red (128/255) on white and on black.
        let a = 128.0 / 255.0;
        let white = test.data.views[0].image.as_ref().unwrap()[0];
        assert!((white[0] - 1.0).abs() < 1e-6 && (white[1] - (1.0 - a)).abs() < 1e-6, "{white:?}");
        let black = load_dataset(dir.path(), CaptureSplit::Test, &options(fit, 1, Background::Black)).unwrap();
        assert_eq!(black.data.views[0].image.as_ref().unwrap()[0], [a, 0.0, 0.0]);
        // The camera as the file gives it, halved with --downscale 2 (distortion unchanged).
        let cam = test.data.views[0].camera;
        assert_eq!((cam.fx, cam.fy, cam.cx, cam.cy, cam.distortion.unwrap().k1), (4.0, 3.0, 2.5, 1.0, 0.1));
        let half = load_dataset(dir.path(), CaptureSplit::Test, &options(fit, 2, Background::White)).unwrap();
        let c = half.data.views[0].camera;
        assert_eq!((c.width, c.height, c.fx, c.fy, c.cx, c.cy), (2, 1, 2.0, 1.5, 1.25, 0.5));
        assert_eq!(half.data.views[0].image.as_ref().unwrap().len(), 2);
        let err = load_dataset(dir.path(), CaptureSplit::Test, &options(fit, 3, Background::White)).unwrap_err().to_string();
        assert!(err.contains("00.png") && err.contains("not divisible by the downscale factor 3"), "{err}");
    }

    #[test]
    fn a_contracted_fit_puts_the_farthest_camera_on_the_unit_sphere() {
        let dir = tempfile::tempdir().unwrap();
        ngp_capture(dir.path());
        let contraction = Some(crate::sample::Contraction::Linf);
        let fit = load_dataset(dir.path(), CaptureSplit::All, &options(SceneFrame::Fit { bound: 1.5, ndc: None, contraction }, 1, Background::White)).unwrap();
        let farthest = fit.data.views.iter().map(|v| v.pose.origin().length()).fold(0.0f32, f32::max);
        assert!((farthest - 1.0).abs() < 1e-5, "farthest camera at {farthest}: aabb_scale is not used");
        assert_eq!(fit.placement.near_far, Some((1.0 / 30.0, 100.0)));
        assert_eq!(fit.placement.ndc, None);
        let both = options(SceneFrame::Fit { bound: 1.5, ndc: Some(true), contraction }, 1, Background::White);
        let err = load_dataset(dir.path(), CaptureSplit::All, &both).unwrap_err().to_string();
        assert!(err.contains("transforms.json") && err.contains("exclude each other"), "{err}");
    }

    #[test]
    fn the_fit_is_recorded_and_a_recorded_transform_is_used_as_is() {
        let dir = tempfile::tempdir().unwrap();
        ngp_capture(dir.path());
        let fit = load_dataset(dir.path(), CaptureSplit::All, &options(SceneFrame::Fit { bound: 1.5, ndc: None, contraction: None }, 1, Background::White)).unwrap();
        let p = &fit.placement;
        // instant-ngp's default mapping (scale 0.33, offset 0.5), then aabb_scale 2 → ±1.5: ×1.5.
        assert!((p.transform.scale - 0.33 * 1.5).abs() < 1e-6, "{:?}", p.transform);
        // The ring's centre (5, 0, 0) lands at 0.495·5 = 2.475 on x (instant-ngp does not recentre).
        assert!((p.transform.apply_point(Vec3::new(5.0, 0.0, 0.0)) - Vec3::new(2.475, 0.0, 0.0)).length() < 1e-4);
        let (near, far) = p.near_far.unwrap();
        assert!(near > 0.0 && far > near);
        // The orbit circles the 9 cameras (ring radius 3·0.495, centroid a little off the
        // ring's centre as one camera is missing) and looks where their axes meet.
        let Some(CameraPath::Circle(orbit)) = p.orbit else { panic!("{:?}", p.orbit) };
        assert!((1.4..1.5).contains(&orbit.radius), "{orbit:?}");
        assert!((Vec3::from(orbit.target) - Vec3::new(2.475, 0.0, 0.0)).length() < 1e-3, "{orbit:?}");
        // Loading again with the recorded transform gives the same poses.
        let again = load_dataset(dir.path(), CaptureSplit::All, &options(SceneFrame::Recorded(p.transform), 1, Background::White)).unwrap();
        for (a, b) in again.data.views.iter().zip(&fit.data.views) {
            assert!((a.pose.origin() - b.pose.origin()).length() < 1e-5);
            assert!((a.pose.rotation().z_axis - b.pose.rotation().z_axis).length() < 1e-5);
        }
        // Any other recorded transform is applied to the file's poses, not refitted.
        let other = SceneTransform { scale: 2.0, rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], translation: [-5.0, 0.0, 0.0] };
        let moved = load_dataset(dir.path(), CaptureSplit::All, &options(SceneFrame::Recorded(other), 1, Background::White)).unwrap();
        // File 00 sits at (8, 0, 0): 2·(8 − 5) = 6.
        assert!((moved.data.views[0].pose.origin() - Vec3::new(6.0, 0.0, 0.0)).length() < 1e-4);
        assert_eq!((moved.placement.transform, moved.placement.near_far), (other, None));
    }

    #[test]
    fn blender_all_is_every_split_and_formats_can_be_forced() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = SyntheticSceneConfig { width: 8, height: 8, n_train: 3, n_val: 2, n_test: 1, ..Default::default() };
        generate_scene(dir.path(), &cfg).unwrap();
        let o = options(SceneFrame::Fit { bound: 1.5, ndc: None, contraction: None }, 1, Background::White);
        let all = load_dataset(dir.path(), CaptureSplit::All, &o).unwrap();
        assert_eq!(all.data.views.len(), 6);
        assert_eq!(all.placement.transform, SceneTransform::identity());
        let val = load_dataset(dir.path(), CaptureSplit::Val, &o).unwrap();
        assert_eq!(val.data.views, crate::dataset::load_split(dir.path(), Split::Val, 1, true).unwrap().views);
        // Forcing a format the directory does not hold names the missing file.
        let forced = LoadOptions { format: Some(CaptureFormat::Llff), ..o };
        let err = load_dataset(dir.path(), CaptureSplit::Val, &forced).unwrap_err().to_string();
        assert!(err.contains("poses_bounds.npy"), "{err}");
        let err = load_dataset(dir.path(), CaptureSplit::Val, &LoadOptions { downscale: 0, ..o }).unwrap_err().to_string();
        assert!(err.contains("downscale factor 0"), "{err}");
    }
}
