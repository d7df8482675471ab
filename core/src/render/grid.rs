//! Empty-space skipping at render time: march through an occupancy grid's occupied cells.

use super::packed::{PackedSamples, march_front_to_back};
use super::RenderOptions;
use crate::field::{Field, Stage};
use crate::camera::{Rays, length, point_at};
use super::compositing::RayOutput;
use crate::sample::occupancy::OccupancyGrid;
use crate::rng::Rng;
use rayon::prelude::*;

/// The samples marching takes: `steps` equal intervals over [near, far], one sample at each
/// interval's middle, kept only where it lies in an occupied cell; δ = the interval · ‖d‖.
/// With `jitter` (training), each ray's samples move together by one uniform draw within their
/// interval instead of sitting at the middles (drawn ray by ray in order: deterministic).
/// Rays are marched in parallel, [`MARCH_RAYS_PER_TASK`] per task.
pub fn occupied_samples(grid: &OccupancyGrid, rays: &Rays, near: f32, far: f32, steps: usize, jitter: Option<&mut Rng>) -> PackedSamples {
    let interval = (far - near) / steps as f32;
    let shifts: Vec<f32> = match jitter {
        Some(rng) => (0..rays.len()).map(|_| rng.uniform()).collect(),
        None => vec![0.5; rays.len()],
    };
    let ray_list: Vec<usize> = (0..rays.len()).collect();
    // Per task: its rays' t values, and each ray's count.
    let parts: Vec<(Vec<f32>, Vec<usize>)> = ray_list
        .par_chunks(MARCH_RAYS_PER_TASK)
        .map(|chunk| {
            let mut t_values = Vec::new();
            let mut counts = Vec::with_capacity(chunk.len());
            for &r in chunk {
                let (o, d) = (rays.origins[r], rays.directions[r]);
                let before = t_values.len();
                for k in 0..steps {
                    let t = near + (k as f32 + shifts[r]) * interval;
                    if grid.is_occupied(point_at(o, d, t)) {
                        t_values.push(t);
                    }
                }
                counts.push(t_values.len() - before);
            }
            (t_values, counts)
        })
        .collect();
    let mut packed = PackedSamples { offsets: Vec::with_capacity(rays.len() + 1), ..PackedSamples::default() };
    packed.offsets.push(0);
    let mut r = 0;
    for (t_values, counts) in parts {
        packed.t.extend_from_slice(&t_values);
        for n in counts {
            let delta = interval * length(rays.directions[r]);
            packed.delta.extend(std::iter::repeat_n(delta, n));
            packed.offsets.push(packed.delta.len());
            r += 1;
        }
    }
    packed
}

/// Rays per parallel task of [`occupied_samples`].
const MARCH_RAYS_PER_TASK: usize = 256;

/// Render `rays` by marching through the grid's occupied cells with the last stage's network
/// (fine if there is one): [`occupied_samples`] with `options.march_steps` intervals, evaluated
/// front to back and packed, each ray stopping once its transmittance is below
/// `options.min_transmittance`. Unevaluated intervals are empty (σ = 0). Compositing is the
/// reference one (exclusive product of 1 − α + 1e-10, white background as rgb + 1 − acc).
pub fn render_rays<F: Field>(field: &mut F, grid: &OccupancyGrid, rays: &Rays, options: &RenderOptions) -> Result<Vec<RayOutput>, F::Error> {
    let s = &options.sampling;
    let stage = if s.n_fine > 0 { Stage::Fine } else { Stage::Coarse };
    let samples = occupied_samples(grid, rays, s.near, s.far, options.march_steps.max(1), None);
    let min_transmittance = options.min_transmittance.unwrap_or(0.0);
    let marched = march_front_to_back(field, stage, rays, &rays.view_directions(), &samples, min_transmittance, options.white_background)?;
    Ok(marched.rays)
}

#[cfg(test)]
mod tests {
    use super::super::{DEFAULT_MARCH_STEPS, render_image};
    use crate::field::FieldOutput;
    use super::*;
    use crate::camera::{Intrinsics, Pose};
    use crate::sample::stratified::SamplingConfig;

    /// A ball of density 200 and radius 0.5 at the origin, coloured by position.
    struct Ball(usize);

    impl Field for Ball {
        type Error = std::convert::Infallible;
        fn evaluate(&mut self, _: Stage, points: &[[f32; 3]], _: &[[f32; 3]]) -> Result<FieldOutput, Self::Error> {
            self.0 += points.len();
            let inside = |p: &[f32; 3]| p[0] * p[0] + p[1] * p[1] + p[2] * p[2] < 0.25;
            Ok(FieldOutput {
                rgb: points.iter().map(|p| p.map(|v| 0.5 + v)).collect(),
                sigma: points.iter().map(|p| if inside(p) { 200.0 } else { 0.0 }).collect(),
            })
        }
    }

