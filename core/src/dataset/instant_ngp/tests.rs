use super::*;
use crate::dataset::capture::CaptureSplit;
use glam::Vec3;

fn write_image(path: &Path, w: u32, h: u32) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    image::RgbImage::from_pixel(w, h, image::Rgb([200, 100, 50]))
        .save(path)
        .unwrap();
}

/// A frame at x = `k` looking down −z, with extra JSON fields `extra`.
fn frame(file_path: &str, k: usize, extra: &str) -> String {
    format!(
        r#"{{"file_path": "{file_path}", "transform_matrix": [[1,0,0,{k}],[0,1,0,0],[0,0,1,4],[0,0,0,1]]{extra}}}"#
    )
}

fn write_json(dir: &Path, top: &str, frames: &[String]) {
    std::fs::write(
        dir.join("transforms.json"),
        format!(r#"{{{top} "frames": [{}]}}"#, frames.join(",")),
    )
    .unwrap();
}

#[test]
fn shared_and_per_frame_intrinsics() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_image(&d.join("images/0001.jpg"), 8, 6);
    write_image(&d.join("images/0002.png"), 8, 6);
    write_image(&d.join("images/0003.png"), 4, 2);
    write_json(
        d,
        r#""fl_x": 10, "fl_y": 11, "cx": 4.2, "cy": 3.1, "w": 8, "h": 6, "k1": 0.1, "p2": 0.002, "aabb_scale": 4,"#,
        &[
            frame("images/0001.jpg", 0, ""),
            // No extension: resolved to .png.
            frame("./images/0002", 1, r#", "fl_x": 20, "k1": 0"#),
            frame(
                "images/0003.png",
                2,
                r#", "w": 4, "h": 2, "cx": 2, "cy": 1, "fl_x": 5, "fl_y": 5, "k1": 0, "p2": 0"#,
            ),
        ],
    );
    let c = load_instant_ngp(d).unwrap();
    assert_eq!(c.format, CaptureFormat::InstantNgp);
    assert_eq!(c.views.len(), 3);
    assert!(c.warnings.is_empty(), "{:?}", c.warnings);
    let cam = c.views[0].camera;
    assert_eq!(
        (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy),
        (8, 6, 10.0, 11.0, 4.2, 3.1)
    );
    assert_eq!(cam.pixel_center, PixelCenter::HalfPixel);
    assert_eq!(
        cam.distortion,
        Some(OpenCvDistortion {
            k1: 0.1,
            k2: 0.0,
            p1: 0.0,
            p2: 0.002
        })
    );
    // Frame 1 overrides fl_x and k1 only.
    let cam = c.views[1].camera;
    assert_eq!((cam.fx, cam.fy), (20.0, 11.0));
    assert_eq!(
        cam.distortion,
        Some(OpenCvDistortion {
            k1: 0.0,
            k2: 0.0,
            p1: 0.0,
            p2: 0.002
        })
    );
    assert_eq!(c.views[1].name, "0002");
    assert!(c.views[1].image_path.ends_with("images/0002.png"));
    // Frame 2 has its own size and no distortion left.
    let cam = c.views[2].camera;
    assert_eq!(
        (cam.width, cam.height, cam.fx, cam.cx, cam.distortion),
        (4, 2, 5.0, 2.0, None)
    );
    // aabb_scale without scale/offset: instant-ngp's defaults x·0.33 (+0.5 − 0.5).
    assert_eq!((c.aabb_scale, c.scale, c.offset), (Some(4.0), None, None));
    assert_eq!(c.transform, SceneTransform::instant_ngp(0.33, [0.5; 3]));
    assert!((c.views[2].pose.origin() - Vec3::new(0.66, 0.0, 1.32)).length() < 1e-6);
}

#[test]
fn camera_angle_fallback_and_image_size() {
    // No fl_x, w or h: focal from camera_angle_x at the image width; fy = fx without
    // camera_angle_y; principal point at the centre.
    let fields = CameraFields {
        camera_angle_x: Some(2.0 * 0.5f64.atan()),
        ..Default::default()
    };
    let cam = camera_from_fields(&fields, (40, 30)).unwrap();
    // 0.5·40 / tan(atan(0.5)) = 40.
    assert!((cam.fx - 40.0).abs() < 1e-4 && cam.fx == cam.fy, "{cam:?}");
    assert_eq!((cam.cx, cam.cy), (20.0, 15.0));
    let fields = CameraFields {
        camera_angle_y: Some(2.0 * 0.25f64.atan()),
        ..fields
    };
    // 0.5·30 / 0.25 = 60.
    assert!((camera_from_fields(&fields, (40, 30)).unwrap().fy - 60.0).abs() < 1e-4);
    let err = camera_from_fields(&CameraFields::default(), (4, 4)).unwrap_err();
    assert!(err.contains("no focal length"), "{err}");
    let f = CameraFields {
        fl_x: Some(5.0),
        w: Some(8.0),
        ..Default::default()
    };
    let err = camera_from_fields(&f, (4, 4)).unwrap_err();
    assert!(err.contains("w, h = 8×4 but the image is 4×4"), "{err}");
    let f = CameraFields {
        fl_x: Some(5.0),
        camera_model: Some("OPENCV_FISHEYE".into()),
        ..Default::default()
    };
    assert!(
        camera_from_fields(&f, (4, 4))
            .unwrap_err()
            .contains("OPENCV_FISHEYE")
    );
    let f = CameraFields {
        fl_x: Some(5.0),
        k3: Some(0.1),
        ..Default::default()
    };
    assert!(
        camera_from_fields(&f, (4, 4))
            .unwrap_err()
            .contains("k3 = 0.1")
    );
    let f = CameraFields {
        fl_x: Some(-5.0),
        ..Default::default()
    };
    assert!(
        camera_from_fields(&f, (4, 4))
            .unwrap_err()
            .contains("positive")
    );
}

#[test]
fn missing_images_are_skipped_with_warnings() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_image(&d.join("a.png"), 4, 4);
    write_image(&d.join("c.png"), 4, 4);
    write_json(
        d,
        r#""fl_x": 4,"#,
        &[
            frame("a.png", 0, ""),
            frame("b.png", 1, ""),
            frame("c", 2, ""),
            frame("d", 3, ""),
        ],
    );
    let c = load_instant_ngp(d).unwrap();
    let names: Vec<&str> = c.views.iter().map(|v| v.name.as_str()).collect();
    assert_eq!(names, ["a", "c"]);
    assert_eq!(c.warnings.len(), 2);
    assert!(
        c.warnings[0].contains("frame 1") && c.warnings[0].contains("b.png not found"),
        "{:?}",
        c.warnings
    );
    // No aabb_scale/scale/offset: centroid (1, 0, 4) to the origin, farthest camera at 1.
    assert!((c.views[0].pose.origin() - Vec3::new(-1.0, 0.0, 0.0)).length() < 1e-6);
    assert!((c.views[1].pose.origin() - Vec3::new(1.0, 0.0, 0.0)).length() < 1e-6);
    assert_eq!(c.transform.scale, 1.0);
    // Two cameras looking the same way: forward-facing.
    assert!(c.forward_facing);
    // A single camera cannot be scaled to fit: left as it is, with a warning.
    write_json(d, r#""fl_x": 4,"#, &[frame("a.png", 3, "")]);
    let c = load_instant_ngp(d).unwrap();
    assert_eq!(
        (c.transform, c.views[0].pose.origin()),
        (SceneTransform::identity(), Vec3::new(3.0, 0.0, 4.0))
    );
    assert!(
        c.warnings[0].contains("poses left unnormalised"),
        "{:?}",
        c.warnings
    );
    // No image at all is an error.
    std::fs::remove_file(d.join("a.png")).unwrap();
    std::fs::remove_file(d.join("c.png")).unwrap();
    let err = load_instant_ngp(d).unwrap_err().to_string();
    assert!(err.contains("no frame has its image (1 listed)"), "{err}");
}

#[test]
fn scale_offset_and_explicit_splits() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for k in 0..4 {
        write_image(&d.join(format!("{k}.png")), 4, 4);
    }
    let frames: Vec<String> = (0..5).map(|k| frame(&format!("{k}.png"), k, "")).collect();
    write_json(
        d,
        r#""fl_x": 4, "scale": 0.5, "offset": [0.5, 1.0, 0.5], "test_filenames": ["./1.png", "4.png"],"#,
        &frames,
    );
    let c = load_instant_ngp(d).unwrap();
    // x' = 0.5·x + offset − 0.5: frame 2 at (2, 0, 4) → (1, 0.5, 2).
    assert!((c.views[2].pose.origin() - Vec3::new(1.0, 0.5, 2.0)).length() < 1e-6);
    assert_eq!(
        (c.scale, c.offset, c.aabb_scale),
        (Some(0.5), Some([0.5, 1.0, 0.5]), None)
    );
    // 4.png is missing: skipped in the split with a warning; val = test; train = the rest.
    assert_eq!(c.split_indices(CaptureSplit::Test), vec![1]);
    assert_eq!(c.split_indices(CaptureSplit::Val), vec![1]);
    assert_eq!(c.split_indices(CaptureSplit::Train), vec![0, 2, 3]);
    assert_eq!(c.warnings.len(), 2, "{:?}", c.warnings);
    let bad = std::fs::read_to_string(d.join("transforms.json"))
        .unwrap()
        .replace("\"4.png\"]", "\"9.png\"]");
    std::fs::write(d.join("transforms.json"), bad).unwrap();
    let err = load_instant_ngp(d).unwrap_err().to_string();
    assert!(
        err.contains("test_filenames names \"9.png\", which is not a frame"),
        "{err}"
    );
}

