//! How fast the hash grid runs here: forward, and backward + sparse Adam update, in samples/s
//! (what `nerf bench` reports for the grid; `cargo run --release -p nerf-core --example
//! hash_grid_throughput` prints a table).

use super::adam::{SparseAdam, SparseAdamConfig};
use nerf_core::field::ngp::hash_grid::HashGridConfig;
use nerf_core::field::ngp::hash_grid::{HashGrid, HashGridGradient};
use nerf_core::error::{Error, Result};
use nerf_core::rng::Rng;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// How the benchmark's points are laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SampleOrder {
    /// Independent uniform points: every lookup a cache miss on fine levels (the worst case).
    Uniform,
    /// 128 ordered samples along each random chord of the cube, as a NeRF batch is
    /// (neighbouring samples share cells on coarse levels).
    Rays,
}

/// Samples along one ray in [`SampleOrder::Rays`].
pub const SAMPLES_PER_RAY: usize = 128;

/// One measurement (medians over the repeats, after one warm-up run).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GridThroughput {
    /// The grid measured.
    pub config: HashGridConfig,
    /// Points per pass.
    pub points: usize,
    /// rayon threads.
    pub threads: usize,
    /// Point layout.
    pub order: SampleOrder,
    /// Forward pass, samples/s.
    pub forward_samples_per_s: f64,
    /// Backward pass alone (scatter into the sparse gradient), samples/s.
    pub backward_samples_per_s: f64,
    /// Backward pass + sparse Adam step, samples/s.
    pub backward_update_samples_per_s: f64,
    /// Forward and backward + update in samples per CPU-second of this process (all threads
    /// together; Linux only, else NaN). Less sensitive than wall time to other processes
    /// sharing the cores: on an idle machine, wall throughput ≈ threads × this when the pass
    /// scales.
    pub forward_samples_per_cpu_s: f64,
    /// Backward + update, samples per CPU-second.
    pub backward_update_samples_per_cpu_s: f64,
    /// Table size in MiB (parameters only; Adam adds 3×, the gradient 1×).
    pub table_mib: f64,
    /// Fraction of the table's entries one pass touches.
    pub touched_fraction: f64,
}

/// `n` points of the unit cube laid out as `order` says, deterministic in `seed`.
pub fn sample_points(n: usize, order: SampleOrder, seed: u64) -> Vec<[f32; 3]> {
    let mut rng = Rng::new(seed);
    let point = |rng: &mut Rng| [rng.uniform(), rng.uniform(), rng.uniform()];
    match order {
        SampleOrder::Uniform => (0..n).map(|_| point(&mut rng)).collect(),
        SampleOrder::Rays => {
            let mut out = Vec::with_capacity(n);
            while out.len() < n {
                let (a, b) = (point(&mut rng), point(&mut rng));
                let k = SAMPLES_PER_RAY.min(n - out.len());
                out.extend((0..k).map(|i| {
                    let t = (i as f32 + 0.5) / SAMPLES_PER_RAY as f32;
                    [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2])]
                }));
            }
            out
        }
    }
}

