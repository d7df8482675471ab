//! Carving's projection and decisions on hand-computed values.

use super::*;
use crate::camera::{OpenCvDistortion, PixelCenter, Rays};

/// `w`×`h`, focal `f`, principal point `(cx, cy)`, no distortion.
fn camera(w: u32, h: u32, f: f32, (cx, cy): (f32, f32), pixel_center: PixelCenter) -> PinholeCamera {
    PinholeCamera { width: w, height: h, fx: f, fy: f, cx, cy, pixel_center, distortion: None }
}

/// The camera at the origin looking down −z (camera axes = world axes).
fn identity() -> Pose {
    Pose([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
}

/// A view whose every pixel has the surface at depth `d` (acc 1).
fn flat(camera: PinholeCamera, pose: &Pose, d: f32) -> DepthView {
    let n = camera.num_pixels();
    DepthView::new(camera, pose, (2.0, 6.0), &vec![d; n], &vec![1.0; n])
}

#[test]
fn a_node_lands_in_the_pixel_whose_area_holds_it_in_either_convention() {
    // 4×2, f = 2, principal point (2, 1), integer centres: u = 2x/(−z) + 2, v = −2y/(−z) + 1,
    // and pixel i covers u in [i − ½, i + ½).
    let view = flat(camera(4, 2, 2.0, (2.0, 1.0), PixelCenter::Integer), &identity(), 5.0);
    let at = |p: [f32; 3]| view.pixel(Vec3::from_array(p));
    assert_eq!(at([0.0, 0.0, -3.0]), Some(((2, 1), 3.0)));
    // x/(−z) = −1.2: u = −0.4, still pixel 0; −1.3: u = −0.6, left of the image.
    assert_eq!(at([-3.6, 0.0, -3.0]), Some(((0, 1), 3.0)));
    assert_eq!(at([-3.9, 0.0, -3.0]), None);
    // 0.7: u = 3.4, pixel 3; 0.8: u = 3.6, right of the image.
    assert_eq!(at([2.1, 0.0, -3.0]), Some(((3, 1), 3.0)));
    assert_eq!(at([2.4, 0.0, -3.0]), None);
    // Up is −v: y/(−z) = 0.2 → v = 0.6 (row 1); 0.4 → 0.2 (row 0); 0.6 → −0.2 (row 0);
    // 0.8 → −0.6 (above the image).
    assert_eq!(at([0.0, 0.6, -3.0]).map(|p| p.0), Some((2, 1)));
    assert_eq!(at([0.0, 1.2, -3.0]).map(|p| p.0), Some((2, 0)));
    assert_eq!(at([0.0, 1.8, -3.0]).map(|p| p.0), Some((2, 0)));
    assert_eq!(at([0.0, 2.4, -3.0]), None);
    // Behind the camera.
    assert_eq!(at([0.0, 0.0, 3.0]), None);
    // The same principal point in half-pixel (pixel-edge) coordinates is the corner of pixels
    // (1, 0), (2, 0), (1, 1), (2, 1): x/(−z) = −0.05 gives u = −0.1 + 2 − 0.5 = 1.4 (column 1),
    // where integer centres give u = 1.9 (column 2); y/(−z) = −0.05 gives v = 0.6 (row 1) and
    // v = 1.1 (row 1).
    let half = flat(camera(4, 2, 2.0, (2.0, 1.0), PixelCenter::HalfPixel), &identity(), 5.0);
    assert_eq!(half.pixel(Vec3::new(-0.15, -0.15, -3.0)).map(|p| p.0), Some((1, 1)));
    assert_eq!(half.pixel(Vec3::new(0.15, -0.15, -3.0)).map(|p| p.0), Some((2, 1)));
    assert_eq!(half.pixel(Vec3::new(0.15, 0.15, -3.0)).map(|p| p.0), Some((2, 0)));
    assert_eq!(view.pixel(Vec3::new(-0.15, -0.15, -3.0)).map(|p| p.0), Some((2, 1)));
}

#[test]
fn a_turned_camera_projects_as_its_rays_run() {
    // At (0, −4, 0) looking along +y, up +z: columns x = (1, 0, 0), y = (0, 0, 1), z = (0, −1, 0).
    let pose = Pose([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, -4.0], [0.0, 1.0, 0.0, 0.0]]);
    let k = camera(8, 8, 8.0, (4.0, 4.0), PixelCenter::Integer);
    let view = flat(k, &pose, 5.0);
    // (1, 0, 0.5) is (1, 0.5, −4) in the camera: u = 8·0.25 + 4 = 6, v = −8·0.125 + 4 = 3.
    assert_eq!(view.pixel(Vec3::new(1.0, 0.0, 0.5)), Some(((6, 3), 4.0)));
    // Pixel (6, 3)'s own ray reaches it at t = 4.
    let ray = Rays::for_pixels(&k, &pose, &[(6, 3)]);
    let p = crate::camera::point_at(ray.origins[0], ray.directions[0], 4.0);
    assert_eq!(p, [1.0, 0.0, 0.5]);
    // A distorted half-pixel camera: points along a pixel's ray (and within its area) come back
    // to that pixel at their t.
    let distorted = PinholeCamera { distortion: Some(OpenCvDistortion { k1: 0.1, k2: 0.01, p1: 0.001, p2: 0.002 }), pixel_center: PixelCenter::HalfPixel, ..k };
    let view = flat(distorted, &pose, 5.0);
    let rays = Rays::for_image_points(&distorted, &pose, [(5.0, 2.0), (5.4, 2.4), (5.6, 2.4)].into_iter());
    let back: Vec<_> = (0..3).map(|r| view.pixel(Vec3::from_array(crate::camera::point_at(rays.origins[r], rays.directions[r], 2.5)))).collect();
    assert_eq!(back.iter().map(|b| b.unwrap().0).collect::<Vec<_>>(), [(5, 2), (5, 2), (6, 2)]);
    assert!(back.iter().all(|b| (b.unwrap().1 - 2.5).abs() < 1e-4), "{back:?}");
}

#[test]
fn a_node_is_empty_in_front_of_the_surface_hidden_behind_it_and_unseen_outside_the_span() {
    // 6×2, f = 2, principal point (3, 1): column i holds x/(−z) = (i − 3)/2. Columns 0–2 see a
    // surface at depth 5, columns 3–5 see through (acc 0.2); column 3 borders column 2, whose
    // surface it takes.
    let k = camera(6, 2, 2.0, (3.0, 1.0), PixelCenter::Integer);
    let acc: Vec<f32> = (0..12).map(|p| if p % 6 < 3 { 1.0 } else { 0.2 }).collect();
    let depth: Vec<f32> = acc.iter().map(|a| 5.0 * a).collect();
    let view = DepthView::new(k, &identity(), (2.0, 6.0), &depth, &acc);
    let margin = 0.5;
    // Column 1: x/(−z) = −1, the point (−t, 0, −t).
    let column = |x: f32, t: f32| view.sight(Vec3::new(x * t, 0.0, -t), margin);
    assert_eq!(column(-1.0, 3.0), Sight::Empty);
    assert_eq!(column(-1.0, 4.4), Sight::Empty, "4.4 < 5 − 0.5");
    assert_eq!(column(-1.0, 4.6), Sight::Hidden, "within the margin");
    assert_eq!(column(-1.0, 5.5), Sight::Hidden, "behind the surface");
    // Column 5 sees through: empty at any depth within near..far.
    assert_eq!(column(1.0, 5.9), Sight::Empty);
    assert_eq!(column(1.0, 1.5), Sight::Unseen, "before near");
    assert_eq!(column(1.0, 6.5), Sight::Unseen, "past far");
    // Column 3 sees through itself but borders the surface.
    assert_eq!(column(0.0, 4.6), Sight::Hidden);
    assert_eq!(column(0.0, 4.4), Sight::Empty);
    // Outside the image.
    assert_eq!(column(-2.0, 3.0), Sight::Unseen);
}

#[test]
fn views_together_and_pixel_depths() {
    let k = camera(4, 2, 2.0, (2.0, 1.0), PixelCenter::Integer);
    let (near, far) = (flat(k, &identity(), 3.0), flat(k, &identity(), 5.0));
    let p = Vec3::new(0.0, 0.0, -4.0);
    let mut hint = 0;
    assert_eq!(sight_of(&[near.clone(), far.clone()], p, 0.1, &mut hint), Sight::Empty);
    assert_eq!(hint, 1, "the view that saw it empty is asked first next time");
    assert_eq!(sight_of(&[near.clone(), near.clone()], p, 0.1, &mut hint), Sight::Hidden);
    assert_eq!(sight_of(std::slice::from_ref(&far), Vec3::new(0.0, 0.0, 4.0), 0.1, &mut 0), Sight::Unseen);
    assert_eq!(sight_of(&[far, near], Vec3::new(0.0, 0.0, 4.0), 0.1, &mut 0), Sight::Unseen);
    assert_eq!(sight_of(&[], p, 0.1, &mut 0), Sight::Unseen);
    // Depths.
    assert!((surface_depth(2.7, 0.9) - 3.0).abs() < 1e-6);
    assert_eq!(surface_depth(2.7, 0.3), f32::INFINITY);
    assert_eq!(surface_depth(f32::NAN, 1.0), f32::INFINITY);
    let inf = f32::INFINITY;
    assert_eq!(nearest_around(&[5.0, inf, inf], 3, 1), [5.0, 5.0, inf]);
    // 4×3 with one near pixel at (3, 0): it reaches (2..3, 0..1) only.
    let mut d = vec![9.0; 12];
    d[3] = 1.0;
    assert_eq!(nearest_around(&d, 4, 3), [9.0, 9.0, 1.0, 1.0, 9.0, 9.0, 1.0, 1.0, 9.0, 9.0, 9.0, 9.0]);
}

#[test]
fn carving_cameras_are_at_most_carve_size_on_their_long_side() {
    let k = camera(800, 600, 1000.0, (400.0, 300.0), PixelCenter::Integer);
    let c = carving_camera(&k);
    assert_eq!((c.width, c.height), (128, 96));
    assert!((c.fx - 160.0).abs() < 1e-3 && (c.cx - 64.0).abs() < 1e-3 && (c.cy - 48.0).abs() < 1e-3, "{c:?}");
    let small = camera(64, 64, 80.0, (32.0, 32.0), PixelCenter::Integer);
    assert_eq!(carving_camera(&small), small);
    let thin = camera(1000, 1, 80.0, (500.0, 0.5), PixelCenter::Integer);
    assert_eq!((carving_camera(&thin).width, carving_camera(&thin).height), (128, 1));
}
