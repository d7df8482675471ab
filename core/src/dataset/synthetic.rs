//! A generated Blender-format scene for tests and smoke runs: three coloured spheres on a
//! box-shaped plinth, ray-traced analytically with the project's own camera rays.
//!
//! Scene (world units, +z up, all within |x|, |y|, |z| ≤ 1.2):
//! - plinth: axis-aligned box (−0.9, −0.9, −1.0)–(0.9, 0.9, −0.75), albedo (0.55, 0.5, 0.45),
//!   checkered on each face in squares of 0.15 (the dark ones at 60%): a plain face gives the
//!   views nothing to agree on, and a field may then leave it a soft layer a cell thick;
//! - red sphere: centre (0, 0, −0.15), radius 0.6, albedo (0.9, 0.2, 0.15);
//! - green sphere: centre (0.6, −0.6, −0.45), radius 0.3, albedo (0.2, 0.75, 0.25);
//! - blue sphere: centre (−0.6, 0.55, −0.5), radius 0.25, albedo (0.15, 0.3, 0.85).
//!
//! Shading is Lambertian: `albedo · (0.3 + 0.7·max(0, n·l))` with the light direction
//! `l = (1, −1, 2)/√6`. Hits have alpha 1; misses are transparent black.

use std::path::Path;

use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::Split;
use super::blender::{Frame, Transforms, image_path, transforms_path};
use crate::camera::{Intrinsics, Pose, Rays};
use crate::camera::PinholeCamera;
use crate::io::atomic::write_atomic;
use crate::error::{Error, Result};
use crate::io::image::save_png_rgba;
use crate::rng::Rng;

/// The generated scene's horizontal field of view (radians): the lego scene's.
pub const CAMERA_ANGLE_X: f32 = 0.691_111_2;

const AMBIENT: f32 = 0.3;
const DIFFUSE: f32 = 0.7;
const RADIUS: f32 = 4.0;

/// Size and view counts of a generated scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SyntheticSceneConfig {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Number of training views (at least 1).
    pub n_train: usize,
    /// Number of validation views.
    pub n_val: usize,
    /// Number of test views.
    pub n_test: usize,
    /// Seed of the random train/val camera positions.
    pub seed: u64,
}

impl Default for SyntheticSceneConfig {
    fn default() -> Self {
        SyntheticSceneConfig {
            width: 64,
            height: 64,
            n_train: 40,
            n_val: 8,
            n_test: 8,
            seed: 0,
        }
    }
}

/// The camera poses of a split: train and val at random azimuth in [−180°, 180°) and elevation
/// in [−80°, −10°] (upper hemisphere), radius 4, from independent streams forked off
/// `Rng::new(seed)`; test at evenly spaced azimuths `−180 + 360·k/n` and elevation −30°.
pub fn split_poses(cfg: &SyntheticSceneConfig, split: Split) -> Vec<Pose> {
    let mut root = Rng::new(cfg.seed);
    let mut train_rng = root.fork();
    let mut val_rng = root.fork();
    let random = |rng: &mut Rng, n: usize| -> Vec<Pose> {
        (0..n)
            .map(|_| {
                let theta = -180.0 + 360.0 * rng.uniform();
                let phi = -80.0 + 70.0 * rng.uniform();
                Pose::spherical(theta, phi, RADIUS)
            })
            .collect()
    };
    match split {
        Split::Train => random(&mut train_rng, cfg.n_train),
        Split::Val => random(&mut val_rng, cfg.n_val),
        Split::Test => (0..cfg.n_test)
            .map(|k| Pose::spherical(-180.0 + 360.0 * k as f32 / cfg.n_test as f32, -30.0, RADIUS))
            .collect(),
    }
}

