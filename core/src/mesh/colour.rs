//! Vertex colours: what a camera looking straight at the surface sees.
//!
//! A vertex sits where σ crosses the threshold, the faint outer edge of the field's surface,
//! where its colour is barely trained (the renders hardly weigh it). So each vertex is sampled
//! along its inward normal, from one lattice cell outside to three inside, and the samples'
//! colours are composited as a ray along that line would composite them, normalised by the
//! opacity they gather: the surface's own colour, with no background.

use crate::render::compositing::{RayAccumulator, alpha_from_density};

/// Samples per vertex, a quarter cell apart.
pub const SAMPLES: usize = 16;
/// Distance between samples, in lattice cells.
const STEP_CELLS: f32 = 0.25;
/// Where the samples start, in cells outside the vertex: the vertex is sample [`AT_VERTEX`].
const OUTSIDE_CELLS: f32 = 1.0;
/// The sample at the vertex itself.
const AT_VERTEX: usize = 4;
/// Below this gathered opacity the samples say nothing: the colour at the vertex is taken.
const MIN_OPACITY: f32 = 1e-4;

/// The points sampled for a vertex at `position` with outward unit `normal` on a lattice of
/// `spacing`: `position + normal·(1 − k/4)·spacing` for k = 0 … 15.
///
/// Example: position (0, 0, 0), normal +z, spacing 0.4 → z = 0.4, 0.3, 0.2, 0.1, 0, −0.1 … −1.1.
pub fn sample_points(position: [f32; 3], normal: [f32; 3], spacing: f32) -> impl Iterator<Item = [f32; 3]> {
    (0..SAMPLES).map(move |k| {
        let s = (OUTSIDE_CELLS - STEP_CELLS * k as f32) * spacing;
        [0, 1, 2].map(|c| position[c] + s * normal[c])
    })
}

/// The colour seen along one vertex's samples (`sigma`, `rgb`: [`SAMPLES`] each, from outside
/// in) on a lattice of `spacing`: Σ wₖ·rgbₖ / Σ wₖ with the compositing weights wₖ, or the
/// colour at the vertex when the samples gather less than [`MIN_OPACITY`].
///
/// Example: σ·δ = ln 2 at every sample (α = ½): weights ½, ¼, ⅛ … over the first three, so a
/// red first sample and green ones after give ≈ half red, half green.
pub fn seen_colour(sigma: &[f32], rgb: &[[f32; 3]], spacing: f32) -> [f32; 3] {
    assert!(sigma.len() == SAMPLES && rgb.len() == SAMPLES, "seen_colour: {SAMPLES} samples per vertex");
    let delta = STEP_CELLS * spacing;
    let mut ray = RayAccumulator::default();
    for (k, (&s, &c)) in sigma.iter().zip(rgb).enumerate() {
        ray.add(alpha_from_density(s, delta), c, k as f32);
    }
    let out = ray.finish(false);
    if out.acc < MIN_OPACITY {
        return rgb[AT_VERTEX];
    }
    out.rgb.map(|c| c / out.acc)
}

#[cfg(test)]
mod tests {
    use super::*;

    const RED: [f32; 3] = [1.0, 0.0, 0.0];
    const GREEN: [f32; 3] = [0.0, 1.0, 0.0];

    #[test]
    fn samples_run_from_a_cell_outside_to_three_inside() {
        let z: Vec<f32> = sample_points([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.4).map(|p| p[2]).collect();
        assert_eq!(z.len(), SAMPLES);
        assert!((z[0] - 0.4).abs() < 1e-6 && z[AT_VERTEX].abs() < 1e-6 && (z[15] + 1.1).abs() < 1e-6, "{z:?}");
        let p: Vec<[f32; 3]> = sample_points([1.0, 2.0, 3.0], [-1.0, 0.0, 0.0], 0.4).collect();
        assert!((p[0][0] - 0.6).abs() < 1e-6 && p[0][1] == 2.0 && p[0][2] == 3.0);
    }

    #[test]
    fn the_first_opaque_sample_gives_the_colour() {
        // Empty until sample 6, opaque from there: sample 6's colour, whatever lies behind it.
        let mut sigma = [0.0f32; SAMPLES];
        let mut rgb = [RED; SAMPLES];
        sigma[6..].fill(1e6);
        rgb[6] = GREEN;
        let c = seen_colour(&sigma, &rgb, 0.1);
        assert!((c[0]).abs() < 1e-5 && (c[1] - 1.0).abs() < 1e-5, "{c:?}");
    }

    #[test]
    fn half_opaque_samples_weigh_a_half_a_quarter_an_eighth() {
        // σ·δ = ln 2 with δ = 0.25·0.4 = 0.1: α = ½ each; weights ½, ¼, ⅛ … (Σ = 1 − 2⁻¹⁶).
        let sigma = [std::f32::consts::LN_2 / 0.1; SAMPLES];
        let mut rgb = [GREEN; SAMPLES];
        rgb[0] = RED;
        let c = seen_colour(&sigma, &rgb, 0.4);
        let acc = 1.0 - 0.5f32.powi(SAMPLES as i32);
        assert!((c[0] - 0.5 / acc).abs() < 1e-5 && (c[1] - (acc - 0.5) / acc).abs() < 1e-5, "{c:?}");
    }

    #[test]
    fn samples_with_no_opacity_give_the_colour_at_the_vertex() {
        let mut rgb = [RED; SAMPLES];
        rgb[AT_VERTEX] = GREEN;
        assert_eq!(seen_colour(&[0.0; SAMPLES], &rgb, 0.1), GREEN);
        // A negative σ (the burn MLP leaves its ReLU to compositing) counts as empty.
        assert_eq!(seen_colour(&[-5.0; SAMPLES], &rgb, 0.1), GREEN);
    }
}
