//! Marching cubes over a lattice fed one z-slice at a time: memory is a few slices, never the
//! whole volume.
//!
//! The lattice has `n + 1` nodes per axis at `origin + spacing · (i, j, k)`; slice `k` holds its
//! nodes' values at index `j·(n + 1) + i`. Layer `k` (the cubes between slices `k` and `k + 1`)
//! is marched once slices `k − 1` to `k + 2` are in: the outer two give the density gradient
//! (central differences, one-sided at the lattice's faces) that becomes each vertex's normal.
//! A vertex sits on a lattice edge where the values cross the threshold (linear interpolation)
//! and is shared by every cube around that edge: the ids of the vertices on slice `k + 1`'s
//! edges are kept for the next layer, so the mesh is indexed, not a triangle soup.

use super::cases::{EDGES, corner_offset, triangles};
use std::collections::VecDeque;

/// Where the lattice is and how fine.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lattice {
    /// Cells per axis (`n + 1` nodes).
    pub n: usize,
    /// Node (0, 0, 0).
    pub origin: [f32; 3],
    /// Distance between neighbouring nodes.
    pub spacing: f32,
}

impl Lattice {
    /// The cube `[−bound, bound]³` cut into `n` cells per axis.
    pub fn cube(n: usize, bound: f32) -> Self {
        Lattice { n, origin: [-bound; 3], spacing: 2.0 * bound / n as f32 }
    }

    /// Nodes per slice, `(n + 1)²`.
    pub fn slice_len(&self) -> usize {
        (self.n + 1) * (self.n + 1)
    }

    /// Node `(i, j, k)`'s position.
    pub fn node(&self, i: usize, j: usize, k: usize) -> [f32; 3] {
        let o = self.origin;
        let h = self.spacing;
        [o[0] + h * i as f32, o[1] + h * j as f32, o[2] + h * k as f32]
    }

    /// Slice `k`'s node positions, in slice order.
    pub fn slice_nodes(&self, k: usize) -> Vec<[f32; 3]> {
        let m = self.n + 1;
        (0..self.slice_len()).map(|s| self.node(s % m, s / m, k)).collect()
    }
}

/// A mesh vertex: where the surface crosses a lattice edge, and the outward unit normal there
/// (against the density gradient).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    /// Position.
    pub position: [f32; 3],
    /// Unit normal, pointing to lower density.
    pub normal: [f32; 3],
}

const NONE: u32 = u32::MAX;

/// Vertex ids on the x- and y-edges of one slice.
struct PlaneIds {
    x: Vec<u32>,
    y: Vec<u32>,
}

impl PlaneIds {
    fn new(n: usize) -> Self {
        PlaneIds { x: vec![NONE; n * (n + 1)], y: vec![NONE; (n + 1) * n] }
    }

    fn clear(&mut self) {
        self.x.fill(NONE);
        self.y.fill(NONE);
    }
}

/// What one layer produced: its new vertices (ids `first_id..`, in order) and its triangles.
#[derive(Debug, Default)]
pub struct LayerMesh {
    /// The id of `vertices[0]`.
    pub first_id: u32,
    /// New vertices.
    pub vertices: Vec<SurfacePoint>,
    /// Triangles (vertex ids, counter-clockwise seen from outside).
    pub faces: Vec<[u32; 3]>,
}

