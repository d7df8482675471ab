//! The capture parsers on the real captures in `../shared/data/real` (fox: instant-ngp
//! `transforms.json`; fern, bird: LLFF). Each test skips, saying so, when its data is absent.

use std::path::{Path, PathBuf};

use glam::Vec3;
use nerf_core::dataset::{
    Capture, CaptureFormat, CaptureSplit, centroid, detect_format, focus_point, load_instant_ngp,
    load_llff,
};
use nerf_core::{OpenCvDistortion, PixelCenter};

fn real(scene: &str) -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/real")
        .join(scene);
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("skipped: {} is not there", dir.display());
        None
    }
}

/// The unit viewing direction (−z axis) of each view.
fn view_dirs(c: &Capture) -> Vec<Vec3> {
    c.views
        .iter()
        .map(|v| (v.pose.rotation() * Vec3::NEG_Z).normalize())
        .collect()
}

/// cos of the angle between each camera's viewing direction and the direction to `target`.
fn cos_to(c: &Capture, target: Vec3) -> Vec<f32> {
    c.views
        .iter()
        .zip(view_dirs(c))
        .map(|(v, d)| d.dot((target - v.pose.origin()).normalize()))
        .collect()
}

/// Asserts that the last view's pose matches `expected` (3×4 rows) to 1e-5 (relative for the
/// translation, whose scale depends on the bounds).
fn assert_last_pose(c: &Capture, expected: [[f64; 4]; 3]) {
    let got = c.views.last().unwrap().pose.0;
    for (&g, e) in got.iter().flatten().zip(expected.iter().flatten()) {
        assert!(
            (g as f64 - e).abs() <= 1e-5 * e.abs().max(1.0),
            "{got:?} vs {expected:?}"
        );
    }
}

/// Decodes the first view's image and checks its size against its camera.
fn first_image_decodes(c: &Capture) {
    let view = &c.views[0];
    let pixels = view.load_rgba().unwrap();
    assert_eq!(pixels.len(), view.camera.num_pixels());
    // Real photos are not blank: the channels vary.
    let (lo, hi) = pixels
        .iter()
        .fold((1.0f32, 0.0f32), |(lo, hi), p| (lo.min(p[1]), hi.max(p[1])));
    assert!(
        hi - lo > 0.2,
        "{}: green only spans {lo}..{hi}",
        view.image_path.display()
    );
}

#[test]
fn fox_instant_ngp() {
    let Some(dir) = real("fox") else { return };
    assert_eq!(detect_format(&dir).unwrap(), CaptureFormat::InstantNgp);
    let c = load_instant_ngp(&dir).unwrap();
    // 62 frames listed, 45 images present: 17 skipped, each with a warning naming its file.
    assert_eq!(c.views.len(), 45);
    assert_eq!(c.warnings.len(), 17, "{:#?}", c.warnings);
    for missing in ["0005", "0016", "0113"] {
        assert!(
            c.warnings
                .iter()
                .any(|w| w.contains(&format!("images/{missing}.jpg not found"))),
            "{missing}"
        );
    }
    assert!(c.views.iter().all(|v| v.image_path.is_file()));
    let cam = c.views[0].camera;
    assert_eq!((cam.width, cam.height), (216, 384));
    assert_eq!(
        (cam.fx, cam.fy, cam.cx, cam.cy),
        (275.104, 274.898, 110.9116, 193.0536)
    );
    assert_eq!(cam.pixel_center, PixelCenter::HalfPixel);
    assert_eq!(
        cam.distortion,
        Some(OpenCvDistortion {
            k1: 0.0578421,
            k2: -0.0805099,
            p1: -0.000980296,
            p2: 0.00015575
        })
    );
    assert!(c.views.iter().all(|v| v.camera == cam));
    // instant-ngp's default mapping (scale 0.33, offset 0.5) and aabb_scale 4.
    assert_eq!((c.aabb_scale, c.scale, c.offset), (Some(4.0), None, None));
    assert_eq!(c.transform.scale, 0.33);
    // The cameras look at the origin (instant-ngp's recentring), not at their own centroid.
    let cos = cos_to(&c, Vec3::ZERO);
    assert!(
        cos.iter().all(|&x| x > 0.95),
        "min cos {:?}",
        cos.iter().fold(1.0f32, |a, &b| a.min(b))
    );
    let focus = focus_point(&c.poses()).unwrap();
    assert!(focus.length() < 0.3, "focus {focus}");
    // A handheld arc, not forward-facing (views spread over more than 45° from their mean).
    assert!(!c.forward_facing);
    // Cameras 3.8 to 6.4 from the origin in the file's units: 1.25 to 2.12 after the 0.33 scale.
    let dist: Vec<f32> = c.views.iter().map(|v| v.pose.origin().length()).collect();
    assert!(dist.iter().all(|&d| (1.2..2.2).contains(&d)), "{dist:?}");
    assert_eq!(c.split_indices(CaptureSplit::Test).len(), 6); // 0, 8, ..., 40
    first_image_decodes(&c);
}

