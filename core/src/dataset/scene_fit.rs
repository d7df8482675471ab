//! How a capture is placed in the field's cube and viewed: the transform that fits it (decided
//! once, when a run starts, and recorded), near/far for its rays, and the orbit around it.

use glam::{Mat3, Vec3};
use serde::{Deserialize, Serialize};

use super::capture::{Capture, centroid, focus_point};
use super::llff::poses_avg;
use crate::camera::Pose;
use crate::error::{Error, Result};
use crate::camera::transform::{SceneTransform, pose_from};

/// Near for captures without bounds, as a fraction of the cube's half-size (cameras may sit
/// inside the cube, so content can be close).
const BOX_NEAR_FRACTION: f32 = 1.0 / 30.0;

/// Where the farthest camera of a capture fitted by its cameras sits, as a fraction of the
/// cube's half-size. A 360° capture sees the room around its object: with the cameras at a
/// third of the bound, content up to three times the ring's radius from the centre lies inside
/// the field (bird's ring of radius ≈ 4 sees walls at ≈ 10); what lies farther is drawn on the
/// cube's faces. The choice over a scene contraction (mip-NeRF 360): the field, its ONNX graph
/// and every renderer stay as they are, at the cost of a third of the grid's resolution on the
/// object.
pub const RING_FRACTION: f32 = 1.0 / 3.0;

/// The transform (applied after the parser's own) that puts `capture` into the field's cube
/// `[−bound, bound]³`:
/// - a file with `aabb_scale` (instant-ngp): its scene box `[−a/2, a/2]³` becomes the cube;
/// - forward-facing views with depth bounds (LLFF): the cube spans the bounds' depth range,
///   centred at mid-depth in front of the cameras' centroid along their mean view direction;
/// - otherwise: centred where the optical axes meet (the centroid when they are parallel),
///   scaled so that the farthest camera is `RING_FRACTION · bound` away (the object sits
///   inside the ring, the room around it inside the cube).
pub fn fit_to_field(capture: &Capture, bound: f32) -> Result<SceneTransform> {
    let poses = capture.poses();
    if let Some(a) = capture.aabb_scale {
        if !(a > 0.0 && a.is_finite()) {
            return Err(Error::invalid(&capture.source, format!("aabb_scale {a} must be positive")));
        }
        return Ok(SceneTransform { scale: bound / (0.5 * a), ..SceneTransform::identity() });
    }
    if capture.forward_facing
        && let Some((near, far)) = capture.near_far
    {
        let forward = poses.iter().map(|p| p.rotation() * Vec3::NEG_Z).sum::<Vec3>().normalize();
        let centre = centroid(&poses) + forward * (0.5 * (near + far));
        let half = 0.5 * (far - near);
        if !(half > 0.0 && centre.is_finite()) {
            return Err(Error::invalid(&capture.source, format!("bounds ({near}, {far}) give no depth range to fit")));
        }
        return Ok(SceneTransform { scale: bound / half, translation: (-centre).to_array(), ..SceneTransform::identity() });
    }
    capture.camera_fit(RING_FRACTION * bound)
}

/// The smallest instant-ngp `aabb_scale` read as "the background reaches far": instant-ngp's
/// advice for natural scenes seen past the unit cube, and what `nerf process-data --aabb-scale`
/// suggests for a background that matters (docs/captures.md). Smaller boxes bound their scene.
pub const FAR_AABB_SCALE: f32 = 8.0;

/// Why a new run on `capture` contracts its world when not told either way (`nerf train`
/// without `--contract`), or `None` for the cube. The rule: a capture that neither trains on
/// NDC rays (`ndc`), nor faces one way, nor bounds itself with an `aabb_scale` under
/// [`FAR_AABB_SCALE`], sees a world with no edge (a 360° ring in a room, a phone walked around
/// a table), which the cube can only hold at a third of its resolution on the object. Blender
/// scenes never reach here: their cube is their scene.
pub fn contraction_by_default(capture: &Capture, ndc: bool) -> Option<String> {
    if ndc || capture.forward_facing {
        return None;
    }
    match capture.aabb_scale {
        Some(a) if a < FAR_AABB_SCALE => None,
        Some(a) => Some(format!("aabb_scale {a} (≥ {FAR_AABB_SCALE}): its background reaches far")),
        None => Some("its cameras look inwards from all around, and it gives no scene box".to_string()),
    }
}

