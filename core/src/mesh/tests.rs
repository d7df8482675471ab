//! [`extract_mesh`] on an analytic field: a dense ball whose colour shows the view direction.

use super::*;
use crate::mesh::carve::DepthView;
use crate::camera::ndc::Ndc;
use crate::dataset::CaptureFormat;
use crate::field::FieldOutput;
use crate::mesh::ply::read_ply;
use glam::Vec3;

/// σ = 100 inside the ball (centre `c`, radius `r`), 0 outside, a linear ramp 0.4 wide across
/// its surface (wider than the lattice's cells, so that linear interpolation finds the sphere
/// and central differences its normal); rgb = (1 + d)/2 for view direction d.
struct Ball {
    c: [f32; 3],
    r: f32,
    /// Hollow inside this radius (the same ramp), when positive.
    hollow: f32,
    /// A tunnel of this radius (the same ramp) from the centre straight down, when positive.
    tunnel: f32,
}

impl Field for Ball {
    type Error = Error;
    fn evaluate(&mut self, _: Stage, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> Result<FieldOutput> {
        let sigma = points
            .iter()
            .map(|p| {
                let d = ((p[0] - self.c[0]).powi(2) + (p[1] - self.c[1]).powi(2) + (p[2] - self.c[2]).powi(2)).sqrt();
                let wall = if self.hollow > 0.0 { ((d - self.hollow) / 0.4 + 0.5).clamp(0.0, 1.0) } else { 1.0 };
                let axis = ((p[0] - self.c[0]).powi(2) + (p[1] - self.c[1]).powi(2)).sqrt();
                let tunnel = if self.tunnel > 0.0 && p[2] < self.c[2] { ((axis - self.tunnel) / 0.4 + 0.5).clamp(0.0, 1.0) } else { 1.0 };
                100.0 * ((self.r - d) / 0.4 + 0.5).clamp(0.0, 1.0) * wall * tunnel
            })
            .collect();
        Ok(FieldOutput { rgb: viewdirs.iter().map(|d| d.map(|x| 0.5 * (1.0 + x))).collect(), sigma })
    }
}

fn ball() -> Ball {
    Ball { c: [0.2, 0.0, -0.1], r: 0.4, hollow: 0.0, tunnel: 0.0 }
}

#[test]
fn a_ball_meshes_onto_its_surface_in_the_scene_frame() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("meshes/ball.ply");
    // The scene's own frame is the field's shrunk by 2 and shifted: x_field = 2·(x + (1, 0, 0)).
    let transform = SceneTransform { scale: 2.0, rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], translation: [1.0, 0.0, 0.0] };
    let options = MeshOptions { resolution: 32, threshold: 50.0, bound: 1.0, keep_cavities: false };
    let mut field = ball();
    let report = extract_mesh::<_, Error>(&mut field, None, &[], &options, &transform, &out, false).unwrap();
    assert_eq!(report.nodes, 33 * 33 * 33);
    assert_eq!(report.evaluated, report.nodes, "no grid: every node");
    assert_eq!(report.max_density, 100.0);
    let mesh = read_ply(&out).unwrap();
    assert_eq!((mesh.vertices.len(), mesh.faces.len()), (report.vertices, report.faces));
    assert!(mesh.comments.iter().any(|c| c.contains("marching cubes at density 50 on 32^3 cells")), "{:?}", mesh.comments);
    // σ = 50 where the ramp is halfway: on the sphere of radius r. In the scene's frame the
    // ball is at c/2 − (1, 0, 0) with radius r/2. Cell 2/32 in the field: vertices well within
    // a tenth of one.
    let centre = [0.2 / 2.0 - 1.0, 0.0, -0.05];
    for v in &mesh.vertices {
        let d = [0, 1, 2].map(|k| v.position[k] - centre[k]);
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        assert!((len - 0.2).abs() < 0.1 * (2.0 / 32.0) / 2.0, "{v:?} at {len}");
        let cos: f32 = (0..3).map(|k| v.normal[k] * d[k] / len).sum();
        assert!(cos > 0.99, "normals point out: {v:?}");
        // The colour is the view direction's: looking along −normal, (1 − n)/2.
        for k in 0..3 {
            let want = (0.5 * (1.0 - v.normal[k]) * 255.0).round();
            assert!((v.color[k] as f32 - want).abs() <= 2.0, "{v:?}");
        }
    }
    let left: Vec<_> = std::fs::read_dir(out.parent().unwrap()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 1, "only the mesh: {left:?}");
    // A part left by a killed writer (PID 0 names none alive) goes with the next mesh.
    let stale = out.with_file_name(".ball.ply.faces.tmp-0");
    std::fs::write(&stale, b"half").unwrap();
    extract_mesh::<_, Error>(&mut ball(), None, &[], &options, &transform, &out, false).unwrap();
    assert!(!stale.exists());
}

