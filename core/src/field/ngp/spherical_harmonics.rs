//! Real spherical harmonics of degree 4 (bands 0–3, 16 values) of a unit direction, the view
//! encoding of instant-ngp's colour network, with tiny-cuda-nn's signs, order and constants.
//!
//! tiny-cuda-nn's `SphericalHarmonics` encoding takes directions mapped to [0, 1]³ and undoes
//! it (`x = 2·in − 1`); here the direction is taken as it is, which is the same function.
//! Band by band (x, y, z the direction's components; constants are √((2l+1)/4π)-style norms):
//!
//! ```text
//! 0:  1/(2√π)
//! 1:  −√3·y/(2√π),  √3·z/(2√π),  −√3·x/(2√π)
//! 2:  √15·xy/(2√π),  −√15·yz/(2√π),  √5·(3z² − 1)/(4√π),  −√15·xz/(2√π),  √15·(x² − y²)/(4√π)
//! 3:  √70·y(y² − 3x²)/(8√π),  √105·xyz/(2√π),  √42·y(1 − 5z²)/(8√π),  √7·z(5z² − 3)/(4√π),
//!     √42·x(1 − 5z²)/(8√π),  √105·z(x² − y²)/(4√π),  √70·x(3y² − x²)/(8√π)
//! ```
//!
//! The exported graph (nerf-export's lowering) evaluates the same expressions in the same order
//! of operations.

/// Number of values: 16.
pub const SH4_DIM: usize = 16;

/// The coefficients in the order they are used, closed forms in the module doc.
pub const SH4_CONSTANTS: [f32; 11] = [
    0.282_094_8,  // 1/(2√π)
    0.488_602_5,  // √3/(2√π)
    1.092_548_4,  // √15/(2√π)
    0.946_174_7,  // 3√5/(4√π)
    0.315_391_57, // √5/(4√π)
    0.546_274_2,  // √15/(4√π)
    0.590_043_6,  // √70/(8√π)
    2.890_611_4,  // √105/(2√π)
    0.457_045_8,  // √42/(8√π)
    0.373_176_3,  // √7/(4√π)
    1.445_305_7,  // √105/(4√π)
];

/// The 16 harmonics of unit direction `d`.
#[inline]
pub fn sh4(d: [f32; 3]) -> [f32; SH4_DIM] {
    let [x, y, z] = d;
    let c = &SH4_CONSTANTS;
    let (xy, yz, xz) = (x * y, y * z, x * z);
    let (x2, y2, z2) = (x * x, y * y, z * z);
    [
        c[0],
        -c[1] * y,
        c[1] * z,
        -c[1] * x,
        c[2] * xy,
        -c[2] * yz,
        c[3] * z2 - c[4],
        -c[2] * xz,
        c[5] * x2 - c[5] * y2,
        c[6] * y * (-3.0 * x2 + y2),
        c[7] * xy * z,
        c[8] * y * (1.0 - 5.0 * z2),
        c[9] * z * (5.0 * z2 - 3.0),
        c[8] * x * (1.0 - 5.0 * z2),
        c[10] * z * (x2 - y2),
        c[6] * x * (-x2 + 3.0 * y2),
    ]
}

/// The gradient with respect to `d` of `Σ_k g[k]·sh4(d)[k]` (the polynomials differentiated
/// as they are written, `d` a free 3-vector: normalising is the caller's).
pub fn sh4_backward(d: [f32; 3], g: &[f32; SH4_DIM]) -> [f32; 3] {
    let [x, y, z] = d;
    let c = &SH4_CONSTANTS;
    let (x2, y2, z2) = (x * x, y * y, z * z);
    // ∂sh_k/∂(x, y, z), k = 1..15 (sh_0 is constant).
    let partials: [[f32; 3]; 15] = [
        [0.0, -c[1], 0.0],
        [0.0, 0.0, c[1]],
        [-c[1], 0.0, 0.0],
        [c[2] * y, c[2] * x, 0.0],
        [0.0, -c[2] * z, -c[2] * y],
        [0.0, 0.0, 2.0 * c[3] * z],
        [-c[2] * z, 0.0, -c[2] * x],
        [2.0 * c[5] * x, -2.0 * c[5] * y, 0.0],
        [-6.0 * c[6] * x * y, 3.0 * c[6] * (y2 - x2), 0.0],
        [c[7] * y * z, c[7] * x * z, c[7] * x * y],
        [0.0, c[8] * (1.0 - 5.0 * z2), -10.0 * c[8] * y * z],
        [0.0, 0.0, c[9] * (15.0 * z2 - 3.0)],
        [c[8] * (1.0 - 5.0 * z2), 0.0, -10.0 * c[8] * x * z],
        [2.0 * c[10] * x * z, -2.0 * c[10] * y * z, c[10] * (x2 - y2)],
        [3.0 * c[6] * (y2 - x2), 6.0 * c[6] * x * y, 0.0],
    ];
    let mut out = [0.0f32; 3];
    for (p, &g) in partials.iter().zip(&g[1..]) {
        for a in 0..3 {
            out[a] += g * p[a];
        }
    }
    out
}

