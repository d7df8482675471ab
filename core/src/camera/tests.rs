use super::*;
use glam::Vec3;

fn assert_close(a: Vec3, b: Vec3) {
    assert!((a - b).abs().max_element() < 1e-5, "{a:?} != {b:?}");
}

#[test]
fn point_at_and_length() {
    assert_eq!(point_at([1.0, 0.0, 0.0], [0.0, 2.0, 0.0], 1.5), [1.0, 3.0, 0.0]);
    assert_eq!(length([3.0, 0.0, 4.0]), 5.0);
}

#[test]
fn focal_from_camera_angle() {
    // tan(0.5 · 2·atan(0.5)) = 0.5 → focal = 0.5·W / 0.5 = W.
    let k = Intrinsics::from_camera_angle_x(400, 400, 2.0 * 0.5f32.atan());
    assert!((k.focal - 400.0).abs() < 1e-3);
    let half = k.resized(100, 100);
    assert!((half.focal - 100.0).abs() < 1e-3);
}

#[test]
fn ray_directions_for_known_pose_and_focal() {
    // W=4, H=2, f=2; c2w rotates camera x→world x, camera y→world z, camera z→world −y
    // (the "swap" used by pose_spherical's last step would differ; this one is explicit).
    let k = PinholeCamera::from(Intrinsics { width: 4, height: 2, focal: 2.0 });
    let pose = Pose([[1.0, 0.0, 0.0, 0.5], [0.0, 0.0, -1.0, -4.0], [0.0, 1.0, 0.0, 1.0]]);
    // Corner pixel (0,0): camera dir ((0−2)/2, −(0−1)/2, −1) = (−1, 0.5, −1).
    // World = R·d = (−1, −(−1), 0.5) = (−1, 1, 0.5).
    assert_close(pose.ray_direction(&k, 0.0, 0.0), Vec3::new(-1.0, 1.0, 0.5));
    // Centre pixel (2,1): camera (0, 0, −1) → world (0, 1, 0): no +0.5 offset.
    assert_close(pose.ray_direction(&k, 2.0, 1.0), Vec3::new(0.0, 1.0, 0.0));
    // Last corner (3,1): camera (0.5, 0, −1) → world (0.5, 1, 0).
    assert_close(pose.ray_direction(&k, 3.0, 1.0), Vec3::new(0.5, 1.0, 0.0));
    let rays = Rays::for_rows(&k, &pose, 0..2);
    assert_eq!(rays.len(), 8);
    assert_eq!(rays.origins[5], [0.5, -4.0, 1.0]);
    assert_close(Vec3::from_array(rays.directions[0]), Vec3::new(-1.0, 1.0, 0.5));
    assert_close(Vec3::from_array(rays.directions[6]), Vec3::new(0.0, 1.0, 0.0));
    let unit = rays.view_directions();
    assert!((Vec3::from_array(unit[0]).length() - 1.0).abs() < 1e-6);
    // Half a pixel right of the centre pixel, and a corner of pixel (0, 0)'s area: camera
    // (0.25, 0, −1) → world (0.25, 1, 0); (−1.25, 0.75, −1) → (−1.25, 1, 0.75).
    let points = Rays::for_image_points(&k, &pose, [(2.5, 1.0), (-0.5, -0.5), (3.0, 1.0)].into_iter());
    assert_close(Vec3::from_array(points.directions[0]), Vec3::new(0.25, 1.0, 0.0));
    assert_close(Vec3::from_array(points.directions[1]), Vec3::new(-1.25, 1.0, 0.75));
    assert_eq!(points.directions[2], Rays::for_pixels(&k, &pose, &[(3, 1)]).directions[0]);
    assert_eq!(points.origins[1], [0.5, -4.0, 1.0]);
}

#[test]
fn spherical_pose_looks_at_origin_from_radius() {
    for &(theta, phi) in &[(0.0, -30.0), (90.0, -30.0), (-135.0, 10.0)] {
        let pose = Pose::spherical(theta, phi, 4.0);
        assert!((pose.origin().length() - 4.0).abs() < 1e-5);
        // The camera looks along −z: that axis points from the origin back to the centre.
        let forward = pose.rotation() * Vec3::NEG_Z;
        assert_close(forward, -pose.origin().normalize());
        // Elevation −30° puts the camera above the object (+z up in Blender's world).
        if phi < 0.0 {
            assert!((pose.origin().z - 4.0 * 0.5).abs() < 1e-4, "{:?}", pose.origin());
        }
    }
    // theta = 0, phi = 0: the reference gives the camera at (0, 4, 0)... after the swap:
    // trans (0,0,4) → swap rows (−x, z, y) → (0, 4, 0).
    assert_close(Pose::spherical(0.0, 0.0, 4.0).origin(), Vec3::new(0.0, 4.0, 0.0));
    assert_eq!(Pose::orbit(40).len(), 40);
}
