//! The marching-cubes case table, built once from a rule instead of typed in.
//!
//! A cube's corner `c` (0–7) sits at `(c & 1, c >> 1 & 1, c >> 2 & 1)`; its case is the byte
//! whose bit `c` says corner `c` is inside (density above the threshold). For each case the
//! surface crosses exactly the edges whose corners differ. On each face of the cube the
//! crossing edges are joined in pairs by segments: two crossings make one segment; four (the
//! ambiguous face: inside corners on one diagonal) make two, each cutting off one inside corner
//! (the inside corners stay apart). The rule reads only the face's own four corners, which the
//! neighbouring cube shares, so both cubes cut the shared face alike and the surface has no
//! cracks. Segments are directed so that, seen from outside the cube, the inside lies on their
//! left; the segments then chain into closed loops (the boundary of the inside part of the
//! cube's surface), each loop is reversed (so that it turns counter-clockwise seen from the
//! outside of the surface) and cut into triangles whose diagonals never lie in a face of the
//! cube ([`triangulate`]).
//!
//! The tests check every case (each crossing edge is used by one loop, nothing else is) and the
//! surfaces built from the table (closed, every edge shared by two triangles in opposite
//! directions, normals pointing out), on a sphere and on random values.

use std::sync::OnceLock;

/// The cube's 12 edges as (lower corner, upper corner, axis): axis `a`'s four edges in the
/// order of their lower corners.
pub const EDGES: [(u8, u8, u8); 12] = edges();

const fn edges() -> [(u8, u8, u8); 12] {
    let mut out = [(0u8, 0u8, 0u8); 12];
    let mut n = 0;
    let mut axis = 0u8;
    while axis < 3 {
        let mut c = 0u8;
        while c < 8 {
            if c & (1 << axis) == 0 {
                out[n] = (c, c | (1 << axis), axis);
                n += 1;
            }
            c += 1;
        }
        axis += 1;
    }
    out
}

/// Corner `c`'s offset in the cube.
pub fn corner_offset(c: u8) -> [u8; 3] {
    [c & 1, (c >> 1) & 1, (c >> 2) & 1]
}

/// The triangles of every case, as edge indices into [`EDGES`], counter-clockwise seen from
/// outside the surface (from where the density is below the threshold).
pub fn triangles(case: u8) -> &'static [[u8; 3]] {
    static TABLE: OnceLock<Vec<Vec<[u8; 3]>>> = OnceLock::new();
    &TABLE.get_or_init(|| (0..=255u8).map(case_triangles).collect())[case as usize]
}

/// The closed loops of crossing edges of `case`, each counter-clockwise seen from outside the
/// surface.
pub fn loops(case: u8) -> Vec<Vec<u8>> {
    let inside = |c: u8| case & (1 << c) != 0;
    let crossing = |e: usize| inside(EDGES[e].0) != inside(EDGES[e].1);
    let mut next = [None::<u8>; 12];
    for axis in 0..3u8 {
        for side in 0..2u8 {
            for (from, to) in face_segments(case, axis, side) {
                debug_assert!(next[from as usize].is_none(), "edge {from} leaves twice in case {case}");
                next[from as usize] = Some(to);
            }
        }
    }
    let mut seen = [false; 12];
    let mut loops = Vec::new();
    for start in (0..12).filter(|&e| crossing(e)) {
        if seen[start] {
            continue;
        }
        let mut cycle = Vec::new();
        let mut e = start;
        while !seen[e] {
            seen[e] = true;
            cycle.push(e as u8);
            e = next[e].expect("every crossing edge has a next edge") as usize;
        }
        debug_assert_eq!(e, start, "a loop of case {case} closes where it started");
        cycle.reverse();
        loops.push(cycle);
    }
    loops
}

fn case_triangles(case: u8) -> Vec<[u8; 3]> {
    loops(case).iter().flat_map(|l| triangulate(l).unwrap_or_else(|| panic!("case {case}: loop {l:?} has no triangulation"))).collect()
}

/// Whether edges `a` and `b` lie on one face of the cube.
fn share_face(a: u8, b: u8) -> bool {
    let (ea, eb) = (EDGES[a as usize], EDGES[b as usize]);
    (0..3).any(|axis| (0..2).any(|side| [ea.0, ea.1, eb.0, eb.1].iter().all(|c| (c >> axis) & 1 == side)))
}

/// Triangles covering the loop `p` (in its order, so they keep its orientation) whose
/// diagonals never join two edges of one face: such a diagonal would lie in the face, where
/// the neighbouring cube may draw the same one, and four triangles would meet at it (the
/// surface pinched where it should pass through the face). `None` if there is no such
/// triangulation.
fn triangulate(p: &[u8]) -> Option<Vec<[u8; 3]>> {
    let n = p.len();
    if n == 3 {
        return Some(vec![[p[0], p[1], p[2]]]);
    }
    // The side p[0]–p[n−1] belongs to one triangle (p[0], p[k], p[n−1]).
    (1..n - 1).find_map(|k| {
        let diagonal_ok = |i: usize, j: usize| j - i == 1 || !share_face(p[i], p[j]);
        if !(diagonal_ok(0, k) && diagonal_ok(k, n - 1)) {
            return None;
        }
        let mut out = vec![[p[0], p[k], p[n - 1]]];
        if k > 1 {
            out.extend(triangulate(&p[..=k])?);
        }
        if k < n - 2 {
            out.extend(triangulate(&p[k..])?);
        }
        Some(out)
    })
}