#[test]
fn an_occupancy_grid_skips_empty_cells_and_keeps_the_surface() {
    let dir = tempfile::tempdir().unwrap();
    let options = MeshOptions { resolution: 24, threshold: 50.0, bound: 1.0, keep_cavities: false };
    let identity = SceneTransform::identity();
    let (all, skipped) = (dir.path().join("all.ply"), dir.path().join("skipped.ply"));
    extract_mesh::<_, Error>(&mut ball(), None, &[], &options, &identity, &all, false).unwrap();
    // A grid of 8³ cells over the same cube: a cell is occupied (σ 1) when it comes within
    // r + 0.22 of the ball's centre (σ > 0 reaches r + 0.2).
    let mut grid = OccupancyGrid::new(8, 1.0, 0.5);
    let b = ball();
    let sigma: Vec<f32> = (0..512)
        .map(|c| {
            let lo = [c / 64, (c / 8) % 8, c % 8].map(|n| -1.0 + 0.25 * n as f32);
            let gap: f32 = (0..3).map(|k| (lo[k] - b.c[k]).max(b.c[k] - lo[k] - 0.25).max(0.0).powi(2)).sum::<f32>().sqrt();
            if gap < b.r + 0.22 { 1.0 } else { 0.0 }
        })
        .collect();
    grid.update(&sigma, 1.0);
    assert!(grid.occupied_fraction() < 0.5);
    let report = extract_mesh::<_, Error>(&mut ball(), Some(&grid), &[], &options, &identity, &skipped, false).unwrap();
    assert!(report.evaluated < report.nodes / 2, "{report:?}");
    assert_eq!(read_ply(&skipped).unwrap(), read_ply(&all).unwrap(), "the same mesh from fewer evaluations");
}

#[test]
fn a_hollow_inside_is_filled_unless_kept() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("hollow.ply");
    let mut hollow = Ball { c: [0.0; 3], r: 0.8, hollow: 0.4, tunnel: 0.0 };
    let radii = |keep_cavities: bool, hollow: &mut Ball| {
        let options = MeshOptions { resolution: 32, threshold: 50.0, bound: 1.0, keep_cavities };
        let report = extract_mesh::<_, Error>(hollow, None, &[], &options, &SceneTransform::identity(), &out, false).unwrap();
        let radii: Vec<f32> = read_ply(&out).unwrap().vertices.iter().map(|v| Vec3::from_array(v.position).length()).collect();
        (report, radii)
    };
    // Kept: the outer sphere (r 0.8) and the hollow's wall (r 0.4), facing in.
    let (report, kept) = radii(true, &mut hollow);
    assert_eq!(report.filled, 0);
    assert!(kept.iter().any(|&r| (r - 0.4).abs() < 0.01) && kept.iter().any(|&r| (r - 0.8).abs() < 0.01));
    // Filled: the empty nodes inside r 0.4 (about 4/3·π·0.4³ / 0.0625³ ≈ 1100 of them) count
    // as inside, and only the outer sphere is left.
    let (report, filled) = radii(false, &mut hollow);
    assert!((900..1300).contains(&report.filled), "{report:?}");
    assert!(filled.iter().all(|&r| (r - 0.8).abs() < 0.01), "{:?}", filled.iter().fold(1.0f32, |a, &b| a.min(b)));
    assert_eq!(filled.len(), kept.iter().filter(|&&r| r > 0.6).count());
}