/// Time `config` on `points` samples with `threads` rayon threads, `repeats` times each.
pub fn measure_throughput(config: &HashGridConfig, points: usize, threads: usize, order: SampleOrder, repeats: usize) -> Result<GridThroughput> {
    if points == 0 || repeats == 0 || threads == 0 {
        return Err(Error::Argument(format!("hash grid throughput: points {points}, threads {threads}, repeats {repeats} must all be positive")));
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Error::Argument(format!("hash grid throughput: cannot start {threads} threads: {e}")))?;
    pool.install(|| {
        let mut grid = HashGrid::new(*config, 1)?;
        let mut adam = SparseAdam::new(SparseAdamConfig::default(), &grid);
        let mut grad = HashGridGradient::new(&grid);
        let xs = sample_points(points, order, 2);
        let mut rng = Rng::new(3);
        let grad_out: Vec<f32> = (0..points * grid.output_dim()).map(|_| rng.uniform() - 0.5).collect();
        let mut out = vec![0.0; points * grid.output_dim()];
        let median = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        // (wall, CPU) seconds of `f`.
        let timed = |f: &mut dyn FnMut()| {
            let (start, cpu) = (Instant::now(), process_cpu_seconds());
            f();
            (start.elapsed().as_secs_f64(), process_cpu_seconds() - cpu)
        };
        // Warm-up: first touches of the gradient and Adam buffers page them in.
        grid.forward_into(&xs, &mut out);
        grid.backward(&xs, &grad_out, &mut grad);
        let touched = grad.touched_entries();
        adam.step(&mut grid, &mut grad);
        let (mut forward, mut forward_cpu) = (Vec::new(), Vec::new());
        for _ in 0..repeats {
            let (wall, cpu) = timed(&mut || grid.forward_into(&xs, &mut out));
            forward.push(wall);
            forward_cpu.push(cpu);
        }
        let (mut backward, mut both, mut both_cpu) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..repeats {
            let b = timed(&mut || grid.backward(&xs, &grad_out, &mut grad));
            let u = timed(&mut || adam.step(&mut grid, &mut grad));
            backward.push(b.0);
            both.push(b.0 + u.0);
            both_cpu.push(b.1 + u.1);
        }
        let total = config.total_entries()?;
        Ok(GridThroughput {
            config: *config,
            points,
            threads,
            order,
            forward_samples_per_s: points as f64 / median(forward),
            forward_samples_per_cpu_s: points as f64 / median(forward_cpu),
            backward_update_samples_per_cpu_s: points as f64 / median(both_cpu),
            backward_samples_per_s: points as f64 / median(backward),
            backward_update_samples_per_s: points as f64 / median(both),
            table_mib: (total * config.features_per_level * 4) as f64 / (1 << 20) as f64,
            touched_fraction: touched as f64 / total as f64,
        })
    })
}

/// User + system CPU time of this process so far, in seconds (`/proc/self/stat`, clock ticks of
/// 1/100 s); NaN where that file is not available.
fn process_cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else { return f64::NAN };
    // Fields after the parenthesised command name: state is the 3rd field, utime the 14th.
    let Some(rest) = stat.rsplit_once(')').map(|(_, r)| r) else { return f64::NAN };
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(f64::NAN);
    (ticks(11) + ticks(12)) / 100.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rays_are_ordered_chords_and_measurement_reports_positive_rates() {
        let p = sample_points(300, SampleOrder::Rays, 1);
        assert_eq!(p.len(), 300);
        assert!(p.iter().flatten().all(|v| (0.0..=1.0).contains(v)));
        // Consecutive samples of one ray are 1/128 of a chord apart (≤ √3/128).
        assert!(p[..128].windows(2).all(|w| (0..3).map(|d| (w[0][d] - w[1][d]).powi(2)).sum::<f32>().sqrt() <= 3f32.sqrt() / 128.0 + 1e-6));
        let config = HashGridConfig { levels: 4, log2_table_size: 10, max_resolution: 64, ..Default::default() };
        let t = measure_throughput(&config, 2000, 1, SampleOrder::Uniform, 1).unwrap();
        assert!(t.forward_samples_per_s > 0.0 && t.backward_update_samples_per_s > 0.0);
        assert!(t.backward_update_samples_per_s <= t.backward_samples_per_s);
        // Ticks are 1/100 s: spin until one has passed (a fresh test binary may not have one yet).
        let start = std::time::Instant::now();
        let mut spin = 0u64;
        while !(process_cpu_seconds() > 0.0) && start.elapsed().as_secs() < 2 {
            spin = std::hint::black_box(spin.wrapping_add(1));
        }
        assert!(process_cpu_seconds() > 0.0, "this process has used CPU time");
        assert!(t.touched_fraction > 0.0 && t.touched_fraction <= 1.0);
        assert!(measure_throughput(&config, 0, 1, SampleOrder::Uniform, 1).unwrap_err().to_string().contains("points 0"));
    }
}