/// The directed segments on the face `axis = side` of the cube: (from edge, to edge), inside
/// on the left seen from outside the cube.
fn face_segments(case: u8, axis: u8, side: u8) -> Vec<(u8, u8)> {
    let inside = |c: u8| case & (1 << c) != 0;
    let on_face = |c: u8| (c >> axis) & 1 == side;
    let face_edges: Vec<u8> = (0..12u8).filter(|&e| on_face(EDGES[e as usize].0) && on_face(EDGES[e as usize].1)).collect();
    let crossing: Vec<u8> = face_edges.iter().copied().filter(|&e| inside(EDGES[e as usize].0) != inside(EDGES[e as usize].1)).collect();
    let point = |c: u8| corner_offset(c).map(f32::from);
    let midpoint = |e: u8| {
        let (a, b, _) = EDGES[e as usize];
        let (pa, pb) = (point(a), point(b));
        [0, 1, 2].map(|k| 0.5 * (pa[k] + pb[k]))
    };
    // (edge, edge, a point on the inside of the segment)
    let pairs: Vec<(u8, u8, [f32; 3])> = match crossing.len() {
        0 => Vec::new(),
        2 => {
            let corners: Vec<[f32; 3]> = (0..8u8).filter(|&c| on_face(c) && inside(c)).map(point).collect();
            let n = corners.len() as f32;
            let centroid = [0, 1, 2].map(|k| corners.iter().map(|p| p[k]).sum::<f32>() / n);
            vec![(crossing[0], crossing[1], centroid)]
        }
        4 => (0..8u8)
            .filter(|&c| on_face(c) && inside(c))
            .map(|c| {
                let touching: Vec<u8> = face_edges.iter().copied().filter(|&e| EDGES[e as usize].0 == c || EDGES[e as usize].1 == c).collect();
                (touching[0], touching[1], point(c))
            })
            .collect(),
        n => unreachable!("a face has 0, 2 or 4 crossing edges, not {n}"),
    };
    let mut normal = [0.0f32; 3];
    normal[axis as usize] = if side == 1 { 1.0 } else { -1.0 };
    pairs
        .into_iter()
        .map(|(a, b, inner)| {
            let (pa, pb) = (midpoint(a), midpoint(b));
            let u = [0, 1, 2].map(|k| pb[k] - pa[k]);
            let v = [0, 1, 2].map(|k| inner[k] - pa[k]);
            let cross = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
            let left = cross.iter().zip(&normal).map(|(c, n)| c * n).sum::<f32>() > 0.0;
            if left { (a, b) } else { (b, a) }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn crossing_edges(case: u8) -> Vec<u8> {
        let inside = |c: u8| case & (1 << c) != 0;
        (0..12u8).filter(|&e| inside(EDGES[e as usize].0) != inside(EDGES[e as usize].1)).collect()
    }

    #[test]
    fn edges_join_corners_one_axis_apart() {
        assert_eq!(EDGES[0], (0, 1, 0));
        assert_eq!(EDGES[4], (0, 2, 1));
        assert_eq!(EDGES[11], (3, 7, 2));
        for (a, b, axis) in EDGES {
            assert_eq!(a ^ b, 1 << axis);
        }
    }

    #[test]
    fn every_case_uses_each_crossing_edge_once() {
        for case in 0..=255u8 {
            let loops = loops(case);
            let mut used: Vec<u8> = loops.iter().flatten().copied().collect();
            used.sort();
            assert_eq!(used, crossing_edges(case), "case {case:#010b}");
            assert!(loops.iter().all(|l| l.len() >= 3), "case {case:#010b}: {loops:?}");
            let triangles = triangles(case).len();
            assert_eq!(triangles, loops.iter().map(|l| l.len() - 2).sum::<usize>());
            assert!(triangles <= 12);
        }
        assert!(triangles(0).is_empty() && triangles(255).is_empty());
    }

    #[test]
    fn one_inside_corner_is_one_outward_triangle() {
        // Corner 0 inside: edges 0 (x), 4 (y) and 8 (z) cross, at their midpoints
        // (0.5, 0, 0), (0, 0.5, 0), (0, 0, 0.5). Counter-clockwise seen from outside the
        // surface: the normal (b − a) × (c − a) points away from corner 0, along (1, 1, 1).
        let t = triangles(1);
        assert_eq!(t.len(), 1);
        let mid = |e: u8| {
            let (a, b, _) = EDGES[e as usize];
            let (pa, pb) = (corner_offset(a), corner_offset(b));
            [0, 1, 2].map(|k| 0.5 * (pa[k] + pb[k]) as f32)
        };
        let [a, b, c] = t[0].map(mid);
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        assert_eq!(n, [0.25, 0.25, 0.25]);
        // The complement (everything but corner 0 inside) is the same triangle facing corner 0.
        let t = triangles(254);
        assert_eq!(t.len(), 1);
        let mut flipped = t[0];
        flipped.swap(1, 2);
        let rot = |x: [u8; 3]| (0..3).map(|s| [x[s], x[(s + 1) % 3], x[(s + 2) % 3]]).collect::<Vec<_>>();
        assert!(rot(triangles(1)[0]).contains(&flipped), "{:?} vs {:?}", triangles(1), t);
    }

    #[test]
    fn an_ambiguous_face_keeps_inside_corners_apart() {
        // Corners 0 and 3 (a diagonal of the face z = 0) inside: two separate corners, two
        // triangles, not a band joining them.
        let l = loops(0b0000_1001);
        assert_eq!(l.len(), 2, "{l:?}");
        assert!(l.iter().all(|l| l.len() == 3));
        // The opposite diagonal outside (corners 1 and 2 inside with 0, 3 out) mirrors it.
        assert_eq!(loops(0b0000_0110).len(), 2);
    }
}
