use super::*;
use crate::camera::Pose;

const D: OpenCvDistortion = OpenCvDistortion {
    k1: 0.1,
    k2: 0.01,
    p1: 0.001,
    p2: 0.002,
};

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

#[test]
fn distortion_matches_hand_computed_values() {
    // r² = 0.3125, r⁴ = 0.09765625, radial = 1 + 0.03125 + 0.0009765625 = 1.0322265625.
    // xd = 0.5·radial + 2·0.001·0.5·(−0.25) + 0.002·(0.3125 + 0.5)
    //    = 0.51611328125 − 0.00025 + 0.001625 = 0.51748828125.
    // yd = −0.25·radial + 0.001·(0.3125 + 0.125) + 2·0.002·0.5·(−0.25)
    //    = −0.258056640625 + 0.0004375 − 0.0005 = −0.258119140625.
    // (The coefficients are f32: 0.1 is 0.100000001…, hence tolerances of 1e-8.)
    let (xd, yd) = D.distort(0.5, -0.25);
    assert!(
        close(xd, 0.51748828125, 1e-8) && close(yd, -0.258119140625, 1e-8),
        "{xd} {yd}"
    );
    // Pure radial on the axis: k1 = 0.1 at (1, 0): radial = 1.1 + 0.01 (k2) → 1.11.
    let radial = OpenCvDistortion {
        k1: 0.1,
        k2: 0.01,
        p1: 0.0,
        p2: 0.0,
    };
    assert!(close(radial.distort(1.0, 0.0).0, 1.11, 1e-8));
    // The centre never moves; all-zero coefficients are the identity.
    assert_eq!(D.distort(0.0, 0.0), (0.0, 0.0));
    let zero = OpenCvDistortion {
        k1: 0.0,
        k2: 0.0,
        p1: 0.0,
        p2: 0.0,
    };
    assert!(zero.is_zero() && !D.is_zero());
    assert_eq!(zero.distort(0.3, -0.7), (0.3, -0.7));
}

#[test]
fn distortion_jacobian_matches_finite_differences() {
    let h = 1e-6;
    for &(x, y) in &[(0.5, -0.25), (-0.8, 0.6), (0.1, 0.9), (0.0, 0.0)] {
        let (_, jac) = D.distort_with_jacobian(x, y);
        let (xp, yp) = D.distort(x + h, y);
        let (xm, ym) = D.distort(x - h, y);
        let (xq, yq) = D.distort(x, y + h);
        let (xn, yn) = D.distort(x, y - h);
        let numeric = [
            [(xp - xm) / (2.0 * h), (xq - xn) / (2.0 * h)],
            [(yp - ym) / (2.0 * h), (yq - yn) / (2.0 * h)],
        ];
        for r in 0..2 {
            for c in 0..2 {
                assert!(
                    close(jac[r][c], numeric[r][c], 1e-7),
                    "({x}, {y}) [{r}][{c}]: {jac:?} vs {numeric:?}"
                );
            }
        }
    }
}

#[test]
fn undistort_inverts_distort() {
    // The fox capture's coefficients and a strong barrel lens.
    let fox = OpenCvDistortion {
        k1: 0.0578421,
        k2: -0.0805099,
        p1: -0.000980296,
        p2: 0.00015575,
    };
    let barrel = OpenCvDistortion {
        k1: -0.3,
        k2: 0.1,
        p1: 0.002,
        p2: -0.001,
    };
    for d in [D, fox, barrel] {
        for k in 0..50 {
            // Points over a normalised image of ±0.8 × ±0.6.
            let (x, y) = (
                -0.8 + 1.6 * (k % 10) as f64 / 9.0,
                -0.6 + 1.2 * (k / 10) as f64 / 4.0,
            );
            let (xd, yd) = d.distort(x, y);
            let (ux, uy) = d.undistort(xd, yd);
            assert!(
                close(ux, x, 1e-10) && close(uy, y, 1e-10),
                "{d:?} ({x}, {y}) → ({ux}, {uy})"
            );
        }
    }
    // Hand value: undistort(0.51748828125, −0.258119140625) = (0.5, −0.25).
    let (x, y) = D.undistort(0.51748828125, -0.258119140625);
    assert!(close(x, 0.5, 1e-8) && close(y, -0.25, 1e-8), "{x} {y}");
}

fn camera(pixel_center: PixelCenter, distortion: Option<OpenCvDistortion>) -> PinholeCamera {
    PinholeCamera {
        width: 4,
        height: 2,
        fx: 2.0,
        fy: 4.0,
        cx: 2.5,
        cy: 1.5,
        pixel_center,
        distortion,
    }
}