/// Writes a complete Blender-format dataset into `dir` (created if needed):
/// `{train,val,test}/r_k.png` (RGBA, 8 bits) and `transforms_{train,val,test}.json`
/// (`camera_angle_x` = [`CAMERA_ANGLE_X`], frames with `file_path` `./{split}/r_k` and the 4×4
/// `transform_matrix`). Images are written before their JSON, each file atomically.
pub fn generate_scene(dir: &Path, cfg: &SyntheticSceneConfig) -> Result<()> {
    if cfg.width == 0 || cfg.height == 0 {
        return Err(Error::Argument(format!(
            "synthetic scene size {}×{} must be non-empty",
            cfg.width, cfg.height
        )));
    }
    if cfg.n_train == 0 {
        return Err(Error::Argument(
            "a synthetic scene needs at least one training view".into(),
        ));
    }
    let camera = PinholeCamera::from(Intrinsics::from_camera_angle_x(cfg.width, cfg.height, CAMERA_ANGLE_X));
    for split in Split::ALL {
        let split_dir = dir.join(split.name());
        std::fs::create_dir_all(&split_dir).map_err(|e| Error::io(&split_dir, e))?;
        let frames: Vec<Frame> = split_poses(cfg, split)
            .into_iter()
            .enumerate()
            .map(|(k, pose)| {
                let r = pose.0;
                Frame {
                    file_path: format!("./{}/r_{k}", split.name()),
                    transform_matrix: [r[0], r[1], r[2], [0.0, 0.0, 0.0, 1.0]],
                }
            })
            .collect();
        frames.par_iter().try_for_each(|frame| {
            let pose = Pose::from_rows(frame.transform_matrix);
            let rgba = render_reference(&pose, &camera);
            save_png_rgba(
                &image_path(dir, &frame.file_path),
                cfg.width,
                cfg.height,
                &rgba,
            )
        })?;
        let json_path = transforms_path(dir, split);
        let transforms = Transforms {
            camera_angle_x: CAMERA_ANGLE_X,
            frames,
        };
        let text = serde_json::to_string_pretty(&transforms).map_err(|source| Error::Json {
            path: json_path.clone(),
            source,
        })?;
        write_atomic(&json_path, text.as_bytes())?;
    }
    Ok(())
}

/// The analytic image of the scene from any camera: straight RGBA per pixel, row-major, using
/// exactly the project's rays ([`Rays::for_rows`]: no half-pixel offset, one ray per pixel).
/// Hits are opaque with the shaded colour; misses are `[0, 0, 0, 0]`.
pub fn render_reference(pose: &Pose, camera: &PinholeCamera) -> Vec<[f32; 4]> {
    let rays = Rays::for_rows(camera, pose, 0..camera.height);
    let light = Vec3::new(1.0, -1.0, 2.0).normalize();
    rays.origins
        .iter()
        .zip(&rays.directions)
        .map(
            |(o, d)| match trace(Vec3::from_array(*o), Vec3::from_array(*d)) {
                Some((normal, albedo)) => {
                    let c = albedo * (AMBIENT + DIFFUSE * normal.dot(light).max(0.0));
                    [c.x, c.y, c.z, 1.0]
                }
                None => [0.0; 4],
            },
        )
        .collect()
}

struct Sphere {
    centre: Vec3,
    radius: f32,
    albedo: Vec3,
}

const SPHERES: [Sphere; 3] = [
    Sphere {
        centre: Vec3::new(0.0, 0.0, -0.15),
        radius: 0.6,
        albedo: Vec3::new(0.9, 0.2, 0.15),
    },
    Sphere {
        centre: Vec3::new(0.6, -0.6, -0.45),
        radius: 0.3,
        albedo: Vec3::new(0.2, 0.75, 0.25),
    },
    Sphere {
        centre: Vec3::new(-0.6, 0.55, -0.5),
        radius: 0.25,
        albedo: Vec3::new(0.15, 0.3, 0.85),
    },
];
const BOX_MIN: Vec3 = Vec3::new(-0.9, -0.9, -1.0);
const BOX_MAX: Vec3 = Vec3::new(0.9, 0.9, -0.75);
const BOX_ALBEDO: Vec3 = Vec3::new(0.55, 0.5, 0.45);
const EPS: f32 = 1e-5;
/// Side of the plinth's checker squares.
const CHECKER: f32 = 0.15;