#[test]
fn bad_files_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let msg = || load_instant_ngp(d).unwrap_err().to_string();
    assert!(msg().contains("transforms.json"), "{}", msg());
    write_image(&d.join("a.png"), 4, 4);
    std::fs::write(d.join("transforms.json"), r#"{"fl_x": 4, "frames": [}"#).unwrap();
    assert!(msg().contains("invalid JSON"), "{}", msg());
    write_json(d, r#""fl_x": 4,"#, &[]);
    assert!(msg().contains("\"frames\" is empty"), "{}", msg());
    let f =
        r#"{"file_path": "a.png", "transform_matrix": [[1,0,0],[0,1,0],[0,0,1]]}"#.to_string();
    write_json(d, r#""fl_x": 4,"#, &[f]);
    assert!(
        msg().contains("frame 0 (a.png): transform_matrix must be 4 rows of 4"),
        "{}",
        msg()
    );
    // Python's json writes a NaN pose as NaN, which is not JSON.
    let f = frame("a.png", 0, "").replace("[0,1,0,0]", "[0,NaN,0,0]");
    write_json(d, r#""fl_x": 4,"#, &[f]);
    assert!(
        msg().contains("transforms.json: line 1: NaN is not a finite number"),
        "{}",
        msg()
    );
    // A finite but huge entry that overflows f32 is caught as non-finite.
    let f = frame("a.png", 0, "").replace("[0,1,0,0]", "[0,1e300,0,0]");
    write_json(d, r#""fl_x": 4,"#, &[f]);
    assert!(
        msg().contains("frame 0 (a.png): transform_matrix has a non-finite entry"),
        "{}",
        msg()
    );
    write_json(d, r#""fl_x": 4, "w": 8,"#, &[frame("a.png", 0, "")]);
    assert!(msg().contains("frame 0 (a.png): w, h = 8×4"), "{}", msg());
    write_json(d, "", &[frame("a.png", 0, "")]);
    assert!(
        msg().contains("frame 0 (a.png): no focal length"),
        "{}",
        msg()
    );
    std::fs::write(d.join("a.png"), b"not an image").unwrap();
    write_json(d, r#""fl_x": 4,"#, &[frame("a.png", 0, "")]);
    assert!(msg().contains("a.png"), "{}", msg());
}

#[test]
fn resolve_image_tries_extensions() {
    let dir = tempfile::tempdir().unwrap();
    write_image(&dir.path().join("x/a.JPG"), 2, 2);
    assert_eq!(
        resolve_image(dir.path(), "./x/a"),
        Some(dir.path().join("x/a.JPG"))
    );
    assert_eq!(
        resolve_image(dir.path(), "x/a.JPG"),
        Some(dir.path().join("x/a.JPG"))
    );
    assert_eq!(resolve_image(dir.path(), "x/b"), None);
}