/// March the lattice: `slice(k)` gives slice `k`'s values (`(n + 1)²`, asked for once each,
/// in order), `emit(k, mesh)` takes layer `k`'s vertices and triangles as soon as they are
/// made. A node is inside when its value is above `threshold`. Fails (the message through
/// `fail`) when a slice has the wrong length or more than `u32::MAX − 1` vertices are made, or
/// when a callback fails.
pub fn march<E>(
    lattice: &Lattice,
    threshold: f32,
    mut slice: impl FnMut(usize) -> Result<Vec<f32>, E>,
    mut emit: impl FnMut(usize, LayerMesh) -> Result<(), E>,
    fail: impl Fn(String) -> E,
) -> Result<(), E> {
    let n = lattice.n;
    let m = n + 1;
    let mut window: VecDeque<(usize, Vec<f32>)> = VecDeque::new();
    let mut load = |k: usize, window: &mut VecDeque<(usize, Vec<f32>)>| -> Result<(), E> {
        let values = slice(k)?;
        if values.len() != m * m {
            return Err(fail(format!("slice {k} has {} values, the lattice needs {}", values.len(), m * m)));
        }
        window.push_back((k, values));
        Ok(())
    };
    let mut lower = PlaneIds::new(n);
    let mut upper = PlaneIds::new(n);
    let mut vertical = vec![NONE; m * m];
    let mut next_id: u32 = 0;
    for k in 0..n {
        while window.back().is_none_or(|(last, _)| *last < (k + 2).min(n)) {
            let next = window.back().map_or(0, |(last, _)| last + 1);
            load(next, &mut window)?;
        }
        while window.front().is_some_and(|(first, _)| *first + 1 < k) {
            window.pop_front();
        }
        let get = |kk: usize| window.iter().find(|(s, _)| *s == kk).map(|(_, v)| v.as_slice());
        let slabs = Slabs { below: k.checked_sub(1).and_then(get), lower: get(k).expect("slice k"), upper: get(k + 1).expect("slice k + 1"), above: get(k + 2) };
        let mut out = LayerMesh { first_id: next_id, ..LayerMesh::default() };
        for j in 0..n {
            for i in 0..n {
                let mut case = 0u8;
                for c in 0..8u8 {
                    let [dx, dy, dz] = corner_offset(c).map(usize::from);
                    if slabs.value(dz, (j + dy) * m + i + dx) > threshold {
                        case |= 1 << c;
                    }
                }
                for tri in triangles(case) {
                    let mut face = [0u32; 3];
                    for (slot, &e) in face.iter_mut().zip(tri) {
                        let (c0, _, axis) = EDGES[e as usize];
                        let [dx, dy, dz] = corner_offset(c0).map(usize::from);
                        let (ni, nj) = (i + dx, j + dy);
                        let plane = if dz == 0 { &mut lower } else { &mut upper };
                        let id = match axis {
                            0 => &mut plane.x[nj * n + ni],
                            1 => &mut plane.y[nj * m + ni],
                            _ => &mut vertical[nj * m + ni],
                        };
                        if *id == NONE {
                            if next_id == NONE {
                                return Err(fail(format!("more than {} vertices", NONE - 1)));
                            }
                            out.vertices.push(slabs.crossing(lattice, threshold, [ni, nj, dz], axis as usize, k));
                            *id = next_id;
                            next_id += 1;
                        }
                        *slot = *id;
                    }
                    out.faces.push(face);
                }
            }
        }
        emit(k, out)?;
        std::mem::swap(&mut lower, &mut upper);
        upper.clear();
        vertical.fill(NONE);
    }
    Ok(())
}

/// The slices around one layer: `lower` is slice `k`, `upper` slice `k + 1`.
struct Slabs<'a> {
    below: Option<&'a [f32]>,
    lower: &'a [f32],
    upper: &'a [f32],
    above: Option<&'a [f32]>,
}

