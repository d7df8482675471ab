use super::*;
use crate::camera::PixelCenter;

#[test]
fn holdout_is_every_eighth_from_the_first() {
    assert_eq!(holdout_split(17, 8, CaptureSplit::Test), vec![0, 8, 16]);
    assert_eq!(holdout_split(17, 8, CaptureSplit::Val), vec![0, 8, 16]);
    let train = holdout_split(17, 8, CaptureSplit::Train);
    assert_eq!(train.len(), 14);
    assert!(!train.contains(&8) && train.contains(&1) && train.contains(&15));
    assert_eq!(holdout_split(3, 8, CaptureSplit::All), vec![0, 1, 2]);
    assert_eq!(holdout_split(0, 8, CaptureSplit::Test), Vec::<usize>::new());
}

#[test]
fn split_names_parse() {
    for (s, v) in [
        ("train", CaptureSplit::Train),
        ("val", CaptureSplit::Val),
        ("test", CaptureSplit::Test),
        ("all", CaptureSplit::All),
    ] {
        assert_eq!(s.parse::<CaptureSplit>().unwrap(), v);
        assert_eq!(v.to_string(), s);
    }
    let err = "everything"
        .parse::<CaptureSplit>()
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("\"everything\"") && err.contains("all"),
        "{err}"
    );
    assert_eq!(CaptureSplit::from(Split::Val), CaptureSplit::Val);
    assert_eq!(
        "nerfstudio".parse::<CaptureFormat>().unwrap(),
        CaptureFormat::InstantNgp
    );
    assert!("colmap".parse::<CaptureFormat>().is_err());
}

#[test]
fn detects_formats_by_their_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let err = detect_format(d).unwrap_err().to_string();
    assert!(
        err.contains("no dataset found") && err.contains("poses_bounds.npy"),
        "{err}"
    );
    std::fs::write(d.join("poses_bounds.npy"), b"").unwrap();
    assert_eq!(detect_format(d).unwrap(), CaptureFormat::Llff);
    std::fs::write(d.join("transforms.json"), b"{}").unwrap();
    assert_eq!(detect_format(d).unwrap(), CaptureFormat::InstantNgp);
    std::fs::write(d.join("transforms_train.json"), b"{}").unwrap();
    assert_eq!(detect_format(d).unwrap(), CaptureFormat::Blender);
    let err = detect_format(&d.join("nope")).unwrap_err().to_string();
    assert!(
        err.contains("nope") && err.contains("not a directory"),
        "{err}"
    );
}

/// A camera at `origin` looking at `target`, +y roughly up.
pub(crate) fn look_at(origin: Vec3, target: Vec3) -> Pose {
    let back = (origin - target).normalize();
    let right = Vec3::Y.cross(back).normalize();
    let up = back.cross(right);
    crate::camera::transform::pose_from(Mat3::from_cols(right, up, back), origin)
}

/// `n` cameras on a circle of radius 4 about `target`, 0.5 above it, looking at it.
fn ring(n: usize, target: Vec3) -> Vec<Pose> {
    (0..n)
        .map(|k| {
            let a = k as f32 * std::f32::consts::TAU / n as f32;
            look_at(
                target + Vec3::new(4.0 * a.cos(), 0.5, 4.0 * a.sin()),
                target,
            )
        })
        .collect()
}

#[test]
fn ring_is_not_forward_facing_and_has_a_focus() {
    let target = Vec3::new(1.0, 2.0, 3.0);
    let ring = ring(12, target);
    assert!(!is_forward_facing(&ring, FORWARD_FACING_MAX_DEG));
    let f = focus_point(&ring).unwrap();
    assert!((f - target).length() < 1e-3, "{f}");
    assert!((centroid(&ring) - (target + Vec3::new(0.0, 0.5, 0.0))).length() < 1e-4);
    // A forward-facing rig: small spread of centres, all looking down −z within 10°.
    let rig: Vec<Pose> = (0..5)
        .map(|k| {
            let o = Vec3::new(k as f32 * 0.2, 0.0, 0.0);
            look_at(o, o + Vec3::new(0.1 * (k as f32 - 2.0), 0.0, -1.0))
        })
        .collect();
    assert!(is_forward_facing(&rig, FORWARD_FACING_MAX_DEG));
    assert!(!is_forward_facing(&rig, 5.0));
    assert!(!is_forward_facing(&[], 45.0));
    // Parallel axes have no focus point.
    let parallel: Vec<Pose> = (0..4)
        .map(|k| {
            look_at(
                Vec3::new(k as f32, 0.0, 0.0),
                Vec3::new(k as f32, 0.0, -1.0),
            )
        })
        .collect();
    assert_eq!(focus_point(&parallel), None);
}

