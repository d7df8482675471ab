//! Where a frame's time goes on a device: render a bundle's first test view with the GPU loop
//! (where there is one; its largest difference from the CPU loop's frame), then with the CPU
//! loop, recording every field call (its points and its seconds), and, with page-locked and
//! with ordinary host buffers: whole frames, the recorded calls replayed alone, and single calls
//! of growing size (the fixed cost of a call against its cost per point).
//! Usage: cargo run --release -p nerf-runtime --example device_calls -- <bundle> [--device cuda] [--repeats N]

use nerf_core::camera::Pose;
use nerf_core::field::{Field, FieldOutput, Stage};
use nerf_core::render::{RenderedImage, render_image};
use nerf_runtime::environment::Device;
use nerf_runtime::{OpenOptions, OrtScene};
use std::time::Instant;

/// A field call: its points, directions and wall seconds.
type Call = (Vec<[f32; 3]>, Vec<[f32; 3]>, f64);

/// Records each call.
struct Recorder<'a, F: Field> {
    field: &'a mut F,
    calls: Vec<Call>,
}

impl<F: Field> Field for Recorder<'_, F> {
    type Error = F::Error;
    fn evaluate(&mut self, stage: Stage, points: &[[f32; 3]], dirs: &[[f32; 3]]) -> Result<FieldOutput, F::Error> {
        let start = Instant::now();
        let out = self.field.evaluate(stage, points, dirs)?;
        if !points.is_empty() {
            self.calls.push((points.to_vec(), dirs.to_vec(), start.elapsed().as_secs_f64()));
        }
        Ok(out)
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let bundle = std::path::Path::new(args.get(1).expect("usage: device_calls <bundle> [--device cuda] [--repeats N]"));
    let value = |flag: &str| args.iter().position(|a| a == flag).map(|i| args[i + 1].clone());
    let device: Device = value("--device").map_or(Device::Cpu, |d| d.parse().unwrap_or_else(|e| panic!("{e}")));
    let repeats: usize = value("--repeats").map_or(3, |r| r.parse().expect("--repeats: a number"));
    let mut scene = OrtScene::open(bundle, &OpenOptions { device, gpu_loop: true, ..OpenOptions::default() }).unwrap_or_else(|e| panic!("{e}"));
    let view = scene.description.poses.test.first().expect("the bundle has test poses");
    let pose = Pose::from_rows(view.transform_matrix);
    let k = scene.camera(None);
    let frame = |scene: &mut OrtScene| -> (f64, f64, RenderedImage) {
        let before = scene.field.graphs[0].1.seconds;
        let start = Instant::now();
        let image = scene.render(&k, &pose, &mut |_, _| {}).unwrap_or_else(|e| panic!("{e}"));
        (start.elapsed().as_secs_f64(), scene.field.graphs[0].1.seconds - before, image)
    };
    let best = |frames: &[(f64, f64, RenderedImage)]| -> (f64, f64) {
        let times = frames.iter().map(|f| format!("{:.3}", f.0)).collect::<Vec<_>>().join(" ");
        let b = frames.iter().min_by(|a, b| a.0.total_cmp(&b.0)).expect("a frame");
        println!("frames {times} s");
        (b.0, b.1)
    };
    let gpu_frame = if scene.gpu.is_some() {
        frame(&mut scene); // warm-up: sessions, arenas, kernels
        let frames: Vec<_> = (0..repeats).map(|_| frame(&mut scene)).collect();
        let (s, ort) = best(&frames);
        println!("the GPU loop: best {s:.3} s, of which onnxruntime {ort:.3} s");
        scene.gpu = None;
        Some(frames.into_iter().next().expect("a frame").2)
    } else {
        None
    };
    let cpu_frame = frame(&mut scene).2; // warm-up: sessions, arenas
    if let Some(g) = gpu_frame {
        let worst = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        let (a, b) = (&g.rays, &cpu_frame.rays);
        println!(
            "the GPU loop's frame against the CPU loop's: max |Δ| rgb {:.2e}, depth {:.2e}, acc {:.2e}",
            worst(a.rgb.as_flattened(), b.rgb.as_flattened()),
            worst(&a.depth, &b.depth),
            worst(&a.acc, &b.acc)
        );
    }
    let mut recorder = Recorder { field: &mut scene.field, calls: Vec::new() };
    let start = Instant::now();
    render_image(&mut recorder, scene.occupancy.as_ref(), &k, &pose, &scene.options, &mut |_, _| {}).unwrap_or_else(|e| panic!("{e}"));
    let recorded_s = start.elapsed().as_secs_f64();
    let calls = recorder.calls;
    let points: usize = calls.iter().map(|c| c.0.len()).sum();
    let in_calls: f64 = calls.iter().map(|c| c.2).sum();
    println!(
        "{}: {}×{} on {device}, {} rays a batch, overlap {}: {} field calls, {points} points; frame {recorded_s:.3} s, {in_calls:.3} s in the calls",
        bundle.display(),
        k.width,
        k.height,
        scene.options.chunk,
        scene.options.overlap,
        calls.len()
    );
    println!("calls (points:ms): {}", calls.iter().map(|c| format!("{}:{:.1}", c.0.len(), c.2 * 1e3)).collect::<Vec<_>>().join(" "));
    let largest = calls.iter().max_by_key(|c| c.0.len()).expect("at least one call");
    let pinned = scene.field.graphs[0].1.pinned();
    for mode in if pinned { vec!["pinned", "pageable"] } else { vec!["pageable"] } {
        if mode == "pageable" {
            scene.field.graphs[0].1.unpin();
        }
        let frames: Vec<_> = (0..repeats).map(|_| frame(&mut scene)).collect();
        let (s, ort) = best(&frames);
        println!("{mode}: the CPU loop: best {s:.3} s, of which onnxruntime {ort:.3} s");
        let net = &mut scene.field.graphs[0].1;
        let start = Instant::now();
        for (p, d, _) in &calls {
            net.run(p, d).unwrap_or_else(|e| panic!("{e}"));
        }
        println!("{mode}: the {} recorded calls replayed: {:.3} s", calls.len(), start.elapsed().as_secs_f64());
        let mut sweep = Vec::new();
        let mut n = 4096;
        while n <= largest.0.len() {
            let best = (0..3)
                .map(|_| {
                    let start = Instant::now();
                    net.run(&largest.0[..n], &largest.1[..n]).unwrap_or_else(|e| panic!("{e}"));
                    start.elapsed().as_secs_f64()
                })
                .fold(f64::INFINITY, f64::min);
            sweep.push(format!("{n}:{:.2}ms({:.1}M/s)", best * 1e3, n as f64 / best / 1e6));
            n *= 4;
        }
        println!("{mode}: one call of n points (best of 3): {}", sweep.join(" "));
    }
}