#[test]
fn directions_follow_the_pixel_convention() {
    let half = camera(PixelCenter::HalfPixel, None);
    // (0.5 − 2.5)/2 = −1, −(0.5 − 1.5)/4 = 0.25.
    assert_eq!(half.camera_direction(0.0, 0.0), Vec3::new(-1.0, 0.25, -1.0));
    // Pixel (2, 1) is centred on (2.5, 1.5): the optical axis.
    assert_eq!(half.camera_direction(2.0, 1.0), Vec3::new(0.0, 0.0, -1.0));
    let integer = camera(PixelCenter::Integer, None);
    // (0 − 2.5)/2 = −1.25, −(0 − 1.5)/4 = 0.375.
    assert_eq!(
        integer.camera_direction(0.0, 0.0),
        Vec3::new(-1.25, 0.375, -1.0)
    );
    // With distortion: the normalised point (−1, −0.25) (y down) is undistorted, then y flips.
    let distorted = camera(PixelCenter::HalfPixel, Some(D));
    let dir = distorted.camera_direction(0.0, 0.0);
    let (x, y) = D.undistort(-1.0, -0.25);
    assert!(close(dir.x as f64, x, 1e-6) && close(dir.y as f64, -y, 1e-6) && dir.z == -1.0);
    // Distortion pulls an edge ray outwards under k1 > 0, so undistorting moves it in.
    assert!(dir.x > -1.0, "{dir:?}");
}

#[test]
fn fox_directions_match_opencv_undistort_points() {
    // The fox capture's camera; expected values from OpenCV 5.0's
    // `cv2.undistortPoints([[i + 0.5, j + 0.5]], K, (k1, k2, p1, p2))` (100 iterations),
    // y negated into OpenGL.
    let fox = PinholeCamera {
        width: 216,
        height: 384,
        fx: 275.104,
        fy: 274.898,
        cx: 110.9116,
        cy: 193.0536,
        pixel_center: PixelCenter::HalfPixel,
        distortion: Some(OpenCvDistortion {
            k1: 0.0578421,
            k2: -0.0805099,
            p1: -0.000980296,
            p2: 0.00015575,
        }),
    };
    let cases: [((f32, f32), (f64, f64)); 4] = [
        ((0.0, 0.0), (-0.39941427, 0.69628246)),
        ((215.0, 383.0), (0.37869988, -0.69087819)),
        ((100.0, 17.0), (-0.03747789, 0.63097599)),
        ((3.0, 300.0), (-0.38691716, -0.38757754)),
    ];
    for ((i, j), (x, y)) in cases {
        let d = fox.camera_direction(i, j);
        let (dx, dy) = (d.x as f64, d.y as f64);
        assert!(
            (dx - x).abs() < 2e-6 && (dy - y).abs() < 2e-6 && d.z == -1.0,
            "({i}, {j}): {d:?}"
        );
    }
}

#[test]
fn project_inverts_camera_direction() {
    for c in [
        camera(PixelCenter::HalfPixel, Some(D)),
        camera(PixelCenter::Integer, None),
    ] {
        for &(i, j) in &[(0.0, 0.0), (3.0, 1.0), (1.25, 0.5)] {
            let (pi, pj) = c.project(c.camera_direction(i, j)).unwrap();
            assert!(
                (pi - i).abs() < 1e-4 && (pj - j).abs() < 1e-4,
                "({i}, {j}) → ({pi}, {pj})"
            );
        }
        assert_eq!(c.project(Vec3::new(0.0, 0.0, 1.0)), None);
    }
}

