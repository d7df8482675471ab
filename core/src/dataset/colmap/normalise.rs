//! instant-ngp's placement of a COLMAP capture (`colmap2nerf.py`'s conventions, written here
//! from their description): the cameras' mean up direction becomes +z, the point their optical
//! axes pass closest to (weighted over all pairs, in front of both cameras) becomes the origin,
//! and the cameras' mean distance from it becomes 4. With it comes an `aabb_scale`, the side of
//! the scene box in instant-ngp's units (where the cameras sit at 4 × 0.33 ≈ 1.3 from the
//! centre): the box holds the content up to `aabb_scale / 2 / 0.33 / 4` times the cameras'
//! distance from the centre.

use glam::{DMat3, DVec3};

/// The cameras' mean distance from the centre after [`normalise`].
pub const MEAN_CAMERA_DISTANCE: f64 = 4.0;

/// Pairs of optical axes closer to parallel than this (|da × db|², unit directions) say
/// nothing about where they meet.
const MIN_PAIR_WEIGHT: f64 = 1e-5;

/// The similarity [`normalise`] applied: `p ↦ scale · (rotation · p − centre)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Normalisation {
    /// Rotation taking the cameras' mean up to +z.
    pub rotation: DMat3,
    /// The rotated centre of attention, moved to the origin.
    pub centre: DVec3,
    /// Scale putting the cameras at [`MEAN_CAMERA_DISTANCE`] on average.
    pub scale: f64,
}

impl Normalisation {
    /// The mapping as a 3 × 4 matrix `[scale·R | −scale·centre]` (nerfstudio's
    /// `applied_transform` layout, rows).
    pub fn matrix(&self) -> [[f64; 4]; 3] {
        let r = self.rotation.transpose().to_cols_array_2d(); // rows of R
        let t = -self.scale * self.centre;
        [0, 1, 2].map(|i| [self.scale * r[i][0], self.scale * r[i][1], self.scale * r[i][2], t[i]])
    }
}

/// The rotation taking unit `from` to +z (about their common normal; a half turn about x when
/// `from` is −z).
fn rotation_to_z(from: DVec3) -> DMat3 {
    let z = DVec3::Z;
    let axis = from.cross(z);
    let (sin, cos) = (axis.length(), from.dot(z));
    if sin < 1e-12 {
        return if cos > 0.0 { DMat3::IDENTITY } else { DMat3::from_rotation_x(std::f64::consts::PI) };
    }
    DMat3::from_axis_angle(axis / sin, sin.atan2(cos))
}

/// Where the optical axes (origin `o`, forward `d`, unit) of two cameras pass closest to each
/// other, with the pair's weight `|da × db|²` (0 when nearly parallel). Points behind a camera
/// are clamped to its centre.
fn closest_point(oa: DVec3, da: DVec3, ob: DVec3, db: DVec3) -> (DVec3, f64) {
    let c = da.cross(db);
    let denom = c.length_squared();
    if denom < MIN_PAIR_WEIGHT {
        return (DVec3::ZERO, 0.0);
    }
    let w = ob - oa;
    let s = (DMat3::from_cols(w, db, c).determinant() / denom).max(0.0);
    let t = (DMat3::from_cols(w, da, c).determinant() / denom).max(0.0);
    (0.5 * (oa + s * da + ob + t * db), denom)
}

