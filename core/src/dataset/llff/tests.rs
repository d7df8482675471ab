use super::*;
use crate::io::npy::{encode_npy, f8_bytes};

fn assert_close(a: Vec3, b: Vec3, tol: f32) {
    assert!((a - b).abs().max_element() <= tol, "{a:?} != {b:?}");
}

/// A row: LLFF columns down, right, back, centre given as world vectors.
fn row(
    down: [f64; 3],
    right: [f64; 3],
    back: [f64; 3],
    centre: [f64; 3],
    hwf: [f64; 3],
    bounds: [f64; 2],
) -> [f64; 17] {
    let mut r = [0.0; 17];
    for i in 0..3 {
        r[i * 5] = down[i];
        r[i * 5 + 1] = right[i];
        r[i * 5 + 2] = back[i];
        r[i * 5 + 3] = centre[i];
        r[i * 5 + 4] = hwf[i];
    }
    r[15] = bounds[0];
    r[16] = bounds[1];
    r
}

#[test]
fn columns_become_opengl_as_in_nerf_pytorch() {
    // down = −y, right = x, back = z (a camera looking down −z, y up in LLFF terms).
    let r = row(
        [0.0, -1.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
        [1.0, 2.0, 3.0],
        [300.0, 400.0, 320.0],
        [2.0, 9.0],
    );
    let c = llff_row(&r);
    // [right, −down, back] = [x, y, z]: the identity rotation.
    assert_eq!(
        c.pose,
        Pose([
            [1.0, 0.0, 0.0, 1.0],
            [0.0, 1.0, 0.0, 2.0],
            [0.0, 0.0, 1.0, 3.0]
        ])
    );
    assert_eq!((c.hwf, c.bounds), ([300.0, 400.0, 320.0], (2.0, 9.0)));
    // A general row: 3×5 row-major values 0..15; new columns [c1, −c0, c2, c3].
    let mut r = [0.0; 17];
    for (k, v) in r.iter_mut().enumerate() {
        *v = k as f64;
    }
    let c = llff_row(&r);
    assert_eq!(c.pose.0[0], [1.0, -0.0, 2.0, 3.0]);
    assert_eq!(c.pose.0[1], [6.0, -5.0, 7.0, 8.0]);
    assert_eq!(c.pose.0[2], [11.0, -10.0, 12.0, 13.0]);
    assert_eq!(c.hwf, [4.0, 9.0, 14.0]);
}

#[test]
fn poses_avg_and_recentering_match_hand_values() {
    // Two cameras looking down −z at x = 0 and x = 2 (identity rotations), and one turned
    // about y: the average centre is the mean, the average axes re-orthogonalised.
    let p = |x: f32| {
        Pose([
            [1.0, 0.0, 0.0, x],
            [0.0, 1.0, 0.0, 1.0],
            [0.0, 0.0, 1.0, 5.0],
        ])
    };
    let avg = poses_avg(&[p(0.0), p(2.0)]);
    assert_eq!(avg, p(1.0));
    let centred = recenter_poses(&[p(0.0), p(2.0)]);
    assert_close(centred[0].origin(), Vec3::new(-1.0, 0.0, 0.0), 1e-6);
    assert_close(centred[1].origin(), Vec3::new(1.0, 0.0, 0.0), 1e-6);
    // A rotated pair: z axes at ±30° about y sum to z; after recentering the average is I.
    let turned = |deg: f32, x: f32| {
        let r = Mat3::from_rotation_y(deg.to_radians());
        pose_from(r, Vec3::new(x, 0.0, 0.0))
    };
    let base = Mat3::from_rotation_x(0.3);
    let pair: Vec<Pose> = [turned(30.0, 0.0), turned(-30.0, 4.0)]
        .iter()
        .map(|q| {
            pose_from(
                base * q.rotation(),
                base * q.origin() + Vec3::new(0.0, 0.0, 7.0),
            )
        })
        .collect();
    let avg = poses_avg(&pair);
    assert_close(avg.rotation().z_axis, base * Vec3::Z, 1e-6);
    assert_close(
        avg.origin(),
        base * Vec3::new(2.0, 0.0, 0.0) + Vec3::new(0.0, 0.0, 7.0),
        1e-5,
    );
    let again = poses_avg(&recenter_poses(&pair));
    for (a, b) in again
        .0
        .iter()
        .flatten()
        .zip(Pose::from_mat4(glam::Mat4::IDENTITY).0.iter().flatten())
    {
        assert!((a - b).abs() < 1e-5, "{again:?}");
    }
    // The recentred cameras sit at ∓2 on x, turned by ±30°.
    let c = recenter_poses(&pair);
    assert_close(c[0].origin(), Vec3::new(-2.0, 0.0, 0.0), 1e-5);
    assert_close(
        c[0].rotation().z_axis,
        Vec3::new(0.5, 0.0, 0.75f32.sqrt()),
        1e-5,
    );
}

#[test]
fn normalisation_equals_scale_then_recenter() {
    let poses: Vec<Pose> = (0..4)
        .map(|k| {
            let r = Mat3::from_rotation_y(0.1 * k as f32) * Mat3::from_rotation_x(0.2);
            pose_from(
                r,
                Vec3::new(k as f32, 2.0 - k as f32 * 0.5, 10.0 + k as f32),
            )
        })
        .collect();
    let bounds = [(4.0, 20.0), (2.0, 18.0), (3.0, 30.0), (5.0, 25.0)];
    // 1/(2·0.75) = 2/3.
    let sc = bd_factor_scale(&bounds, BD_FACTOR).unwrap();
    assert!((sc - 2.0 / 3.0).abs() < 1e-7);
    // nerf-pytorch order: poses[:, :3, 3] *= sc, then recenter_poses.
    let scaled: Vec<Pose> = poses
        .iter()
        .map(|p| pose_from(p.rotation(), p.origin() * sc))
        .collect();
    let reference = recenter_poses(&scaled);
    let t = llff_normalisation(&poses, sc);
    for (p, r) in poses.iter().zip(&reference) {
        let ours = t.apply_pose(p);
        for (a, b) in ours.0.iter().flatten().zip(r.0.iter().flatten()) {
            assert!((a - b).abs() < 1e-5, "{ours:?} vs {r:?}");
        }
    }
    assert!(bd_factor_scale(&[(0.0, 1.0)], BD_FACTOR).is_err());
    assert!(bd_factor_scale(&[], BD_FACTOR).is_err());
}

/// Writes an LLFF capture: forward-facing cameras along x looking down −z (LLFF columns
/// down = −y, right = x, back = z), images of `w × h`, `[H, W, f]` = `hwf`.
fn write_capture(
    dir: &Path,
    names: &[&str],
    w: u32,
    h: u32,
    hwf: [f64; 3],
    v2: bool,
) -> Vec<[f64; 17]> {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    for name in names {
        let img = image::RgbImage::from_pixel(w, h, image::Rgb([10, 20, 30]));
        img.save(dir.join("images").join(name)).unwrap();
    }
    let rows: Vec<[f64; 17]> = (0..names.len())
        .map(|k| {
            row(
                [0.0, -1.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0],
                [k as f64, 0.5, 0.0],
                hwf,
                [2.0 + k as f64, 40.0],
            )
        })
        .collect();
    write_rows(dir, &rows, v2);
    rows
}

fn write_rows(dir: &Path, rows: &[[f64; 17]], v2: bool) {
    let flat: Vec<f64> = rows.iter().flatten().copied().collect();
    std::fs::write(
        dir.join("poses_bounds.npy"),
        encode_npy(&[rows.len(), 17], &f8_bytes(&flat), "<f8", false, v2),
    )
    .unwrap();
}

#[test]
fn loads_a_small_capture_with_rescaled_focal() {
    for v2 in [false, true] {
        let dir = tempfile::tempdir().unwrap();
        // Images 8×6, hwf for 16×12 with focal 20 → focal 10 at the images' size.
        // Names sort as a.png < b.jpg < c.PNG, whatever the directory order.
        write_capture(
            dir.path(),
            &["c.PNG", "a.png", "b.jpg"],
            8,
            6,
            [12.0, 16.0, 20.0],
            v2,
        );
        std::fs::write(dir.path().join("images/notes.txt"), b"x").unwrap();
        let capture = load_llff(dir.path()).unwrap();
        assert_eq!(capture.format, CaptureFormat::Llff);
        let names: Vec<&str> = capture.views.iter().map(|v| v.name.as_str()).collect();
        assert_eq!(names, ["a", "b", "c"]);
        let cam = capture.views[0].camera;
        assert_eq!(
            (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy),
            (8, 6, 10.0, 10.0, 4.0, 3.0)
        );
        assert_eq!(cam.pixel_center, PixelCenter::Integer);
        // Bounds: min near 2 → scale 1/(2·0.75) = 2/3; near_far = (0.9·4/3, 40·2/3).
        let s = 2.0 / 3.0;
        assert!((capture.transform.scale - s).abs() < 1e-6);
        let (near, far) = capture.near_far.unwrap();
        assert!((near - 0.9 * 2.0 * s).abs() < 1e-5 && (far - 40.0 * s).abs() < 1e-4);
        assert_eq!(
            capture.views[1].bounds.map(|b| (b.0 / s).round()),
            Some(3.0)
        );
        // Recentred: centres at x = (k − 1)·2/3, y = z = 0, looking down −z.
        for (k, v) in capture.views.iter().enumerate() {
            assert_close(
                v.pose.origin(),
                Vec3::new((k as f32 - 1.0) * s, 0.0, 0.0),
                1e-5,
            );
            assert_close(v.pose.rotation() * Vec3::NEG_Z, Vec3::NEG_Z, 1e-6);
        }
        assert!(capture.forward_facing);
        assert!(capture.warnings.is_empty());
    }
}

#[test]
fn bad_captures_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let msg = || load_llff(d).unwrap_err().to_string();
    assert!(msg().contains("poses_bounds.npy"), "{}", msg());
    let rows = write_capture(d, &["a.png", "b.png"], 8, 6, [6.0, 8.0, 10.0], false);
    // Three rows for two images.
    write_rows(d, &[rows[0], rows[1], rows[1]], false);
    assert!(msg().contains("3 poses but 2 images"), "{}", msg());
    // A non-finite value names the row and its image.
    let mut bad = rows[1];
    bad[3] = f64::NAN;
    write_rows(d, &[rows[0], bad], false);
    assert!(
        msg().contains("row 1 (b.png) has a non-finite value"),
        "{}",
        msg()
    );
    let mut bad = rows[0];
    bad[15] = -1.0;
    write_rows(d, &[bad, rows[1]], false);
    assert!(
        msg().contains("row 0 (a.png): bounds (-1, 40)"),
        "{}",
        msg()
    );
    // Wrong shape.
    std::fs::write(
        d.join("poses_bounds.npy"),
        encode_npy(&[2, 15], &f8_bytes(&[1.0; 30]), "<f8", false, false),
    )
    .unwrap();
    assert!(msg().contains("shape [2, 15]: expected N×17"), "{}", msg());
    // Another aspect ratio in [H, W].
    let mut wide = rows.clone();
    for r in &mut wide {
        r[4] = 3.0; // H = 3 with W = 8 → 8×3, but images are 8×6.
    }
    write_rows(d, &wide, false);
    assert!(msg().contains("another aspect ratio"), "{}", msg());
    // Images of different sizes.
    write_rows(d, &rows, false);
    image::RgbImage::new(4, 4)
        .save(d.join("images/b.png"))
        .unwrap();
    assert!(msg().contains("b.png: image is 4×4 but"), "{}", msg());
    // No images folder.
    std::fs::remove_dir_all(d.join("images")).unwrap();
    assert!(msg().contains("images"), "{}", msg());
}