    #[test]
    fn occupied_samples_keep_the_interval_middles_inside_occupied_cells_ray_by_ray() {
        // Every cell of the box ±1 occupied: a sample is kept iff it lies inside the box.
        let mut grid = OccupancyGrid::new(4, 1.0, 0.5);
        grid.update(&vec![1.0; grid.len()], 1.0);
        // 4 intervals over [0, 4]: middles at t = 0.5, 1.5, 2.5, 3.5.
        // A: x = −2 + t → −1.5, −0.5, 0.5, 1.5: t 1.5 and 2.5, δ = 1.
        // B: x = −2.5 + 2t → −1.5, 0.5, 2.5, 4.5: t 1.5, δ = 2 (‖d‖ = 2).
        // C: y = 5, never inside.
        let a = ([-2.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
        let b = ([-2.5, 0.1, 0.0], [2.0, 0.0, 0.0]);
        let c = ([-2.0, 5.0, 0.0], [1.0, 0.0, 0.0]);
        // 700 rays: the pattern crosses the parallel tasks' boundaries.
        let pattern = [a, b, c];
        let rays = Rays { origins: (0..700).map(|i| pattern[i % 3].0).collect(), directions: (0..700).map(|i| pattern[i % 3].1).collect(), viewdirs: None };
        let packed = occupied_samples(&grid, &rays, 0.0, 4.0, 4, None);
        let mut at = 0;
        for r in 0..700 {
            let (t, delta): (&[f32], f32) = match r % 3 {
                0 => (&[1.5, 2.5], 1.0),
                1 => (&[1.5], 2.0),
                _ => (&[], 0.0),
            };
            assert_eq!(packed.ray(r), at..at + t.len(), "ray {r}");
            assert_eq!(&packed.t[packed.ray(r)], t, "ray {r}");
            assert!(packed.delta[packed.ray(r)].iter().all(|&d| d == delta), "ray {r}");
            at += t.len();
        }
        assert_eq!(packed.offsets.len(), 701);
        // Jittered: one shift per ray, drawn in ray order (the same draws sequentially).
        let mut rng = Rng::new(3);
        let jittered = occupied_samples(&grid, &rays, 0.0, 4.0, 4, Some(&mut rng));
        let mut again = Rng::new(3);
        let shift0 = again.uniform();
        assert_eq!(jittered.t[0], 1.0 + shift0);
    }

    #[test]
    fn marching_through_the_grid_matches_the_dense_path_with_far_fewer_evaluations() {
        // Occupied: the 16³ cells over ±1.5 that touch the ball (known empty space elsewhere).
        let mut grid = OccupancyGrid::new(16, 1.5, 0.5);
        let size = 3.0 / 16.0;
        let touches = |c: usize| {
            let (i, j, k) = (c / 256, (c / 16) % 16, c % 16);
            let nearest = [i, j, k].map(|n| {
                let lo = -1.5 + n as f32 * size;
                0.0f32.clamp(lo, lo + size)
            });
            nearest.iter().map(|v| v * v).sum::<f32>() < 0.25
        };
        grid.update(&(0..grid.len()).map(|c| if touches(c) { 1.0 } else { 0.0 }).collect::<Vec<_>>(), 1.0);
        assert!(grid.occupied_fraction() < 0.05);
        let k = crate::PinholeCamera::from(Intrinsics { width: 24, height: 24, focal: 30.0 });
        let pose = Pose::spherical(30.0, -30.0, 4.0);
        let options = RenderOptions {
            sampling: SamplingConfig { n_coarse: 64, n_fine: 128, ..Default::default() },
            white_background: true,
            chunk: 100,
            min_transmittance: Some(1e-4),
            march_steps: DEFAULT_MARCH_STEPS,
        };
        let mut field = Ball(0);
        let dense = render_image(&mut field, None, &k, &pose, &RenderOptions { min_transmittance: None, ..options.clone() }, &mut |_, _| {}).unwrap();
        let dense_points = std::mem::take(&mut field.0);
        let skip = render_image(&mut field, Some(&grid), &k, &pose, &options, &mut |_, _| {}).unwrap();
        let skip_points = field.0;
        assert!(skip_points * 20 < dense_points, "{skip_points} points marched vs {dense_points} dense");
        assert!(dense.rays.acc.iter().any(|a| *a > 0.99) && dense.rays.acc.iter().any(|a| *a < 0.01), "the ball is in view");
        let db = crate::render::metrics::psnr(&skip.rays.rgb, &dense.rays.rgb);
        assert!(db > 35.0, "marching vs dense: {db:.1} dB");
    }
}