impl Slabs<'_> {
    /// Node value at `index` of slice `k + dz` (`dz` 0 or 1).
    fn value(&self, dz: usize, index: usize) -> f32 {
        if dz == 0 { self.lower[index] } else { self.upper[index] }
    }

    fn at(&self, dz: isize) -> Option<&[f32]> {
        match dz {
            -1 => self.below,
            0 => Some(self.lower),
            1 => Some(self.upper),
            2 => self.above,
            _ => None,
        }
    }

    /// The density gradient at node `(i, j)` of slice `k + dz` (`dz` 0 or 1).
    fn gradient(&self, lattice: &Lattice, i: usize, j: usize, dz: usize) -> [f32; 3] {
        let (n, m, h) = (lattice.n, lattice.n + 1, lattice.spacing);
        let here = self.at(dz as isize).expect("own slice");
        let diff = |lo: Option<f32>, mid: f32, hi: Option<f32>| match (lo, hi) {
            (Some(a), Some(b)) => (b - a) / (2.0 * h),
            (None, Some(b)) => (b - mid) / h,
            (Some(a), None) => (mid - a) / h,
            (None, None) => 0.0,
        };
        let v = here[j * m + i];
        let gx = diff((i > 0).then(|| here[j * m + i - 1]), v, (i < n).then(|| here[j * m + i + 1]));
        let gy = diff((j > 0).then(|| here[(j - 1) * m + i]), v, (j < n).then(|| here[(j + 1) * m + i]));
        let gz = diff(self.at(dz as isize - 1).map(|s| s[j * m + i]), v, self.at(dz as isize + 1).map(|s| s[j * m + i]));
        [gx, gy, gz]
    }

    /// The surface point on the edge from node `(i, j)` of slice `k + dz` along `axis`.
    fn crossing(&self, lattice: &Lattice, threshold: f32, [i, j, dz]: [usize; 3], axis: usize, k: usize) -> SurfacePoint {
        let m = lattice.n + 1;
        let (i1, j1, dz1) = match axis {
            0 => (i + 1, j, dz),
            1 => (i, j + 1, dz),
            _ => (i, j, dz + 1),
        };
        let (v0, v1) = (self.value(dz, j * m + i), self.value(dz1, j1 * m + i1));
        let t = ((threshold - v0) / (v1 - v0)).clamp(0.0, 1.0);
        let mut position = lattice.node(i, j, k + dz);
        position[axis] += t * lattice.spacing;
        let (g0, g1) = (self.gradient(lattice, i, j, dz), self.gradient(lattice, i1, j1, dz1));
        let g: [f32; 3] = [0, 1, 2].map(|d| g0[d] + t * (g1[d] - g0[d]));
        let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        let normal = if len > 0.0 && len.is_finite() {
            g.map(|x| -x / len)
        } else {
            // No gradient to follow: out along the edge, from its inside end to its outside end.
            let mut out = [0.0; 3];
            out[axis] = if v0 > threshold { 1.0 } else { -1.0 };
            out
        };
        SurfacePoint { position, normal }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    /// March a whole lattice of `f` (values at node positions) into one mesh.
    fn mesh_of(lattice: &Lattice, threshold: f32, f: impl Fn([f32; 3]) -> f32) -> (Vec<SurfacePoint>, Vec<[u32; 3]>) {
        let (mut vertices, mut faces) = (Vec::new(), Vec::new());
        let mut asked = Vec::new();
        march::<String>(
            lattice,
            threshold,
            |k| {
                asked.push(k);
                Ok(lattice.slice_nodes(k).into_iter().map(&f).collect())
            },
            |_, layer| {
                assert_eq!(layer.first_id as usize, vertices.len(), "ids follow the order of emission");
                vertices.extend(layer.vertices);
                faces.extend(layer.faces);
                Ok(())
            },
            |e| e,
        )
        .unwrap();
        assert_eq!(asked, (0..=lattice.n).collect::<Vec<_>>(), "each slice once, in order");
        (vertices, faces)
    }

    /// Every directed edge appears once and its reverse once: closed and consistently oriented.
    fn assert_closed_and_oriented(faces: &[[u32; 3]]) {
        let mut directed: HashMap<(u32, u32), usize> = HashMap::new();
        for f in faces {
            assert!(f[0] != f[1] && f[1] != f[2] && f[0] != f[2], "degenerate face {f:?}");
            for s in 0..3 {
                *directed.entry((f[s], f[(s + 1) % 3])).or_default() += 1;
            }
        }
        for (&(a, b), &count) in &directed {
            assert_eq!(count, 1, "edge {a}→{b} used {count} times");
            assert_eq!(directed.get(&(b, a)), Some(&1), "edge {a}→{b} has no twin");
        }
    }

    fn sphere(c: [f32; 3], r: f32) -> impl Fn([f32; 3]) -> f32 {
        move |p| r - ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt()
    }

    #[test]
    fn a_sphere_is_closed_outward_and_on_its_surface() {
        let lattice = Lattice::cube(24, 1.0);
        let (c, r) = ([0.1, -0.05, 0.02], 0.7);
        let (vertices, faces) = mesh_of(&lattice, 0.0, sphere(c, r));
        assert!(faces.len() > 1000, "{} faces", faces.len());
        assert_closed_and_oriented(&faces);
        let h = lattice.spacing;
        let mut volume = 0.0f64;
        for f in &faces {
            let [a, b, cc] = f.map(|v| vertices[v as usize].position.map(f64::from));
            // Signed tetrahedron volume with the origin: positive sum ⇔ normals point out.
            volume += (a[0] * (b[1] * cc[2] - b[2] * cc[1]) - a[1] * (b[0] * cc[2] - b[2] * cc[0]) + a[2] * (b[0] * cc[1] - b[1] * cc[0])) / 6.0;
        }
        let exact = 4.0 / 3.0 * std::f64::consts::PI * (r as f64).powi(3);
        assert!((volume - exact).abs() < 0.02 * exact, "volume {volume} vs {exact}");
        for v in &vertices {
            let d = [0, 1, 2].map(|k| v.position[k] - c[k]);
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            // Linear interpolation of a distance function along an edge is exact up to the
            // curvature: well within a tenth of a cell.
            assert!((len - r).abs() < 0.1 * h, "vertex {:?} at distance {len}", v.position);
            let radial = d.map(|x| x / len);
            let cos = (0..3).map(|k| radial[k] * v.normal[k]).sum::<f32>();
            assert!(cos > 0.99, "normal {:?} at {:?}", v.normal, v.position);
        }
    }

    #[test]
    fn random_values_still_make_a_closed_surface() {
        // Values at random (seeded) in a lattice whose border is outside: every ambiguous face
        // and every case appears, and the surface must still close with one orientation, no
        // edge shared by more than two triangles.
        let lattice = Lattice::cube(12, 1.0);
        let m = lattice.n + 1;
        for seed in 0..4 {
            let mut rng = crate::rng::Rng::new(seed);
            let values: Vec<f32> = (0..m * m * m).map(|_| rng.uniform()).collect();
            let (mut vertices, mut faces) = (Vec::new(), Vec::new());
            march::<String>(
                &lattice,
                0.5,
                |k| {
                    Ok((0..m * m)
                        .map(|s| {
                            let (i, j) = (s % m, s / m);
                            let border = i == 0 || j == 0 || k == 0 || i == lattice.n || j == lattice.n || k == lattice.n;
                            if border { 0.0 } else { values[(k * m + j) * m + i] }
                        })
                        .collect())
                },
                |_, layer| {
                    vertices.extend(layer.vertices);
                    faces.extend(layer.faces);
                    Ok(())
                },
                |e| e,
            )
            .unwrap();
            assert!(faces.len() > 500);
            assert_closed_and_oriented(&faces);
            assert!(faces.iter().flatten().all(|&v| (v as usize) < vertices.len()));
        }
    }

    #[test]
    fn one_edge_crossing_is_interpolated_by_hand() {
        // 1 cell; only node (0, 0, 0) inside with value 3, the others 1, threshold 2: the
        // surface crosses each of its three edges halfway: (−1, −1, −1) + 0.5·2 along each axis.
        let lattice = Lattice::cube(1, 1.0);
        let (vertices, faces) = mesh_of(&lattice, 2.0, |p| if p == [-1.0, -1.0, -1.0] { 3.0 } else { 1.0 });
        assert_eq!(faces.len(), 1);
        let mut positions: Vec<[f32; 3]> = vertices.iter().map(|v| v.position).collect();
        positions.sort_by(|a, b| a.partial_cmp(b).unwrap());
        assert_eq!(positions, vec![[-1.0, -1.0, 0.0], [-1.0, 0.0, -1.0], [0.0, -1.0, -1.0]]);
        // One-sided differences (spacing 2): the gradient is (−1, −1, −1) at the inside node
        // and, at its neighbour along x, −1 along x and 0 across; halfway (−1, −0.5, −0.5).
        // The normal is its opposite, normalised: (1, 0.5, 0.5)/√1.5 along each edge's axis.
        for v in &vertices {
            let axis = (0..3).find(|&d| v.position[d] == 0.0).unwrap();
            for d in 0..3 {
                let want = if d == axis { 1.0 } else { 0.5 } / 1.5f32.sqrt();
                assert!((v.normal[d] - want).abs() < 1e-6, "{v:?}");
            }
        }
    }

    #[test]
    fn short_slices_are_an_error() {
        let lattice = Lattice::cube(2, 1.0);
        let err = march::<String>(&lattice, 0.0, |_| Ok(vec![0.0; 3]), |_, _| Ok(()), |e| e).unwrap_err();
        assert_eq!(err, "slice 0 has 3 values, the lattice needs 9");
    }
}