/// The nearest hit along `o + t·d` (t > 0): its unit normal and albedo.
fn trace(o: Vec3, d: Vec3) -> Option<(Vec3, Vec3)> {
    let mut best: Option<(f32, Vec3, Vec3)> = None;
    let mut consider = |t: f32, normal: Vec3, albedo: Vec3| {
        if best.is_none_or(|(bt, _, _)| t < bt) {
            best = Some((t, normal, albedo));
        }
    };
    for s in &SPHERES {
        if let Some(t) = hit_sphere(o, d, s.centre, s.radius) {
            consider(t, (o + t * d - s.centre) / s.radius, s.albedo);
        }
    }
    if let Some((t, normal)) = hit_box(o, d, BOX_MIN, BOX_MAX) {
        consider(t, normal, BOX_ALBEDO * plinth_pattern(o + t * d, normal));
    }
    best.map(|(_, n, a)| (n, a))
}

/// The plinth's checkerboard at `p` on the face with outward `normal`: squares of [`CHECKER`]
/// in the face's two axes, dark ones at 60%.
fn plinth_pattern(p: Vec3, normal: Vec3) -> f32 {
    let cell = (p / CHECKER).floor() * (Vec3::ONE - normal.abs());
    if (cell.x + cell.y + cell.z).rem_euclid(2.0) < 1.0 { 1.0 } else { 0.6 }
}

/// Distance from `p` to the nearest surface of the scene's solids, each taken alone (a sphere's
/// or the plinth's own boundary): the ground truth a mesh of the scene is measured against.
pub fn surface_distance(p: Vec3) -> f32 {
    // The plinth's signed distance: outside, to the box; inside, minus the nearest face's.
    let q = (p - 0.5 * (BOX_MIN + BOX_MAX)).abs() - 0.5 * (BOX_MAX - BOX_MIN);
    let plinth = (q.max(Vec3::ZERO).length() + q.max_element().min(0.0)).abs();
    SPHERES.iter().map(|s| ((p - s.centre).length() - s.radius).abs()).fold(plinth, f32::min)
}

fn hit_sphere(o: Vec3, d: Vec3, centre: Vec3, radius: f32) -> Option<f32> {
    let oc = o - centre;
    let a = d.dot(d);
    let b = oc.dot(d);
    let c = oc.dot(oc) - radius * radius;
    let disc = b * b - a * c;
    if disc < 0.0 || a == 0.0 {
        return None;
    }
    let s = disc.sqrt();
    [(-b - s) / a, (-b + s) / a].into_iter().find(|&t| t > EPS)
}