/// [`sh4`] of many directions.
///
/// # Shapes
/// `dirs`: `[n, 3]` unit vectors → `[n, 16]` row-major.
pub fn sh4_all(dirs: &[[f32; 3]]) -> Vec<f32> {
    dirs.iter().flat_map(|&d| sh4(d)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn the_backward_pass_matches_finite_differences() {
        let mut rng = crate::Rng::new(9);
        for _ in 0..50 {
            let d = [0; 3].map(|_: i32| rng.uniform() * 2.0 - 1.0);
            let g: [f32; SH4_DIM] = [0; SH4_DIM].map(|_| rng.uniform() * 2.0 - 1.0);
            let loss = |d: [f32; 3]| sh4(d).iter().zip(&g).map(|(s, g)| *s as f64 * *g as f64).sum::<f64>();
            let got = sh4_backward(d, &g);
            for a in 0..3 {
                let eps = 1e-3f32;
                let (mut hi, mut lo) = (d, d);
                hi[a] += eps;
                lo[a] -= eps;
                let numeric = (loss(hi) - loss(lo)) / (hi[a] - lo[a]) as f64;
                assert!((got[a] as f64 - numeric).abs() < 1e-3 * (1.0 + numeric.abs()), "{d:?} axis {a}: {} vs {numeric}", got[a]);
            }
        }
    }

    #[test]
    fn constants_are_their_closed_forms() {
        let s = |v: f64| v.sqrt();
        let want = [
            1.0 / (2.0 * s(PI)),
            s(3.0) / (2.0 * s(PI)),
            s(15.0) / (2.0 * s(PI)),
            3.0 * s(5.0) / (4.0 * s(PI)),
            s(5.0) / (4.0 * s(PI)),
            s(15.0) / (4.0 * s(PI)),
            s(70.0) / (8.0 * s(PI)),
            s(105.0) / (2.0 * s(PI)),
            s(42.0) / (8.0 * s(PI)),
            s(7.0) / (4.0 * s(PI)),
            s(105.0) / (4.0 * s(PI)),
        ];
        for (i, (&c, w)) in SH4_CONSTANTS.iter().zip(want).enumerate() {
            assert!((c as f64 - w).abs() < 1e-7, "constant {i}: {c} vs {w}");
        }
    }

    #[test]
    fn axis_directions_by_hand() {
        // +z: band 0 = 0.2820948, z-terms only: √3/(2√π) = 0.4886025 at index 2,
        // (3√5 − √5)/(4√π) = √5/(2√π) = 0.6307831 at 6, √7·2/(4√π) = 0.7463527 at 12.
        let z = sh4([0.0, 0.0, 1.0]);
        let mut want = [0.0f32; 16];
        want[0] = 0.282_094_8;
        want[2] = 0.488_602_5;
        want[6] = 0.630_783_1;
        want[12] = 0.746_352_7;
        for i in 0..16 {
            assert!((z[i] - want[i]).abs() < 1e-6, "+z, {i}: {} vs {}", z[i], want[i]);
        }
        // +x: −√3/(2√π) at 3, −√5/(4√π) at 6, √15/(4√π) = 0.5462742 at 8, √42/(8√π) = 0.4570458
        // at 13, −√70/(8√π) = −0.5900436 at 15.
        let x = sh4([1.0, 0.0, 0.0]);
        let mut want = [0.0f32; 16];
        want[0] = 0.282_094_8;
        want[3] = -0.488_602_5;
        want[6] = -0.315_391_57;
        want[8] = 0.546_274_2;
        want[13] = 0.457_045_8;
        want[15] = -0.590_043_6;
        for i in 0..16 {
            assert!((x[i] - want[i]).abs() < 1e-6, "+x, {i}: {} vs {}", x[i], want[i]);
        }
    }

    #[test]
    fn harmonics_are_orthonormal_on_the_sphere() {
        // Fibonacci sphere quadrature: (4π/n) Σ Yᵢ Yⱼ ≈ δᵢⱼ.
        let n = 20_000;
        let golden = PI * (3.0 - 5f64.sqrt());
        let dirs: Vec<[f32; 3]> = (0..n)
            .map(|k| {
                let z = 1.0 - (2.0 * k as f64 + 1.0) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let phi = golden * k as f64;
                [(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32]
            })
            .collect();
        let y = sh4_all(&dirs);
        for i in 0..16 {
            for j in 0..16 {
                let dot: f64 = y.chunks_exact(16).map(|r| r[i] as f64 * r[j] as f64).sum::<f64>() * 4.0 * PI / n as f64;
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((dot - want).abs() < 2e-3, "⟨Y{i}, Y{j}⟩ = {dot}");
            }
        }
    }
}