#[test]
fn cameras_from_above_close_a_hollow_that_opens_downwards() {
    // The hollow ball with a tunnel from its centre down through its bottom: the outside reaches
    // the hollow, so the cavity fill keeps its wall. 24 cameras above the ball (radius 4, 10° to
    // 70° up, the generated scene's range) see neither the hollow nor the tunnel: carved, only
    // the outer sphere is left where they see it. At σ = 10 the outer sphere is at radius 0.96,
    // the hollow's wall at 0.34 and the tunnel 0.14 wide; the renders' surface (where the rays
    // turn opaque) lies a little inside 0.96, as a trained field's lies inside its σ = 2.5.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tunnel.ply");
    let ball = || Ball { c: [0.0; 3], r: 0.8, hollow: 0.5, tunnel: 0.3 };
    let camera = crate::camera::PinholeCamera::from(crate::camera::Intrinsics::from_camera_angle_x(32, 32, 0.69));
    let frames: Vec<crate::frames::spec::FrameSpec> = [-10.0, -40.0, -70.0]
        .iter()
        .flat_map(|&phi| (0..8).map(move |k| crate::camera::Pose::spherical(45.0 * k as f32, phi, 4.0)))
        .enumerate()
        .map(|(k, pose)| crate::frames::spec::FrameSpec { name: format!("v{k}"), camera, pose, target: None })
        .collect();
    let render_options = crate::render::RenderOptions::new(crate::sample::SamplingConfig::default(), false, 4096, false);
    let views = carve::render_depth_views(&frames, (2.0, 6.0), |k, pose| crate::render::render_image(&mut ball(), None, k, pose, &render_options, &mut |_, _| {}), false).unwrap();
    let options = MeshOptions { resolution: 32, threshold: 10.0, bound: 1.0, keep_cavities: false };
    let mesh = |views: &[DepthView]| {
        let report = extract_mesh::<_, Error>(&mut ball(), None, views, &options, &SceneTransform::identity(), &out, false).unwrap();
        let mesh = read_ply(&out).unwrap();
        assert_eq!(report.views, views.len());
        assert!(mesh.comments.iter().any(|c| c.starts_with("cavities: filled")), "{:?}", mesh.comments);
        (report, mesh.vertices.iter().map(|v| Vec3::from_array(v.position)).collect::<Vec<_>>())
    };
    let (open, walls) = mesh(&[]);
    assert!(walls.iter().any(|p| (p.length() - 0.34).abs() < 0.01), "the hollow's wall, through the tunnel");
    let (carved, kept) = mesh(&views);
    assert!(carved.filled > open.filled + 1000, "{carved:?} vs {open:?}");
    // Above the ball's lower part, which the cameras see at a slant (or not at all: the space
    // under it is filled, and the surface bulges out where the views stop seeing it): the
    // outer sphere alone, as exactly as without carving (the empty nodes just outside it stay
    // open).
    let seen: Vec<f32> = kept.iter().filter(|p| p.z > -0.5).map(|p| p.length()).collect();
    assert!(seen.len() > 500 && seen.iter().all(|&r| (r - 0.96).abs() < 0.01), "{} vertices, radii {:?}", seen.len(), seen.iter().fold((1f32, 0f32), |(a, b), &r| (a.min(r), b.max(r))));
    assert_eq!(seen.len(), walls.iter().filter(|p| p.z > -0.5 && p.length() > 0.6).count());
}