/// Moves OpenGL camera-to-world matrices (3 × 4 rows) into instant-ngp's placement (module
/// doc) and returns the mapping applied. Cameras whose axes never meet (all parallel) are
/// centred on their centroid.
pub fn normalise(c2ws: &mut [[[f64; 4]; 3]]) -> Normalisation {
    let column = |m: &[[f64; 4]; 3], j: usize| DVec3::new(m[0][j], m[1][j], m[2][j]);
    let up = c2ws.iter().map(|m| column(m, 1)).sum::<DVec3>().normalize_or(DVec3::Z);
    let rotation = rotation_to_z(up);
    let rotated: Vec<(DVec3, DMat3)> = c2ws
        .iter()
        .map(|m| (rotation * column(m, 3), rotation * DMat3::from_cols(column(m, 0), column(m, 1), column(m, 2))))
        .collect();
    let (mut sum, mut weight) = (DVec3::ZERO, 0.0);
    for (i, (oa, ra)) in rotated.iter().enumerate() {
        for (ob, rb) in &rotated[i + 1..] {
            let (p, w) = closest_point(*oa, -ra.z_axis, *ob, -rb.z_axis);
            sum += w * p;
            weight += w;
        }
    }
    let centre = if weight > 0.0 { sum / weight } else { rotated.iter().map(|(o, _)| *o).sum::<DVec3>() / rotated.len().max(1) as f64 };
    let mean = rotated.iter().map(|(o, _)| (*o - centre).length()).sum::<f64>() / rotated.len().max(1) as f64;
    let scale = if mean > 0.0 && mean.is_finite() { MEAN_CAMERA_DISTANCE / mean } else { 1.0 };
    for (m, (o, r)) in c2ws.iter_mut().zip(&rotated) {
        let p = scale * (*o - centre);
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] = r.col(j)[i];
            }
            m[i][3] = p[i];
        }
    }
    Normalisation { rotation, centre, scale }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An OpenGL camera at `origin` looking at `target` with `up` roughly up.
    fn look_at(origin: DVec3, target: DVec3, up: DVec3) -> [[f64; 4]; 3] {
        let back = (origin - target).normalize();
        let right = up.cross(back).normalize();
        let true_up = back.cross(right);
        [0, 1, 2].map(|i| [right[i], true_up[i], back[i], origin[i]])
    }

    #[test]
    fn the_axes_meeting_point_goes_to_the_origin_and_up_to_z() {
        // Six cameras on a tilted ring of radius 2 about (1, 2, 3), 1 above its plane, all
        // looking at (1, 2, 3), with up along the ring's normal.
        let target = DVec3::new(1.0, 2.0, 3.0);
        let normal = DVec3::new(0.3, -0.2, 1.0).normalize();
        let u = normal.cross(DVec3::X).normalize();
        let v = normal.cross(u);
        let mut c2ws: Vec<_> = (0..6)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 6.0;
                look_at(target + 2.0 * (a.cos() * u + a.sin() * v) + normal, target, normal)
            })
            .collect();
        let before = c2ws.clone();
        let n = normalise(&mut c2ws);
        // All cameras were √5 from the target: now 4 from the origin, 4/√5 above the plane.
        for m in &c2ws {
            let o = DVec3::new(m[0][3], m[1][3], m[2][3]);
            assert!((o.length() - 4.0).abs() < 1e-9, "{o}");
            assert!((o.z - 4.0 / 5f64.sqrt()).abs() < 1e-9, "{o}");
            // Still looking at the (new) centre.
            let forward = -DVec3::new(m[0][2], m[1][2], m[2][2]);
            assert!((forward.dot(-o.normalize()) - 1.0).abs() < 1e-9);
        }
        assert!((n.scale - 4.0 / 5f64.sqrt()).abs() < 1e-9);
        // The matrix maps the old camera centres to the new ones.
        let m = n.matrix();
        for (old, new) in before.iter().zip(&c2ws) {
            for i in 0..3 {
                let mapped = (0..3).map(|j| m[i][j] * old[j][3]).sum::<f64>() + m[i][3];
                assert!((mapped - new[i][3]).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn closest_points_of_two_axes_on_hand_values() {
        // Axes along +x through (0, 0, 0) and along +y through (1, −1, 2): closest at (1, 0, 0)
        // and (1, 0, 2), so the midpoint (1, 0, 1), weight |x × y|² = 1.
        let (p, w) = closest_point(DVec3::ZERO, DVec3::X, DVec3::new(1.0, -1.0, 2.0), DVec3::Y);
        assert!((p - DVec3::new(1.0, 0.0, 1.0)).length() < 1e-12 && (w - 1.0).abs() < 1e-12, "{p} {w}");
        // Parallel axes carry no weight.
        assert_eq!(closest_point(DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::X).1, 0.0);
        // Up already +z: no rotation; up −z: a half turn.
        assert_eq!(rotation_to_z(DVec3::Z), DMat3::IDENTITY);
        assert!((rotation_to_z(-DVec3::Z) * -DVec3::Z - DVec3::Z).length() < 1e-12);
        let tilted = DVec3::new(0.2, 0.5, 0.8).normalize();
        assert!((rotation_to_z(tilted) * tilted - DVec3::Z).length() < 1e-12);
    }
}
