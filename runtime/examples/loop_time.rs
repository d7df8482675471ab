//! Time the loop around the field alone: render a bundle's first test view once through
//! onnxruntime, recording every field call's output, then render it again with a field that
//! replays those outputs (checking each call asks for the same points), so what is timed is
//! rays, marching, packing and compositing only.
//! Usage: cargo run --release -p nerf-runtime --example loop_time -- <bundle> [repeats] [--overlap] [--chunk RAYS]

use nerf_core::camera::Pose;
use nerf_core::field::{Field, FieldOutput, Stage};
use nerf_core::render::render_image;
use nerf_runtime::{OpenOptions, OrtScene};
use std::time::Instant;

/// Records each call's points' count and output.
struct Recorder<'a, F: Field> {
    field: &'a mut F,
    calls: Vec<(usize, FieldOutput)>,
}

impl<F: Field> Field for Recorder<'_, F> {
    type Error = F::Error;
    fn evaluate(&mut self, stage: Stage, points: &[[f32; 3]], dirs: &[[f32; 3]]) -> Result<FieldOutput, F::Error> {
        let out = self.field.evaluate(stage, points, dirs)?;
        if !points.is_empty() {
            self.calls.push((points.len(), out.clone()));
        }
        Ok(out)
    }
}

/// Gives the recorded outputs back, in order.
struct Replay<'a> {
    calls: &'a [(usize, FieldOutput)],
    next: usize,
}

impl Field for Replay<'_> {
    type Error = std::convert::Infallible;
    fn evaluate(&mut self, _: Stage, points: &[[f32; 3]], _: &[[f32; 3]]) -> Result<FieldOutput, Self::Error> {
        if points.is_empty() {
            return Ok(FieldOutput::default());
        }
        let (n, out) = &self.calls[self.next];
        assert_eq!(*n, points.len(), "call {}: the replay asks for other points", self.next);
        self.next += 1;
        Ok(out.clone())
    }
}

/// CPU seconds this process has used, all threads (/proc/self/stat's utime + stime): on a busy
/// machine a steadier measure than the wall clock.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command's closing parenthesis; utime and stime are the 14th and 15th.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let ticks: f64 = rest.split_whitespace().skip(11).take(2).filter_map(|v| v.parse::<f64>().ok()).sum();
    ticks / 100.0
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let bundle = std::path::Path::new(args.get(1).expect("usage: loop_time <bundle> [repeats] [--overlap]"));
    let repeats: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(5);
    let overlap = args.iter().any(|a| a == "--overlap");
    let chunk = args.iter().position(|a| a == "--chunk").map(|i| args[i + 1].parse().expect("--chunk: a number"));
    let mut scene = OrtScene::open(bundle, &OpenOptions { chunk, ..OpenOptions::default() }).unwrap_or_else(|e| panic!("{e}"));
    scene.options.overlap = overlap;
    let view = scene.description.poses.test.first().expect("the bundle has test poses");
    let pose = Pose::from_rows(view.transform_matrix);
    let k = scene.camera(None);
    let mut recorder = Recorder { field: &mut scene.field, calls: Vec::new() };
    let start = Instant::now();
    let reference = render_image(&mut recorder, scene.occupancy.as_ref(), &k, &pose, &scene.options, &mut |_, _| {}).unwrap();
    let recorded_s = start.elapsed().as_secs_f64();
    let calls = recorder.calls;
    let net = &scene.field.graphs[0].1;
    println!("the recorded frame: {recorded_s:.3} s = onnxruntime {:.3} + Rust encoding {:.3} + the rest {:.3} s", net.seconds, net.encoding_seconds, recorded_s - net.seconds - net.encoding_seconds);
    let points: usize = calls.iter().map(|c| c.0).sum();
    println!("{}: {}×{}, {} rays a batch, {} field calls, {points} points, recorded in {:.3} s (overlap {overlap})", bundle.display(), k.width, k.height, scene.options.chunk, calls.len(), start.elapsed().as_secs_f64());
    if let Some(grid) = &scene.occupancy {
        // Made once per grid and kept (not part of the loop below): its cost, on a fresh copy.
        let fresh = grid.clone().with_threshold(grid.threshold());
        let start = Instant::now();
        let made: usize = (0..8).map(|octant| fresh.corner_reach(octant).len()).sum();
        println!("the grid's cubes, all 8 octants ({made} cells), made once: {:.4} s", start.elapsed().as_secs_f64());
    }
    let cpu_start = cpu_seconds();
    let mut wall = 0.0;
    for _ in 0..repeats {
        // Cloning the outputs stands in for the field's own output allocation: timed apart.
        let start = Instant::now();
        let mut replay = Replay { calls: &calls, next: 0 };
        let image = render_image(&mut replay, scene.occupancy.as_ref(), &k, &pose, &scene.options, &mut |_, _| {}).unwrap();
        let seconds = start.elapsed().as_secs_f64();
        let clone = Instant::now();
        let _copies: Vec<FieldOutput> = calls.iter().map(|c| c.1.clone()).collect();
        let clone_s = clone.elapsed().as_secs_f64();
        assert!(image == reference, "the replayed frame differs");
        wall += seconds;
        println!("loop {:.3} s (of which replaying the outputs ≈ {clone_s:.3} s), the same frame", seconds - clone_s);
    }
    // The clones are in the CPU time too (one thread): a small part.
    println!("mean over {repeats}: wall {:.3} s, CPU {:.3} s (all threads, with the replay's copies; /proc ticks of 10 ms)", wall / repeats as f64, (cpu_seconds() - cpu_start) / repeats as f64);
}