#[test]
fn bad_options_and_empty_meshes_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("mesh.ply");
    let identity = SceneTransform::identity();
    let run = |options: MeshOptions| extract_mesh::<_, Error>(&mut ball(), None, &[], &options, &identity, &out, false).unwrap_err().to_string();
    let ok = MeshOptions { resolution: 8, threshold: 50.0, bound: 1.0, keep_cavities: false };
    assert!(run(MeshOptions { resolution: 0, ..ok }).contains("--resolution"));
    assert!(run(MeshOptions { resolution: 1, ..ok }).contains("at least 2"));
    assert!(run(MeshOptions { resolution: MAX_RESOLUTION + 1, ..ok }).contains("--resolution"));
    assert!(run(MeshOptions { threshold: f32::NAN, ..ok }).contains("--threshold NaN"));
    assert!(run(MeshOptions { threshold: -1.0, ..ok }).contains("--threshold -1"));
    assert!(run(MeshOptions { bound: 0.0, ..ok }).contains("--bound 0"));
    let err = run(MeshOptions { threshold: 500.0, ..ok });
    assert!(err.contains("no density above --threshold 500") && err.contains("the largest seen is 100.000"), "{err}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "nothing written");
    let err = extract_mesh::<_, Error>(&mut ball(), None, &[], &ok, &identity, dir.path(), false).unwrap_err().to_string();
    assert!(err.contains("is a directory"), "{err}");
}

#[test]
fn boxes_kinds_and_placements() {
    let grid = OccupancyGrid::new(4, 2.0, 0.1);
    assert_eq!(choose_bound(Some(1.2), Some(1.5), Some(&grid)), (1.2, BoundSource::Option));
    assert_eq!(choose_bound(None, Some(1.5), Some(&grid)), (1.5, BoundSource::Field));
    assert_eq!(choose_bound(None, None, Some(&grid)), (2.0, BoundSource::Occupancy));
    assert_eq!(choose_bound(None, None, None), (DEFAULT_BOUND, BoundSource::Default));
    assert_eq!(kind_named("ngp"), Some(FieldKind::Ngp));
    assert_eq!(kind_named("mlp").map(default_threshold), Some(50.0));
    assert_eq!(kind_named("tensorf"), None);
    let source = Path::new("run/source.json");
    let mut placement = ScenePlacement { format: CaptureFormat::Llff, transform: SceneTransform::identity(), near_far: Some((0.0, 1.0)), orbit: None, ndc: None };
    placement.transform.scale = 0.5;
    assert_eq!(scene_transform(Some(&placement), false, source).unwrap().scale, 0.5);
    assert_eq!(scene_transform(None, false, source).unwrap(), SceneTransform::identity());
    let err = scene_transform(None, true, source).unwrap_err().to_string();
    assert!(err.starts_with("run/source.json: the scene was trained with NDC rays"), "{err}");
    placement.ndc = Some(Ndc { width: 8.0, height: 6.0, fx: 10.0, fy: 10.0, near: 1.0 });
    assert!(scene_transform(Some(&placement), false, source).is_err());
    // Options: the kind's threshold unless given; an unknown kind needs one.
    let request = MeshRequest { resolution: 64, threshold: None, bound: None, keep_cavities: false };
    let (options, from) = request.options(Some(FieldKind::Ngp), Some(1.5), None, source).unwrap();
    assert_eq!((options, from), (MeshOptions { resolution: 64, threshold: 2.5, bound: 1.5, keep_cavities: false }, BoundSource::Field));
    let err = request.options(None, None, None, source).unwrap_err().to_string();
    assert!(err.contains("give --threshold"), "{err}");
    let err = MeshRequest { bound: Some(-1.0), ..request }.options(Some(FieldKind::Mlp), None, None, source).unwrap_err().to_string();
    assert!(err.contains("--bound -1"), "{err}");
}
