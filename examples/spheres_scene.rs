//! Write the generated scene (three spheres on a plinth, `nerf_core::dataset::generate_scene`)
//! at any size, for measurements against its analytic surfaces (docs/mesh.md).
//!
//! ```text
//! cargo run --release --example spheres_scene -- --out spheres64 --size 64 --train 40 --seed 1
//! ```

use anyhow::Result;
use clap::Parser;
use nerf_core::dataset::{SyntheticSceneConfig, generate_scene};
use std::path::PathBuf;

#[derive(Parser)]
struct Args {
    /// Scene directory to write.
    #[arg(long)]
    out: PathBuf,
    /// Image side in pixels.
    #[arg(long, default_value_t = 64)]
    size: u32,
    /// Training views.
    #[arg(long, default_value_t = 40)]
    train: usize,
    /// Seed of the camera positions.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

fn main() -> Result<()> {
    let a = Args::parse();
    generate_scene(&a.out, &SyntheticSceneConfig { width: a.size, height: a.size, n_train: a.train, n_val: 1, n_test: 1, seed: a.seed })?;
    println!("{}×{} scene, {} training views: {}", a.size, a.size, a.train, a.out.display());
    Ok(())
}
