//! Hash-grid throughput on this machine for a few (L, F, T) choices.
//!
//! `cargo run --release --example hash_grid_throughput [points] [threads] [repeats]`
//! (defaults 262144, 2, 3). Compare rows within one run: the machine may be shared.

use nerf::field::ngp::throughput::{SampleOrder, measure_throughput};
use nerf_core::field::ngp::hash_grid::HashGridConfig;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<usize> = std::env::args().skip(1).map(|a| a.parse()).collect::<Result<_, _>>()?;
    let points = args.first().copied().unwrap_or(1 << 18);
    let threads = args.get(1).copied().unwrap_or(2);
    let repeats = args.get(2).copied().unwrap_or(3);
    println!("{points} points, {threads} threads, median of {repeats}");
    println!("(wall: samples per second; cpu: samples per CPU-second of all threads)");
    println!(
        "{:>7} {:>3} {:>3} {:>4} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8}",
        "order", "L", "F", "logT", "table MiB", "fwd M/s", "bwd M/s", "bwd+upd", "fwd cpu", "b+u cpu", "touched"
    );
    for order in [SampleOrder::Rays, SampleOrder::Uniform] {
        for (levels, features_per_level, log2_table_size) in [(16, 2, 19), (16, 2, 17), (8, 4, 17), (8, 2, 17), (16, 2, 15)] {
            let config = HashGridConfig { levels, features_per_level, log2_table_size, ..Default::default() };
            let t = measure_throughput(&config, points, threads, order, repeats)?;
            println!(
                "{:>7} {levels:>3} {features_per_level:>3} {log2_table_size:>4} {:>9.1} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>7.1}%",
                format!("{order:?}").to_lowercase(),
                t.table_mib,
                t.forward_samples_per_s / 1e6,
                t.backward_samples_per_s / 1e6,
                t.backward_update_samples_per_s / 1e6,
                t.forward_samples_per_cpu_s / 1e6,
                t.backward_update_samples_per_cpu_s / 1e6,
                100.0 * t.touched_fraction
            );
        }
    }
    Ok(())
}