#[test]
fn intrinsics_round_trip_and_refusals() {
    let k = Intrinsics {
        width: 400,
        height: 300,
        focal: 323.5,
    };
    let c = PinholeCamera::from_intrinsics(&k);
    assert_eq!((c.cx, c.cy, c.fx, c.fy), (200.0, 150.0, 323.5, 323.5));
    assert_eq!(c.to_intrinsics().unwrap(), k);
    // The Blender rays, bit for bit: ((i − W/2)/f, −(j − H/2)/f, −1) in f32.
    for &(i, j) in &[(0.0f32, 0.0f32), (399.0, 17.0), (123.0, 299.0), (7.0, 3.0)] {
        let blender = Vec3::new((i - 200.0) / 323.5, -(j - 150.0) / 323.5, -1.0);
        assert_eq!(c.camera_direction(i, j), blender);
    }
    // A half-pixel camera centred on (W/2 + 0.5, H/2 + 0.5) is the same camera.
    let shifted = PinholeCamera {
        cx: 200.5,
        cy: 150.5,
        pixel_center: PixelCenter::HalfPixel,
        ..c
    };
    assert_eq!(shifted.to_intrinsics().unwrap(), k);
    assert_eq!(
        c.resized(100, 75).to_intrinsics().unwrap(),
        k.resized(100, 75)
    );
    let msg = |c: PinholeCamera| c.to_intrinsics().unwrap_err().to_string();
    assert!(msg(PinholeCamera { fy: 300.0, ..c }).contains("fy = 300"));
    // The fox's principal point (edge convention) is not the centre in integer pixels.
    let fox = PinholeCamera {
        cx: 110.9116,
        pixel_center: PixelCenter::HalfPixel,
        width: 216,
        ..c
    };
    assert!(msg(fox).contains("principal point"), "{}", msg(fox));
    assert!(
        msg(PinholeCamera {
            distortion: Some(D),
            ..c
        })
        .contains("distortion")
    );
    // Zero coefficients are no distortion.
    let zero = Some(OpenCvDistortion {
        k1: 0.0,
        k2: 0.0,
        p1: 0.0,
        p2: 0.0,
    });
    assert!(
        PinholeCamera {
            distortion: zero,
            ..c
        }
        .to_intrinsics()
        .is_ok()
    );
}

#[test]
fn resizing_scales_focal_and_principal_point() {
    let c = PinholeCamera {
        width: 1080,
        height: 1920,
        fx: 1375.52,
        fy: 1374.49,
        cx: 554.558,
        cy: 965.268,
        pixel_center: PixelCenter::HalfPixel,
        distortion: Some(D),
    };
    let small = c.resized(216, 384);
    assert!(
        (small.fx - 275.104).abs() < 1e-3 && (small.cy - 193.0536).abs() < 1e-3,
        "{small:?}"
    );
    assert_eq!(small.distortion, c.distortion);
    // In pixel-edge coordinates the same point of the scene keeps its relative position:
    // the ray through the original pixel edge 540 is the ray through the small one's 108.
    let big = c.camera_direction(540.0 - 0.5, 960.0 - 0.5);
    let sm = small.camera_direction(108.0 - 0.5, 192.0 - 0.5);
    assert!((big - sm).abs().max_element() < 1e-5, "{big:?} {sm:?}");
}

#[test]
fn json_reads_the_full_model_and_the_older_focal() {
    let c = camera(PixelCenter::HalfPixel, Some(D));
    let text = serde_json::to_string(&c).unwrap();
    assert!(text.contains("\"pixel_center\":\"half_pixel\"") && text.contains("\"k1\":0.1"), "{text}");
    assert_eq!(serde_json::from_str::<PinholeCamera>(&text).unwrap(), c);
    // A camera.json written before: focal only → the Blender camera.
    let old: PinholeCamera =
        serde_json::from_str(r#"{"width": 400, "height": 300, "focal": 323.5}"#).unwrap();
    let k = Intrinsics { width: 400, height: 300, focal: 323.5 };
    assert_eq!(old, PinholeCamera::from(k));
    // Neither fx nor focal: NaN, refused by the limits check (naming fx).
    let none: PinholeCamera = serde_json::from_str(r#"{"width": 4, "height": 4}"#).unwrap();
    assert!(none.fx.is_nan());
}

#[test]
fn rays_rotate_into_the_world() {
    // c2w: camera x → world x, camera y → world z, camera z → world −y; centre (0.5, −4, 1).
    let pose = Pose([
        [1.0, 0.0, 0.0, 0.5],
        [0.0, 0.0, -1.0, -4.0],
        [0.0, 1.0, 0.0, 1.0],
    ]);
    let c = camera(PixelCenter::HalfPixel, None);
    let rays = crate::camera::Rays::for_pixels(&c, &pose, &[(0, 0), (2, 1)]);
    // Camera (−1, 0.25, −1) → world (−1, 1, 0.25); the axis (0, 0, −1) → (0, 1, 0).
    assert_eq!(rays.directions, vec![[-1.0, 1.0, 0.25], [0.0, 1.0, 0.0]]);
    assert_eq!(rays.origins, vec![[0.5, -4.0, 1.0]; 2]);
    assert_eq!(c.num_pixels(), 8);
}
