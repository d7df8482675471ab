//! Scene contraction for unbounded captures (mip-NeRF 360's, with the L∞ norm as nerfacto's
//! `SceneContraction(order=inf)`): the cube ‖x‖∞ ≤ 1 stays as it is, everything beyond it is
//! drawn into the shell 1 < ‖c‖∞ < 2, so the hash grid and the occupancy grid cover the whole
//! world with a cube of half-size 2, finest where the object is.
//!
//! Every renderer computes it with the same float32 operations, in this order, so that a point
//! lands in the same occupancy cell everywhere:
//! `n = max(|x|, |y|, |z|)`, `m = max(n, 1)`, `r = 1/m`, `f = (2 − r)·r`, `c = x·f` per axis.
//! Inside the cube m = 1 and f = 1 exactly, so c = x bit for bit. Past ‖x‖∞ ≈ 10⁷ the result
//! rounds onto the face ‖c‖∞ = 2.

use serde::{Deserialize, Serialize};

/// How world points map into the field's box before its grid reads them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Contraction {
    /// mip-NeRF 360's contraction with the L∞ norm: `x` where ‖x‖∞ ≤ 1, else
    /// `(2 − 1/‖x‖∞) · x/‖x‖∞` (the contracted world lies in [−2, 2]³).
    Linf,
}

/// Half the side of the cube a contracted world fills.
pub const CONTRACTED_HALF_SIZE: f32 = 2.0;

impl Contraction {
    /// `p` contracted (the float32 operations of the module's documentation).
    #[inline]
    pub fn apply(self, p: [f32; 3]) -> [f32; 3] {
        match self {
            Contraction::Linf => {
                let n = p[0].abs().max(p[1].abs()).max(p[2].abs());
                // `f32::max` returns the other operand for NaN: a NaN point stays NaN below.
                let m = if n > 1.0 { n } else { 1.0 };
                let r = 1.0 / m;
                let f = (2.0 - r) * r;
                p.map(|v| v * f)
            }
        }
    }

    /// The gradient with respect to `p` of a loss whose gradient with respect to `apply(p)` is
    /// `g` (the contraction's Jacobian, transposed, times `g`). Inside the cube it is `g`; in
    /// the shell, with m = ‖p‖∞ reached on axis j: `c = (2/m − 1/m²)·p`, so
    /// `∂L/∂p = (2/m − 1/m²)·g + e_j·sign(p_j)·(2/m³ − 2/m²)·(g·p)`.
    pub fn backward(self, p: [f32; 3], g: [f32; 3]) -> [f32; 3] {
        match self {
            Contraction::Linf => {
                let a = p.map(f32::abs);
                let j = if a[0] >= a[1] && a[0] >= a[2] { 0 } else if a[1] >= a[2] { 1 } else { 2 };
                let m = a[j];
                if !(m > 1.0) {
                    return g;
                }
                let f = (2.0 - 1.0 / m) / m;
                let slope = (2.0 / m - 2.0) / (m * m) * (g[0] * p[0] + g[1] * p[1] + g[2] * p[2]);
                let mut out = g.map(|v| v * f);
                out[j] += p[j].signum() * slope;
                out
            }
        }
    }

    /// The world point whose contraction is `c` (‖c‖∞ < 2), for the occupancy grid's updates:
    /// its cells are boxes in contracted space, the field is asked about world points.
    pub fn invert(self, c: [f32; 3]) -> [f32; 3] {
        match self {
            Contraction::Linf => {
                let n = c[0].abs().max(c[1].abs()).max(c[2].abs());
                if n <= 1.0 {
                    return c;
                }
                // ‖c‖∞ = 2 − 1/‖x‖∞ → ‖x‖∞ = 1/(2 − ‖c‖∞); x = c · ‖x‖∞/‖c‖∞. Kept finite at
                // the shell's outer face.
                let world = 1.0 / (2.0 - n).max(1e-6);
                c.map(|v| v * (world / n))
            }
        }
    }