/// How far from the centre the farthest camera of a contracted capture sits: on the unit
/// sphere, inside the inner cube ‖x‖∞ ≤ 1 that contraction leaves as it is (nerfstudio scales
/// poses into [−1, 1] too); the object inside the ring, the room in the contracted shell.
pub const CONTRACTED_RING: f32 = 1.0;

/// Far for a contracted capture's rays: marching's segments reach 170 units
/// ([`crate::render::grid::march_segments`]), where the contracted shell is within 1/170 of its
/// outer face.
pub const CONTRACTED_FAR: f32 = 100.0;

/// The transform (applied after the parser's own) that places `capture` for a contracted
/// field: centred where the optical axes meet, the farthest camera [`CONTRACTED_RING`] away,
/// whatever its kind (an instant-ngp `aabb_scale` box is not used: the contraction reaches
/// everything).
pub fn fit_contracted(capture: &Capture) -> Result<SceneTransform> {
    capture.camera_fit(CONTRACTED_RING)
}

/// Near and far for rays of a contracted capture (poses in the field's frame): near from the
/// file's depth bounds (LLFF: 0.9 · nearest) when it has them, at most half the ring's radius,
/// else 1/30 of it; far [`CONTRACTED_FAR`].
pub fn contracted_near_far(capture: &Capture) -> (f32, f32) {
    let near = match capture.near_far {
        Some((near, far)) if near > 0.0 && far > near => near.min(0.5 * CONTRACTED_RING),
        _ => BOX_NEAR_FRACTION * CONTRACTED_RING,
    };
    (near, CONTRACTED_FAR)
}

/// Near and far for rays of a fitted capture (poses in the field's frame): the file's depth
/// bounds (LLFF: 0.9 · nearest, farthest, as nerf-pytorch without NDC) when it has them, never
/// past the cube as seen from the farthest camera (`|o| + √3·bound`); otherwise from
/// `bound / 30` to that distance.
pub fn field_near_far(capture: &Capture, bound: f32) -> (f32, f32) {
    let farthest = capture.views.iter().map(|v| v.pose.origin().length()).fold(0.0f32, f32::max);
    let box_far = farthest + 3f32.sqrt() * bound;
    let box_near = BOX_NEAR_FRACTION * bound;
    match capture.near_far {
        Some((near, far)) if near > 0.0 && far > near => (near.min(box_far * 0.5), far.min(box_far)),
        _ => (box_near, box_far),
    }
}

/// A circle of cameras around a captured scene: centred on the cameras' centroid, in the plane
/// through it perpendicular to their mean up direction, at their mean distance from that axis,
/// every camera looking at `target` (where the cameras' axes meet, else the cube's centre)
/// with `up` up.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OrbitPath {
    /// Centre of the circle.
    pub centre: [f32; 3],
    /// Unit normal of the circle's plane (the cameras' mean up).
    pub up: [f32; 3],
    /// Unit direction from the centre to the first frame.
    pub start: [f32; 3],
    /// Radius.
    pub radius: f32,
    /// The point every frame looks at.
    pub target: [f32; 3],
}

