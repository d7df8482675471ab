//! Time `occupied_samples` on a bundle's occupancy grid for one 400×400 lego-like view, against
//! testing every interval (the loop it replaced), and check both give the same samples.
//! Usage: cargo run --release -p nerf-core --example march_time -- models/lego-ngp/occupancy.bin [steps]

use nerf_core::camera::{Intrinsics, Pose, Rays, point_at};
use nerf_core::render::grid::occupied_samples;
use nerf_core::sample::occupancy::OccupancyGrid;
use rayon::prelude::*;
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let grid = OccupancyGrid::load(std::path::Path::new(args.get(1).expect("usage: march_time <occupancy.bin> [steps]"))).unwrap_or_else(|e| panic!("{e}"));
    let steps: usize = args.get(2).map_or(1024, |s| s.parse().expect("steps: a number"));
    // Blender's lego camera (camera_angle_x 0.6911) at 400×400, radius 4, elevation −30°.
    let camera = nerf_core::PinholeCamera::from(Intrinsics { width: 400, height: 400, focal: 0.5 * 400.0 / (0.5f32 * 0.691_111_2).tan() });
    let rays = Rays::for_rows(&camera, &Pose::spherical(-90.0, -30.0, 4.0), 0..400);
    let (near, far) = (2.0, 6.0);
    for _ in 0..3 {
        let start = Instant::now();
        let fast = occupied_samples(&grid, &rays, near, far, steps, None);
        let skipping = start.elapsed().as_secs_f64();
        let start = Instant::now();
        let interval = (far - near) / steps as f32;
        let every: Vec<Vec<f32>> = (0..rays.len())
            .into_par_iter()
            .map(|r| (0..steps).map(|k| near + (k as f32 + 0.5) * interval).filter(|&t| grid.is_occupied(point_at(rays.origins[r], rays.directions[r], t))).collect())
            .collect();
        let reference = start.elapsed().as_secs_f64();
        let same = (0..rays.len()).all(|r| fast.t[fast.ray(r)] == every[r][..]);
        println!("{} rays × {steps} steps, {} samples: skipping {skipping:.3} s, every interval {reference:.3} s, same samples: {same}", rays.len(), fast.t.len());
        assert!(same, "the samples differ");
    }
}