    /// What scene.json says of it, for other implementations.
    pub fn describe(self) -> &'static str {
        match self {
            Contraction::Linf => {
                "mip-NeRF 360 with the L-infinity norm, float32 in this order: n = max(|x|,|y|,|z|), m = max(n, 1), \
                 r = 1/m, f = (2 - r)*r, c = x*f; the field and the occupancy grid see c (in [-2, 2]^3)"
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backward_matches_finite_differences() {
        let c = Contraction::Linf;
        let mut rng = crate::Rng::new(4);
        let mut shell = 0;
        for k in 0..400 {
            // Inside the cube, in the shell and far out; every axis the largest in turn.
            let scale = [0.9f32, 3.0, 40.0][k % 3];
            let p = [0; 3].map(|_: i32| (rng.uniform() * 2.0 - 1.0) * scale);
            let g = [0; 3].map(|_: i32| rng.uniform() * 2.0 - 1.0);
            let loss = |q: [f64; 3]| {
                let n = q[0].abs().max(q[1].abs()).max(q[2].abs());
                let f = if n > 1.0 { (2.0 - 1.0 / n) / n } else { 1.0 };
                (0..3).map(|d| q[d] * f * g[d] as f64).sum::<f64>()
            };
            let got = c.backward(p, g);
            for d in 0..3 {
                let eps = 1e-4 * (1.0 + p[d].abs() as f64);
                let mut hi = p.map(|v| v as f64);
                let mut lo = hi;
                hi[d] += eps;
                lo[d] -= eps;
                let numeric = (loss(hi) - loss(lo)) / (2.0 * eps);
                assert!((got[d] as f64 - numeric).abs() < 1e-4 * (1.0 + numeric.abs()), "p {p:?} axis {d}: {} vs {numeric}", got[d]);
            }
            shell += (p.iter().fold(0.0f32, |m, v| m.max(v.abs())) > 1.0) as usize;
        }
        assert!(shell > 200, "{shell} points in the shell");
        assert_eq!(c.backward([0.5, -0.2, 0.1], [1.0, 2.0, 3.0]), [1.0, 2.0, 3.0], "identity inside");
    }

    #[test]
    fn contraction_matches_hand_computed_values() {
        let c = Contraction::Linf;
        // Inside the unit cube: unchanged, bit for bit.
        assert_eq!(c.apply([0.3, -1.0, 0.999]), [0.3, -1.0, 0.999]);
        // ‖x‖∞ = 2: f = (2 − 0.5)·0.5 = 0.75 → (1.5, −0.75, 0.375).
        assert_eq!(c.apply([2.0, -1.0, 0.5]), [1.5, -0.75, 0.375]);
        // ‖x‖∞ = 4: f = (2 − 0.25)·0.25 = 0.4375; the largest coordinate → 2 − 1/4.
        assert_eq!(c.apply([0.0, 0.0, -4.0]), [0.0, 0.0, -1.75]);
        // Far away: towards the face at 2; past ≈ 10⁷ it rounds onto the face (outside the
        // occupancy grid's cells: empty), never past it.
        let far = c.apply([1e3, 5e2, 0.0]);
        assert!(far[0] < 2.0 && far[0] > 1.998 && (far[1] - 0.5 * far[0]).abs() < 1e-6, "{far:?}");
        assert_eq!(c.apply([1e30, -1e30, 0.0]), [2.0, -2.0, 0.0]);
        assert!(c.apply([f32::NAN, 0.0, 0.0])[0].is_nan());
    }

    #[test]
    fn inverse_undoes_the_contraction() {
        let c = Contraction::Linf;
        for p in [[0.2, 0.4, -0.6], [3.0, -1.5, 0.25], [-20.0, 7.0, 19.0], [0.5, 100.0, -2.0]] {
            let back = c.invert(c.apply(p));
            for a in 0..3 {
                assert!((back[a] - p[a]).abs() <= 1e-4 * p[a].abs().max(1.0), "{p:?} → {back:?}");
            }
        }
        assert!(c.invert([2.0, 0.0, 0.0])[0].is_finite());
    }
}