impl OrbitPath {
    /// The orbit around cameras `poses` (in the field's frame); `None` for no poses or a
    /// degenerate (non-finite) result.
    pub fn around(poses: &[Pose]) -> Option<OrbitPath> {
        let centre = centroid(poses);
        let up = poses.iter().map(|p| p.rotation() * Vec3::Y).sum::<Vec3>().normalize_or_zero();
        if up == Vec3::ZERO {
            return None;
        }
        let across = |p: &Pose| {
            let d = p.origin() - centre;
            d - d.dot(up) * up
        };
        let radius = poses.iter().map(|p| across(p).length()).sum::<f32>() / poses.len() as f32;
        // Start at the first camera's side (any perpendicular when it sits on the axis).
        let start = across(&poses[0]).try_normalize().unwrap_or_else(|| up.any_orthonormal_vector());
        let target = focus_point(poses).unwrap_or(Vec3::ZERO);
        let path = OrbitPath { centre: centre.to_array(), up: up.to_array(), start: start.to_array(), radius, target: target.to_array() };
        (centre.is_finite() && radius.is_finite() && target.is_finite()).then_some(path)
    }

    /// `frames` poses evenly around the circle, the first at `start`.
    pub fn poses(&self, frames: usize) -> Vec<Pose> {
        let (centre, up, start) = (Vec3::from(self.centre), Vec3::from(self.up), Vec3::from(self.start));
        let side = up.cross(start);
        (0..frames)
            .map(|k| {
                let a = std::f32::consts::TAU * k as f32 / frames as f32;
                let origin = centre + self.radius * (a.cos() * start + a.sin() * side);
                let back = (origin - Vec3::from(self.target)).normalize();
                let right = up.cross(back).normalize();
                pose_from(Mat3::from_cols(right, back.cross(right), back), origin)
            })
            .collect()
    }
}

/// A camera path for rendering a capture: the circle around an object, or nerf-pytorch's
/// spiral in front of a forward-facing capture. Serialised without a tag (the spiral's fields
/// tell them apart; files written before the spiral hold a circle).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum CameraPath {
    /// nerf-pytorch's `render_path_spiral` (forward-facing captures).
    Spiral(SpiralPath),
    /// A circle around the cameras' centre ([`OrbitPath`]).
    Circle(OrbitPath),
}

impl CameraPath {
    /// `frames` poses along the path.
    pub fn poses(&self, frames: usize) -> Vec<Pose> {
        match self {
            CameraPath::Spiral(s) => s.poses(frames),
            CameraPath::Circle(c) => c.poses(frames),
        }
    }
}

/// nerf-pytorch's `render_path_spiral` for LLFF captures: the camera moves on an ellipse in the
/// average camera's frame (`cos θ·r_x` right, `−sin θ·r_y` up, `−sin(θ/2)·r_z` back) for two
/// turns, always looking at the point `focus_depth` in front of the average camera.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpiralPath {
    /// The average camera's centre.
    pub centre: [f32; 3],
    /// The average camera's axes (right, up, back), each a unit vector.
    pub axes: [[f32; 3]; 3],
    /// Semi-axes of the ellipse: the 90th percentile of the cameras' offsets on each axis.
    pub radii: [f32; 3],
    /// Distance in front of the average camera that every frame looks at.
    pub focus_depth: f32,
    /// Turns over the whole path (nerf-pytorch: 2).
    pub rotations: f32,
}

impl SpiralPath {
    /// The spiral of forward-facing cameras `poses` whose content lies between `near` and `far`
    /// (in the same frame): focus at `1/(0.25/near + 0.75/(5·far))`, nerf-pytorch's
    /// `close_depth = 0.9·min bound` (its `near`), `inf_depth = 5·max bound`, `dt = 0.75`.
    /// `None` for no poses or non-finite results.
    pub fn around(poses: &[Pose], near: f32, far: f32) -> Option<SpiralPath> {
        if poses.is_empty() {
            return None;
        }
        let average = poses_avg(poses);
        let r = average.rotation();
        let centre = average.origin();
        let mut radii = [0.0f32; 3];
        for (axis, radius) in radii.iter_mut().enumerate() {
            let mut offsets: Vec<f32> = poses.iter().map(|p| (r.transpose() * (p.origin() - centre))[axis].abs()).collect();
            *radius = percentile(&mut offsets, 90.0);
        }
        let focus_depth = 1.0 / (0.25 / near + 0.75 / (5.0 * far));
        let axes = [r.x_axis.to_array(), r.y_axis.to_array(), r.z_axis.to_array()];
        let path = SpiralPath { centre: centre.to_array(), axes, radii, focus_depth, rotations: 2.0 };
        let finite = centre.is_finite() && radii.iter().all(|v| v.is_finite()) && focus_depth.is_finite() && focus_depth > 0.0;
        finite.then_some(path)
    }