/// A capture of `poses` with bounds (1, 4) everywhere and aabb_scale 4.
fn capture_of(poses: &[Pose]) -> Capture {
    let camera = PinholeCamera {
        width: 2,
        height: 2,
        fx: 1.0,
        fy: 1.0,
        cx: 1.0,
        cy: 1.0,
        pixel_center: PixelCenter::HalfPixel,
        distortion: None,
    };
    let view = |pose: &Pose| CaptureView {
        name: "v".into(),
        image_path: PathBuf::from("v.png"),
        camera,
        pose: *pose,
        bounds: Some((1.0, 4.0)),
    };
    Capture {
        format: CaptureFormat::InstantNgp,
        source: PathBuf::from("transforms.json"),
        views: poses.iter().map(view).collect(),
        transform: SceneTransform::identity(),
        near_far: Some((1.0, 4.0)),
        forward_facing: true,
        aabb_scale: Some(4.0),
        scale: None,
        offset: None,
        explicit_splits: None,
        warnings: vec![],
    }
}

#[test]
fn fit_cameras_centres_on_the_focus_point() {
    let target = Vec3::new(1.0, 2.0, 3.0);
    let ring = ring(8, target);
    let mut capture = capture_of(&ring);
    capture.fit_cameras(2.0).unwrap();
    // Centred on the target (not the centroid 0.5 above it); every camera at distance
    // √(16 + 0.25) = 4.03 → 2: scale 2/4.03.
    let s = 2.0 / 16.25f32.sqrt();
    assert!((capture.transform.scale - s).abs() < 1e-5);
    for (v, p) in capture.views.iter().zip(&ring) {
        let expected = (p.origin() - target) * s;
        assert!(
            (v.pose.origin() - expected).length() < 1e-4,
            "{:?}",
            v.pose.origin()
        );
    }
    // Bounds scale with the poses: (1, 4) → (s, 4s).
    let (near, far) = capture.views[0].bounds.unwrap();
    assert!((near - s).abs() < 1e-6 && (far - 4.0 * s).abs() < 1e-6);
    // The recorded transform maps the file's target to the origin.
    assert!(capture.transform.apply_point(target).length() < 1e-4);
    // Parallel cameras (no focus point) are centred on their centroid.
    let line: Vec<Pose> = (0..3)
        .map(|k| {
            look_at(
                Vec3::new(k as f32, 0.0, 0.0),
                Vec3::new(k as f32, 0.0, -1.0),
            )
        })
        .collect();
    let mut capture = capture_of(&line);
    capture.fit_cameras(1.0).unwrap();
    assert!((capture.views[2].pose.origin() - Vec3::X).length() < 1e-6);
    assert!(capture_of(&line[..1]).fit_cameras(1.0).is_err());
}

#[test]
fn explicit_splits_override_the_rule_and_renormalise_scales_bounds() {
    let line: Vec<Pose> = (0..10)
        .map(|k| {
            look_at(
                Vec3::new(k as f32, 0.0, 0.0),
                Vec3::new(k as f32, 0.0, -1.0),
            )
        })
        .collect();
    let mut capture = capture_of(&line);
    assert_eq!(capture.split_indices(CaptureSplit::Test), vec![0, 8]);
    assert_eq!(capture.split_indices(CaptureSplit::Train).len(), 8);
    capture.explicit_splits = Some(ExplicitSplits {
        train: vec![1, 2],
        val: vec![3],
        test: vec![4],
    });
    assert_eq!(capture.split_indices(CaptureSplit::Val), vec![3]);
    assert_eq!(capture.split_indices(CaptureSplit::All).len(), 10);
    let t = SceneTransform {
        scale: 0.5,
        rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        translation: [-1.0, 0.0, 0.0],
    };
    capture.renormalise(&t);
    assert_eq!(capture.views[3].pose.origin(), Vec3::new(1.0, 0.0, 0.0));
    assert_eq!(capture.views[3].bounds, Some((0.5, 2.0)));
    assert_eq!(
        (capture.near_far, capture.aabb_scale),
        (Some((0.5, 2.0)), Some(2.0))
    );
    assert_eq!(capture.transform, t);
}

#[test]
fn view_images_must_match_their_camera() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.png");
    image::RgbImage::from_raw(2, 1, vec![255, 0, 0, 0, 0, 51])
        .unwrap()
        .save(&path)
        .unwrap();
    let camera = PinholeCamera {
        width: 2,
        height: 1,
        fx: 1.0,
        fy: 1.0,
        cx: 1.0,
        cy: 0.5,
        pixel_center: PixelCenter::HalfPixel,
        distortion: None,
    };
    let mut view = CaptureView {
        name: view_name(&path),
        image_path: path,
        camera,
        pose: look_at(Vec3::Z, Vec3::ZERO),
        bounds: None,
    };
    assert_eq!(view.name, "a");
    assert_eq!(
        view.load_rgba().unwrap(),
        vec![[1.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.2, 1.0]]
    );
    view.camera.width = 4;
    let err = view.load_rgba().unwrap_err().to_string();
    assert!(
        err.contains("a.png: image is 2×1 but its camera is 4×1"),
        "{err}"
    );
}