#[test]
fn fern_llff_forward_facing() {
    let Some(dir) = real("fern") else { return };
    assert_eq!(detect_format(&dir).unwrap(), CaptureFormat::Llff);
    let c = load_llff(&dir).unwrap();
    let n = std::fs::read_dir(dir.join("images")).unwrap().count();
    assert_eq!(c.views.len(), n);
    assert_eq!(c.views[0].name, "image001");
    let cam = c.views[0].camera;
    assert_eq!(
        (cam.width, cam.height, cam.pixel_center, cam.distortion),
        (400, 300, PixelCenter::Integer, None)
    );
    assert!(
        (cam.fx - 323.4649).abs() < 1e-3 && cam.fx == cam.fy && (cam.cx, cam.cy) == (200.0, 150.0)
    );
    // Forward-facing: after recentring every camera looks within 25° of −z.
    assert!(c.forward_facing);
    assert!(
        view_dirs(&c)
            .iter()
            .all(|d| d.dot(Vec3::NEG_Z) > 25f32.to_radians().cos())
    );
    // bd_factor: the nearest bound becomes 1/0.75; nerf-pytorch's no-NDC near = 0.9 × that.
    let (near, far) = c.near_far.unwrap();
    assert!(
        (near - 0.9 / 0.75).abs() < 1e-4 && far > 3.0 * near,
        "{near} {far}"
    );
    // Recentred: the average camera sits at the origin.
    assert!(centroid(&c.poses()).length() < 1e-4);
    assert_eq!(
        c.split_indices(CaptureSplit::Test),
        (0..n).step_by(8).collect::<Vec<_>>()
    );
    // nerf-pytorch's pipeline in numpy (`scripts/llff_reference.py ../shared/data/real/fern`).
    assert_last_pose(
        &c,
        [
            [0.98934262, 0.04736213, -0.13768839, -0.34887284],
            [-0.05288937, 0.99792338, -0.03676361, -0.12545621],
            [0.13566127, 0.04365406, 0.98979312, -0.03917920],
        ],
    );
    assert!((far - 6.186652).abs() < 1e-4, "{far}");
    first_image_decodes(&c);
}

#[test]
fn bird_llff_360() {
    let Some(dir) = real("bird") else { return };
    let c = load_llff(&dir).unwrap();
    assert_eq!(c.views.len(), 161);
    let cam = c.views[0].camera;
    assert_eq!((cam.width, cam.height), (221, 390));
    assert!((cam.fx - 368.0189).abs() < 1e-3, "{}", cam.fx);
    // A ring of inward-looking cameras: not forward-facing, looking at their centroid.
    assert!(!c.forward_facing);
    let cos = cos_to(&c, centroid(&c.poses()));
    let mean = cos.iter().sum::<f32>() / cos.len() as f32;
    assert!(mean > 0.95, "mean cos to centroid {mean}");
    let focus = focus_point(&c.poses()).unwrap();
    // The ring sits above the bird: the point the axes meet is below the cameras' centroid,
    // by less than a third of the ring's radius, and the cameras look at it more exactly.
    let mean_radius = c
        .views
        .iter()
        .map(|v| (v.pose.origin() - centroid(&c.poses())).length())
        .sum::<f32>()
        / 161.0;
    assert!(
        (focus - centroid(&c.poses())).length() < mean_radius / 3.0,
        "focus {focus}, radius {mean_radius}"
    );
    let cos_focus = cos_to(&c, focus);
    assert!(
        cos_focus.iter().sum::<f32>() / 161.0 > mean,
        "{cos_focus:?}"
    );
    assert_eq!(c.split_indices(CaptureSplit::Train).len(), 161 - 21);
    // nerf-pytorch's pipeline in numpy (`scripts/llff_reference.py ../shared/data/real/bird`).
    assert_last_pose(
        &c,
        [
            [0.99164861, 0.09078091, -0.09160747, -0.64613488],
            [-0.12824268, 0.76938118, -0.62578459, -6.50176981],
            [0.01367178, 0.63230640, 0.77459777, 5.57915776],
        ],
    );
    let (near, far) = c.near_far.unwrap();
    assert!(
        (near - 1.2).abs() < 1e-5 && (far - 167.24155).abs() < 1e-2,
        "{near} {far}"
    );
    first_image_decodes(&c);
}