    /// `frames` poses along the spiral, the first at angle 0 (nerf-pytorch drops its last
    /// of N + 1 angles, as here).
    pub fn poses(&self, frames: usize) -> Vec<Pose> {
        let [x, y, z] = self.axes.map(Vec3::from);
        let centre = Vec3::from(self.centre);
        let [rx, ry, rz] = self.radii;
        let target = centre - self.focus_depth * z;
        (0..frames)
            .map(|k| {
                let theta = std::f32::consts::TAU * self.rotations * k as f32 / frames.max(1) as f32;
                let origin = centre + theta.cos() * rx * x - theta.sin() * ry * y - (0.5 * theta).sin() * rz * z;
                let back = (origin - target).normalize();
                let right = y.cross(back).normalize();
                pose_from(Mat3::from_cols(right, back.cross(right).normalize(), back), origin)
            })
            .collect()
    }
}

/// numpy's default (linear) percentile `q` of `values` (sorted in place); 0 for none.
fn percentile(values: &mut [f32], q: f32) -> f32 {
    if values.is_empty() {
        return 0.0;
    }
    values.sort_by(f32::total_cmp);
    let rank = q / 100.0 * (values.len() - 1) as f32;
    let (lo, hi) = (rank.floor() as usize, rank.ceil() as usize);
    values[lo] + (rank - lo as f32) * (values[hi] - values[lo])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{PinholeCamera, PixelCenter};
    use crate::dataset::{CaptureFormat, CaptureView};
    use std::path::PathBuf;

    /// A camera at `origin` looking at `target`, +y up.
    fn look_at(origin: Vec3, target: Vec3) -> Pose {
        let back = (origin - target).normalize();
        let right = Vec3::Y.cross(back).normalize();
        pose_from(Mat3::from_cols(right, back.cross(right), back), origin)
    }

    fn capture(poses: &[Pose], near_far: Option<(f32, f32)>, forward_facing: bool, aabb_scale: Option<f32>) -> Capture {
        let camera = PinholeCamera { width: 4, height: 4, fx: 4.0, fy: 4.0, cx: 2.0, cy: 2.0, pixel_center: PixelCenter::HalfPixel, distortion: None };
        Capture {
            format: CaptureFormat::Llff,
            source: PathBuf::from("poses_bounds.npy"),
            views: poses.iter().map(|&pose| CaptureView { name: "v".into(), image_path: "v.png".into(), camera, pose, bounds: near_far }).collect(),
            transform: SceneTransform::identity(),
            near_far,
            forward_facing,
            aabb_scale,
            scale: None,
            offset: None,
            explicit_splits: None,
            warnings: vec![],
        }
    }

    /// Eight cameras on a ring of radius 4 about (1, 2, 3), 3 above it, looking at it.
    fn ring() -> Vec<Pose> {
        let target = Vec3::new(1.0, 2.0, 3.0);
        (0..8)
            .map(|k| {
                let a = k as f32 * std::f32::consts::TAU / 8.0;
                look_at(target + Vec3::new(4.0 * a.cos(), 3.0, 4.0 * a.sin()), target)
            })
            .collect()
    }

    #[test]
    fn only_unbounded_captures_contract_by_default() {
        let why = |c: &Capture, ndc: bool| contraction_by_default(c, ndc);
        // A ring with no box: contracted, unless its rays are NDC.
        assert!(why(&capture(&ring(), None, false, None), false).is_some_and(|w| w.contains("no scene box")));
        assert_eq!(why(&capture(&ring(), None, false, None), true), None);
        // Cameras facing one way keep the cube (and usually NDC).
        assert_eq!(why(&capture(&ring(), Some((1.0, 5.0)), true, None), false), None);
        // A box under 8 bounds the scene; from 8 on, the background reaches far.
        assert_eq!(why(&capture(&ring(), None, false, Some(4.0)), false), None);
        assert_eq!(why(&capture(&ring(), None, false, Some(7.9)), false), None);
        assert!(why(&capture(&ring(), None, false, Some(FAR_AABB_SCALE)), false).is_some_and(|w| w.contains("aabb_scale 8")));
        assert!(why(&capture(&ring(), None, false, Some(16.0)), false).is_some());
    }

    #[test]
    fn a_ring_is_centred_on_its_focus_with_the_farthest_camera_at_a_third_of_the_bound() {
        let c = capture(&ring(), None, false, None);
        let t = fit_to_field(&c, 1.5).unwrap();
        // Every camera is 5 from the focus (1, 2, 3) and lands at 1.5/3: scale 0.5/5 = 0.1.
        assert!((t.scale - 0.1).abs() < 1e-6, "{t:?}");
        assert!(t.apply_point(Vec3::new(1.0, 2.0, 3.0)).length() < 1e-4);
        let mut fitted = c.clone();
        fitted.renormalise(&t);
        // No bounds: near = 1.5/30, far = 0.5 + √3·1.5.
        let (near, far) = field_near_far(&fitted, 1.5);
        assert!((near - 0.05).abs() < 1e-6 && (far - (0.5 + 3f32.sqrt() * 1.5)).abs() < 1e-4, "{near} {far}");
    }

    #[test]
    fn an_aabb_becomes_the_cube_and_forward_facing_bounds_span_it() {
        let c = capture(&ring(), None, false, Some(4.0));
        let t = fit_to_field(&c, 1.5).unwrap();
        // [−2, 2]³ → [−1.5, 1.5]³: scale 0.75, no shift.
        assert_eq!((t.scale, t.translation), (0.75, [0.0; 3]));
        // Two cameras at x = ±1 looking down −z, bounds (2, 10): mid-depth 6, half-range 4.
        let rig = [look_at(Vec3::X, Vec3::new(1.0, 0.0, -1.0)), look_at(-Vec3::X, Vec3::new(-1.0, 0.0, -1.0))];
        let c = capture(&rig, Some((2.0, 10.0)), true, None);
        let t = fit_to_field(&c, 1.5).unwrap();
        assert!((t.scale - 0.375).abs() < 1e-6, "{t:?}");
        assert!(t.apply_point(Vec3::new(0.0, 0.0, -6.0)).length() < 1e-5);
        // The nearest content (depth 2) lands on the cube's face: z = (−2 + 6)·0.375 = 1.5.
        assert!((t.apply_point(Vec3::new(0.0, 0.0, -2.0)).z - 1.5).abs() < 1e-5);
        let mut fitted = c.clone();
        fitted.renormalise(&t);
        // Bounds scale by 0.375: (0.75, 3.75); the cube seen from a camera at distance
        // |(±0.375, 0, 2.25)| = 2.281 reaches 2.281 + 2.598 = 4.879, past 3.75.
        let (near, far) = field_near_far(&fitted, 1.5);
        assert!((near - 0.75).abs() < 1e-5 && (far - 3.75).abs() < 1e-5, "{near} {far}");
        // A single camera gives no scale: a clear error naming the file.
        let err = fit_to_field(&capture(&ring()[..1], None, false, None), 1.5).unwrap_err().to_string();
        assert!(err.contains("poses_bounds.npy") && err.contains("farthest camera at distance 0"), "{err}");
    }

    #[test]
    fn the_spiral_is_nerf_pytorchs_render_path_spiral() {
        // Five cameras facing −z: at the origin, (±1, 0, 0) and (0, ±0.5, 0). The average camera
        // is the identity; the 90th percentiles of |x|, |y|, |z| are 1, 0.5, 0 (numpy's linear
        // rule: sorted [0, 0, 0, 1, 1] at rank 3.6 → 1).
        let at = |x: f32, y: f32| pose_from(Mat3::IDENTITY, Vec3::new(x, y, 0.0));
        let poses = [at(0.0, 0.0), at(1.0, 0.0), at(-1.0, 0.0), at(0.0, 0.5), at(0.0, -0.5)];
        let spiral = SpiralPath::around(&poses, 1.0, 10.0).unwrap();
        assert!((Vec3::from(spiral.centre)).length() < 1e-6);
        assert_eq!(spiral.radii, [1.0, 0.5, 0.0]);
        // focus = 1/(0.25/1 + 0.75/(5·10)) = 1/0.265.
        assert!((spiral.focus_depth - 1.0 / 0.265).abs() < 1e-4, "{}", spiral.focus_depth);
        let frames = spiral.poses(8);
        // θ = 2π·2·k/8: k = 0 at (r_x, 0, 0); k = 1 at θ = π/2: (0, −r_y, −sin(π/4)·r_z).
        assert!((frames[0].origin() - Vec3::X).length() < 1e-6);
        assert!((frames[1].origin() - Vec3::new(0.0, -0.5, 0.0)).length() < 1e-6);
        let target = Vec3::new(0.0, 0.0, -spiral.focus_depth);
        for f in &frames {
            let forward = f.rotation() * Vec3::NEG_Z;
            assert!((forward - (target - f.origin()).normalize()).length() < 1e-5);
            // Upright: the right axis stays horizontal (no roll), as viewmatrix with up = +y.
            assert!((f.rotation() * Vec3::X).y.abs() < 1e-6);
        }
        // A path written by an older version (a circle) still reads back as one.
        let circle = CameraPath::Circle(OrbitPath::around(&ring()).unwrap());
        let json = serde_json::to_string(&circle).unwrap();
        assert_eq!(serde_json::from_str::<CameraPath>(&json).unwrap(), circle);
        let json = serde_json::to_string(&CameraPath::Spiral(spiral)).unwrap();
        assert_eq!(serde_json::from_str::<CameraPath>(&json).unwrap(), CameraPath::Spiral(spiral));
        assert_eq!(SpiralPath::around(&[], 1.0, 10.0), None);
    }

    #[test]
    fn the_orbit_circles_the_cameras_at_their_height_looking_at_the_centre() {
        // Cameras on a ring of radius 2 at height 1 about the origin, looking at the origin.
        let poses: Vec<Pose> = (0..6)
            .map(|k| {
                let a = k as f32 * std::f32::consts::TAU / 6.0;
                look_at(Vec3::new(2.0 * a.cos(), 1.0, 2.0 * a.sin()), Vec3::ZERO)
            })
            .collect();
        let orbit = OrbitPath::around(&poses).unwrap();
        assert!((Vec3::from(orbit.centre) - Vec3::Y).length() < 1e-5, "{orbit:?}");
        assert!((orbit.radius - 2.0).abs() < 1e-5);
        // The cameras' mean up: the ring looks down at 26.6°, their up axes average to +y.
        assert!((Vec3::from(orbit.up) - Vec3::Y).length() < 1e-5);
        let frames = orbit.poses(12);
        assert_eq!(frames.len(), 12);
        // The first frame is the first camera.
        assert!((frames[0].origin() - poses[0].origin()).length() < 1e-5);
        for f in &frames {
            assert!((f.origin().y - 1.0).abs() < 1e-5 && (f.origin().x.hypot(f.origin().z) - 2.0).abs() < 1e-5);
            let forward = f.rotation() * Vec3::NEG_Z;
            assert!((forward - (-f.origin()).normalize()).length() < 1e-5);
        }
        assert_eq!(OrbitPath::around(&[]), None);
    }
}
