//! A picture of a `nerf mesh` PLY: a small software rasteriser (orthographic view, z-buffer,
//! flat shading by each triangle's own normal, tinted by its vertices' colours) writing a PNG.
//! With `--spheres` it also prints how far the vertices lie from the generated scene's true
//! surfaces (mean, median, 95th percentile), the figures docs/mesh.md reports.
//!
//! ```text
//! cargo run --release --example mesh_picture -- --mesh lego.ply --out lego.png [--azimuth 30 --elevation 30 --size 800 --clay]
//! cargo run --release --example mesh_picture -- --mesh spheres.ply --out spheres.png --spheres
//! ```

use anyhow::{Context, Result};
use clap::Parser;
use glam::Vec3;
use nerf_core::mesh::ply::read_ply;
use std::path::PathBuf;

#[derive(Parser)]
struct Args {
    /// The PLY file.
    #[arg(long)]
    mesh: PathBuf,
    /// The PNG to write.
    #[arg(long)]
    out: PathBuf,
    /// Side of the square picture in pixels.
    #[arg(long, default_value_t = 800)]
    size: u32,
    /// Where the viewer stands around +z (degrees from +x towards +y).
    #[arg(long, default_value_t = 30.0)]
    azimuth: f32,
    /// How high the viewer stands (degrees above the xy plane).
    #[arg(long, default_value_t = 30.0)]
    elevation: f32,
    /// Grey clay instead of the vertex colours.
    #[arg(long)]
    clay: bool,
    /// Draw only the triangles whose vertices all have y ≤ this (a cut through the mesh).
    #[arg(long)]
    cut_y: Option<f32>,
    /// Print the vertices' distances to the generated scene's surfaces.
    #[arg(long)]
    spheres: bool,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let mesh = read_ply(&args.mesh).with_context(|| format!("reading {}", args.mesh.display()))?;
    anyhow::ensure!(!mesh.faces.is_empty(), "{}: no triangles", args.mesh.display());
    if args.spheres {
        // All vertices, then those above the plinth's bottom face (z = −1), which no camera sees.
        for (what, floor) in [("all", f32::NEG_INFINITY), ("z > -1", -1.0)] {
            let mut d: Vec<f32> =
                mesh.vertices.iter().filter(|v| v.position[2] > floor).map(|v| nerf_core::dataset::surface_distance(Vec3::from_array(v.position))).collect();
            d.sort_by(f32::total_cmp);
            let mean = d.iter().sum::<f32>() / d.len() as f32;
            let at = |q: f32| d[(q * (d.len() - 1) as f32).round() as usize];
            println!("{what}: {} vertices, distance to the true surfaces mean {mean:.4}, median {:.4}, 95th percentile {:.4}", d.len(), at(0.5), at(0.95));
        }
    }
    let positions: Vec<Vec3> = mesh.vertices.iter().map(|v| Vec3::from_array(v.position)).collect();
    let (lo, hi) = positions.iter().fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), &p| (lo.min(p), hi.max(p)));
    let centre = 0.5 * (lo + hi);
    let radius = 0.5 * (hi - lo).length();
    let (az, el) = (args.azimuth.to_radians(), args.elevation.to_radians());
    let toward_viewer = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
    let right = Vec3::Z.cross(toward_viewer).normalize();
    let up = toward_viewer.cross(right);
    let light = (toward_viewer + 0.5 * up + 0.3 * right).normalize();
    let n = args.size as usize;
    let scale = 0.5 * n as f32 / (1.05 * radius);
    // Screen x right, y down; depth grows toward the viewer.
    let screen: Vec<Vec3> = positions
        .iter()
        .map(|&p| {
            let q = p - centre;
            Vec3::new(0.5 * n as f32 + scale * q.dot(right), 0.5 * n as f32 - scale * q.dot(up), q.dot(toward_viewer))
        })
        .collect();
    let mut depth = vec![f32::NEG_INFINITY; n * n];
    let mut rgb = vec![[1.0f32; 3]; n * n];
    for f in &mesh.faces {
        if args.cut_y.is_some_and(|cut| f.iter().any(|&v| positions[v as usize].y > cut)) {
            continue;
        }
        let [a, b, c] = f.map(|v| screen[v as usize]);
        let [pa, pb, pc] = f.map(|v| positions[v as usize]);
        let normal = (pb - pa).cross(pc - pa).normalize_or_zero();
        let shade = 0.25 + 0.75 * normal.dot(light).abs();
        let tint = if args.clay {
            Vec3::splat(0.8)
        } else {
            f.iter().map(|&v| Vec3::from_array(mesh.vertices[v as usize].color.map(|x| x as f32 / 255.0))).sum::<Vec3>() / 3.0
        };
        let colour = (shade * tint).to_array();
        let area = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
        if area.abs() < 1e-12 {
            continue;
        }
        let (x0, x1) = (a.x.min(b.x).min(c.x).floor().max(0.0) as usize, (a.x.max(b.x).max(c.x).ceil() as usize).min(n - 1));
        let (y0, y1) = (a.y.min(b.y).min(c.y).floor().max(0.0) as usize, (a.y.max(b.y).max(c.y).ceil() as usize).min(n - 1));
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                let w0 = ((b.x - px) * (c.y - py) - (b.y - py) * (c.x - px)) / area;
                let w1 = ((c.x - px) * (a.y - py) - (c.y - py) * (a.x - px)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * a.z + w1 * b.z + w2 * c.z;
                let at = y * n + x;
                if z > depth[at] {
                    depth[at] = z;
                    rgb[at] = colour;
                }
            }
        }
    }
    nerf_core::io::image::save_png(&args.out, args.size, args.size, &rgb)?;
    println!("{} triangles drawn into {}", mesh.faces.len(), args.out.display());
    Ok(())
}