/// Slab test; returns the entry distance and the outward normal of the entered face.
fn hit_box(o: Vec3, d: Vec3, min: Vec3, max: Vec3) -> Option<(f32, Vec3)> {
    let mut t_near = f32::NEG_INFINITY;
    let mut t_far = f32::INFINITY;
    let mut axis = 0;
    for k in 0..3 {
        if d[k] == 0.0 {
            if o[k] < min[k] || o[k] > max[k] {
                return None;
            }
            continue;
        }
        let (t0, t1) = ((min[k] - o[k]) / d[k], (max[k] - o[k]) / d[k]);
        let (lo, hi) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
        if lo > t_near {
            t_near = lo;
            axis = k;
        }
        t_far = t_far.min(hi);
    }
    if t_near > t_far || t_near <= EPS {
        return None; // a miss, or the camera is inside the box (not a case we render)
    }
    let mut normal = Vec3::ZERO;
    normal[axis] = -d[axis].signum();
    Some((t_near, normal))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::load_split;

    #[test]
    fn surface_distance_by_hand() {
        let d = |x: f32, y: f32, z: f32| surface_distance(Vec3::new(x, y, z));
        // The red sphere's top (0, 0, −0.15 + 0.6), and 0.55 above it.
        assert!(d(0.0, 0.0, 0.45).abs() < 1e-6);
        assert!((d(0.0, 0.0, 1.0) - 0.55).abs() < 1e-6);
        // 0.1 outside the plinth's +x face (the green sphere is 0.85 − 0.3 away).
        assert!((d(1.0, 0.0, -0.9) - 0.1).abs() < 1e-6);
        // Inside the plinth, 0.05 above its bottom face; at its corner, √3·0.1 out.
        assert!((d(0.0, 0.0, -0.95) - 0.05).abs() < 1e-6);
        assert!((d(1.0, 1.0, -0.65) - 0.1 * 3f32.sqrt()).abs() < 1e-6);
        // Inside the blue sphere's centre: its radius.
        assert!((d(-0.6, 0.55, -0.5) - 0.25).abs() < 1e-6);
    }

    fn close(a: &[f32], b: &[f32], tol: f32) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
    }

    #[test]
    fn hand_computed_hits() {
        // Looking straight down from (0, 0, 4): the red sphere's top (0, 0, 0.45), normal +z;
        // n·l = 2/√6 = 0.816497 → shade 0.3 + 0.7·0.816497 = 0.871548 ×(0.9, 0.2, 0.15).
        let pose = Pose::spherical(0.0, -90.0, 4.0);
        let k = PinholeCamera::from(Intrinsics::from_camera_angle_x(32, 32, CAMERA_ANGLE_X));
        let img = render_reference(&pose, &k);
        assert!(
            close(
                &img[16 * 32 + 16],
                &[0.784393, 0.174310, 0.130732, 1.0],
                1e-4
            ),
            "{:?}",
            img[16 * 32 + 16]
        );
        // The corner ray misses everything.
        assert_eq!(img[0], [0.0; 4]);
        // Box top face seen from above: normal +z, plinth albedo.
        let (n, albedo) = trace(Vec3::new(0.8, 0.8, 4.0), Vec3::NEG_Z).unwrap();
        assert_eq!((n, albedo), (Vec3::Z, BOX_ALBEDO));
        // Box side face seen along +x from x = −4 at z = −0.9: normal −x.
        let (n, _) = trace(Vec3::new(-4.0, 0.0, -0.9), Vec3::X).unwrap();
        assert_eq!(n, Vec3::NEG_X);
        // The checker: (0.8, 0.65) on the top face is in square (5, 4), a dark one; on the −x
        // face the squares run in y and z, and (0.1, −0.8) is in (0, −6), a light one.
        assert_eq!(trace(Vec3::new(0.8, 0.65, 4.0), Vec3::NEG_Z).unwrap().1, BOX_ALBEDO * 0.6);
        assert_eq!(trace(Vec3::new(-4.0, 0.1, -0.8), Vec3::X).unwrap().1, BOX_ALBEDO);
        assert_eq!(trace(Vec3::new(-4.0, 0.2, -0.8), Vec3::X).unwrap().1, BOX_ALBEDO * 0.6);
        // Unnormalised directions give the same hit as normalised ones.
        let (n1, _) = trace(Vec3::new(0.1, 0.0, 4.0), Vec3::new(0.0, 0.0, -3.0)).unwrap();
        let (n2, _) = trace(Vec3::new(0.1, 0.0, 4.0), Vec3::NEG_Z).unwrap();
        assert!((n1 - n2).length() < 1e-5, "{n1:?} vs {n2:?}");
    }

    #[test]
    fn poses_are_in_the_upper_hemisphere_and_seeded() {
        let cfg = SyntheticSceneConfig::default();
        let train = split_poses(&cfg, Split::Train);
        assert_eq!(train.len(), 40);
        for p in &train {
            let o = p.origin();
            assert!((o.length() - 4.0).abs() < 1e-4);
            // Elevation in [10°, 80°] above the xy plane: z = 4·sin(elev).
            assert!(
                o.z >= 4.0 * 10f32.to_radians().sin() - 1e-4
                    && o.z <= 4.0 * 80f32.to_radians().sin() + 1e-4
            );
        }
        assert_eq!(train, split_poses(&cfg, Split::Train));
        assert_ne!(
            train,
            split_poses(
                &SyntheticSceneConfig {
                    seed: 1,
                    ..cfg.clone()
                },
                Split::Train
            )
        );
        // Val does not depend on the number of train views.
        let more = SyntheticSceneConfig {
            n_train: 3,
            ..cfg.clone()
        };
        assert_eq!(
            split_poses(&cfg, Split::Val),
            split_poses(&more, Split::Val)
        );
        let test = split_poses(&cfg, Split::Test);
        assert_eq!(test[0], Pose::spherical(-180.0, -30.0, 4.0));
        assert_eq!(test[2], Pose::spherical(-90.0, -30.0, 4.0));
    }

    #[test]
    fn generated_scene_loads_back() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = SyntheticSceneConfig {
            width: 32,
            height: 24,
            n_train: 3,
            n_val: 2,
            n_test: 4,
            seed: 5,
        };
        generate_scene(dir.path(), &cfg).unwrap();
        assert!(dir.path().join("train/r_2.png").is_file());
        assert!(dir.path().join("test/r_3.png").is_file());

        let test = load_split(dir.path(), Split::Test, 1, true).unwrap();
        assert_eq!(test.views.len(), 4);
        let camera = test.camera().unwrap();
        assert_eq!((camera.width, camera.height), (32, 24));
        let focal = 16.0 / (0.5 * CAMERA_ANGLE_X).tan();
        assert!((camera.fx - focal).abs() < 1e-4);
        assert_eq!(test.views[0].name, "r_0");
        // Poses survive the JSON round trip exactly.
        assert_eq!(test.poses(), split_poses(&cfg, Split::Test));

        let view = &test.views[0];
        let img = view.image.as_ref().unwrap();
        let reference = render_reference(&view.pose, &camera);
        let (mut white, mut coloured) = (0, 0);
        for (p, r) in img.iter().zip(&reference) {
            if r[3] == 0.0 {
                assert_eq!(*p, [1.0, 1.0, 1.0]); // background: exactly white
                white += 1;
            } else {
                assert!(close(p, &r[..3], 0.5 / 255.0 + 1e-6), "{p:?} vs {r:?}");
                coloured += 1;
            }
        }
        assert!(
            white > 0 && coloured > 0,
            "{white} white, {coloured} coloured"
        );

        // Test view 0 is pose_spherical(−180, −30, 4): camera at (0, −3.4641, 2) looking at the
        // origin along (0, 0.8660, −0.5). The centre pixel (16, 12) ray hits the red sphere
        // (centre (0, 0, −0.15), r 0.6) at t = 3.48923, point (0, −0.44234, 0.25538), normal
        // (0, −0.73723, 0.67564); n·l = (0.73723 + 2·0.67564)/√6 = 0.85263 →
        // shade 0.3 + 0.7·0.85263 = 0.896842 → (0.807158, 0.179368, 0.134526).
        let centre = img[12 * 32 + 16];
        assert!(
            close(&centre, &[0.807158, 0.179368, 0.134526], 0.5 / 255.0 + 1e-4),
            "{centre:?}"
        );

        // Downscale 2: block means of the full-resolution RGBA, then composited.
        let half = load_split(dir.path(), Split::Train, 2, true).unwrap();
        let half_camera = half.camera().unwrap();
        assert_eq!((half_camera.width, half_camera.height), (16, 12));
        assert!((half_camera.fx - focal / 2.0).abs() < 1e-4);
        assert_eq!(half.views.len(), 3);
        let full = PinholeCamera::from(Intrinsics {
            width: 32,
            height: 24,
            focal,
        });
        for view in &half.views {
            let small = view.image.as_ref().unwrap();
            assert_eq!(small.len(), 16 * 12);
            let reference = render_reference(&view.pose, &full);
            let mut background = 0;
            for j in 0..12 {
                for i in 0..16 {
                    let mut mean = [0.0f32; 4];
                    for (dj, di) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                        let q = reference[(2 * j + dj) * 32 + 2 * i + di];
                        for c in 0..4 {
                            mean[c] += q[c] / 4.0;
                        }
                    }
                    let expected = [0, 1, 2].map(|c| mean[c] * mean[3] + 1.0 - mean[3]);
                    let got = small[j * 16 + i];
                    assert!(
                        close(&got, &expected, 0.5 / 255.0 + 1e-5),
                        "({i}, {j}): {got:?} vs {expected:?}"
                    );
                    if mean[3] == 0.0 {
                        assert_eq!(got, [1.0; 3]);
                        background += 1;
                    }
                }
            }
            assert!(background > 0 && background < 16 * 12);
        }

        // Val loads without pixels, size from its own images.
        let val = load_split(dir.path(), Split::Val, 2, false).unwrap();
        assert_eq!(
            (val.views[0].camera.width, val.views[0].camera.height, val.views.len()),
            (16, 12, 2)
        );
    }

    #[test]
    fn bad_config_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = SyntheticSceneConfig {
            width: 0,
            ..Default::default()
        };
        assert!(generate_scene(dir.path(), &cfg).is_err());
        let cfg = SyntheticSceneConfig {
            n_train: 0,
            ..Default::default()
        };
        assert!(generate_scene(dir.path(), &cfg).is_err());
    }
}
