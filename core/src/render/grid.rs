//! Empty-space skipping at render time: march through an occupancy grid's occupied cells.

use super::packed::PackedSamples;
#[cfg(doc)]
use super::packed::march_front_to_back;
use super::{MARCH_SEGMENT, RenderOptions};
use crate::field::{Field, FieldOutput, Stage};
use crate::camera::{Rays, length, point_at};
use super::compositing::{RayAccumulator, RayOutput, alpha_from_density};
use crate::sample::contraction::Contraction;
use crate::sample::occupancy::{OCCUPIED_CUBE, OccupancyGrid};
use crate::rng::Rng;
use rayon::prelude::*;

/// The samples marching takes: the steps of [`march_segments`] (`steps` equal intervals over
/// [near, far]; on a contracted grid, intervals that grow with distance), one sample at each
/// interval's middle, kept only where it lies in an occupied cell; δ = its interval · ‖d‖.
/// With `jitter` (training), each ray's samples move together by one uniform draw within their
/// interval instead of sitting at the middles (drawn ray by ray in order: deterministic).
/// Rays are marched in parallel, [`MARCH_RAYS_PER_TASK`] per task. Space is crossed a cube of
/// empty or occupied cells at a time ([`march_ray`]); the samples are exactly those of testing
/// every interval ([`march_ray_every_interval`]).
pub fn occupied_samples(grid: &OccupancyGrid, rays: &Rays, near: f32, far: f32, steps: usize, jitter: Option<&mut Rng>) -> PackedSamples {
    let segments = march_segments(near, far, steps, grid.contraction());
    let shifts: Vec<f32> = match jitter {
        Some(rng) => (0..rays.len()).map(|_| rng.uniform()).collect(),
        None => vec![0.5; rays.len()],
    };
    let skipper = Skipper::new(grid);
    let ray_list: Vec<usize> = (0..rays.len()).collect();
    // Per task: its rays' t values and intervals, and each ray's count.
    let parts: Vec<(Vec<f32>, Vec<f32>, Vec<usize>)> = ray_list
        .par_chunks(MARCH_RAYS_PER_TASK)
        .map(|chunk| {
            let (mut t_values, mut intervals) = (Vec::new(), Vec::new());
            let mut counts = Vec::with_capacity(chunk.len());
            for &r in chunk {
                let before = t_values.len();
                march_ray(&skipper, &segments, rays.origins[r], rays.directions[r], shifts[r], &mut |t, _, interval| {
                    t_values.push(t);
                    intervals.push(interval);
                });
                counts.push(t_values.len() - before);
            }
            (t_values, intervals, counts)
        })
        .collect();
    let mut packed = PackedSamples { offsets: Vec::with_capacity(rays.len() + 1), ..PackedSamples::default() };
    packed.offsets.push(0);
    let mut r = 0;
    for (t_values, intervals, counts) in parts {
        packed.t.extend_from_slice(&t_values);
        let mut at = 0;
        for n in counts {
            let norm = length(rays.directions[r]);
            packed.delta.extend(intervals[at..at + n].iter().map(|&interval| interval * norm));
            at += n;
            packed.offsets.push(packed.delta.len());
            r += 1;
        }
    }
    packed
}

/// One stretch of a ray's steps: `steps` equal intervals of `interval` from t = `start`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// Where the first interval begins.
    pub start: f32,
    /// Each interval's length in t.
    pub interval: f32,
    /// How many intervals.
    pub steps: usize,
}

/// The most segments a contracted march has (the fifth starts 170 units out).
const MAX_SEGMENTS: usize = 8;

/// Where marching steps along a ray, as segments of equal intervals:
/// - uncontracted: one segment, `steps` intervals over [near, far];
/// - over a contracted world: segments of `steps / 4` intervals (at least 1) from `near`, the
///   first spanning 2 units (the inner cube's side), each next one's interval 4× the last's
///   (spans 2, 8, 32, 128, … : steps that grow with distance, as the contraction shrinks what
///   lies far), while a segment starts before `far` ([`MAX_SEGMENTS`] at most). Each start is
///   the last start plus its steps × its interval, in f32, in that order.
pub fn march_segments(near: f32, far: f32, steps: usize, contraction: Option<Contraction>) -> Vec<Segment> {
    if contraction.is_none() {
        return vec![Segment { start: near, interval: (far - near) / steps as f32, steps }];
    }
    let n = (steps / 4).max(1);
    let (mut start, mut interval) = (near, 2.0 / n as f32);
    let mut segments = Vec::new();
    loop {
        segments.push(Segment { start, interval, steps: n });
        start += n as f32 * interval;
        interval *= 4.0;
        if !(start < far) || segments.len() == MAX_SEGMENTS {
            return segments;
        }
    }
}

/// One ray's marching through one [`Segment`]: step `k` (0 ≤ k < `steps`) samples
/// t = near + (k + shift) · interval.
#[derive(Clone, Copy)]
struct March {
    origin: [f32; 3],
    direction: [f32; 3],
    near: f32,
    interval: f32,
    steps: usize,
    shift: f32,
}

impl March {
    fn t(&self, k: usize) -> f32 {
        self.near + (k as f32 + self.shift) * self.interval
    }

    /// The first step whose (exact) t is at or after `t`, clamped to 0..=steps, moved by `by`.
    fn step_at(&self, t: f64, by: f64) -> usize {
        // Clamped before rounding up, by hand: `f64::ceil` is a libm call on baseline x86-64.
        let x = ((t - self.near as f64) / self.interval as f64 - self.shift as f64).clamp(-2.0, self.steps as f64 + 2.0);
        let floor = x as i64 as f64;
        let ceil = if floor < x { floor + 1.0 } else { floor };
        (ceil + by).clamp(0.0, self.steps as f64) as usize
    }
}

/// The reference marching: test every step of every segment (what [`RayMarch`] must equal);
/// pushes each kept step's t and interval.
#[cfg(test)]
fn march_ray_every_interval(segments: &[Segment], origin: [f32; 3], direction: [f32; 3], shift: f32, occupied: &mut impl FnMut([f32; 3]) -> bool, out: &mut Vec<(f32, f32)>) {
    for s in segments {
        let ray = March { origin, direction, near: s.start, interval: s.interval, steps: s.steps, shift };
        for k in 0..ray.steps {
            let t = ray.t(k);
            if occupied(point_at(ray.origin, ray.direction, t)) {
                out.push((t, s.interval));
            }
        }
    }
}

/// The grid's geometry and its cubes ([`OccupancyGrid::corner_reach`]): marching at a cell
/// jumps through the largest cube of cells in the cell's state that has the cell at its corner
/// and reaches along the ray. Shared by every batch of rays.
pub struct Skipper<'a> {
    grid: &'a OccupancyGrid,
    /// A cell's side in world units.
    cell_side: f64,
    /// The cells lo..hi per axis of the centred cube where cells are boxes of the world (the
    /// whole grid; the cube ±1 on a contracted grid): cubes are jumped through only inside it,
    /// cut at its faces.
    identity_cells: (usize, usize),
}

impl<'a> Skipper<'a> {
    /// Marching through `grid` (its cubes made on first use per octant, then kept with the grid).
    pub fn new(grid: &'a OccupancyGrid) -> Self {
        let r = grid.resolution();
        // Contracted: cell i spans −2 + 4i/R .. −2 + 4(i + 1)/R, inside ±1 from ⌈R/4⌉ to ⌊3R/4⌋.
        let identity_cells = if grid.contraction().is_some() { (r.div_ceil(4), 3 * r / 4) } else { (0, r) };
        Skipper { grid, cell_side: 2.0 * grid.bound() as f64 / r as f64, identity_cells }
    }

    /// The cells of the cube of `side` cells from `cell` reaching into `octant` ([`OccupancyGrid::corner_reach`]),
    /// cut to [`Self::identity_cells`]: [lo, hi) per axis (empty on an axis where the cell lies outside).
    fn corner_cells(&self, cell: [usize; 3], side: usize, octant: u8) -> ([usize; 3], [usize; 3]) {
        let (first, end) = self.identity_cells;
        let mut lo = [0; 3];
        let mut hi = [0; 3];
        for a in 0..3 {
            let (l, h) = if octant >> (2 - a) & 1 == 1 { (cell[a], cell[a] + side) } else { ((cell[a] + 1).saturating_sub(side), cell[a] + 1) };
            (lo[a], hi[a]) = (l.max(first), h.min(end));
        }
        (lo, hi)
    }

    /// The world box of cells [lo, hi) per axis, grown by `margin` (shrunk where negative).
    fn cell_box(&self, lo: [usize; 3], hi: [usize; 3], margin: f64) -> ([f64; 3], [f64; 3]) {
        let b = self.grid.bound() as f64;
        (lo.map(|i| -b + i as f64 * self.cell_side - margin), hi.map(|i| -b + i as f64 * self.cell_side + margin))
    }
}

/// The t range over which the line o + t·d lies in the box [lo, hi] (empty: start > end).
fn slab(o: [f64; 3], d: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> (f64, f64) {
    let (mut start, mut end) = (f64::NEG_INFINITY, f64::INFINITY);
    for a in 0..3 {
        if d[a] == 0.0 {
            // A zero component keeps that coordinate exactly o (o + t·0 rounds to o).
            if o[a] < lo[a] || o[a] > hi[a] {
                return (f64::INFINITY, f64::NEG_INFINITY);
            }
        } else {
            let (u, v) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
            start = start.max(u.min(v));
            end = end.min(u.max(v));
        }
    }
    (start, end)
}

/// One ray's marching, resumable: [`RayMarch::advance`] emits its next occupied samples, in
/// order, exactly those of [`march_ray_every_interval`], testing far fewer steps, one
/// [`Segment`] after the other. Steps before the grid's box and after it are not tested (a
/// contracted grid's box is the whole world); at a tested step, the steps up to where the ray
/// leaves the cube of cells in the cell's state with the cell at its corner, reaching along the
/// ray ([`Skipper`]), are skipped (empty) or emitted untested (occupied). Rounding
/// cannot misplace a step: the boxes are grown (the grid's) or shrunk (a cube's, a cell's) by a
/// margin far above the f32 error of a sample's position and of a step's t, and a run ends
/// before the first step at or after the shrunk box's exit. On a contracted grid, cubes are
/// jumped through only inside the inner cube (where contraction leaves points as they are);
/// outside it every step is tested.
struct RayMarch {
    /// The segment being marched, and its index.
    ray: March,
    segment: usize,
    o: [f64; 3],
    d: [f64; 3],
    /// 1/d per axis (the exits of the boxes jumped through).
    inv_d: [f64; 3],
    margin: f64,
    /// The next step to test, and the step after the last that can be occupied.
    k: usize,
    end: usize,
    /// Steps before this one lie in the occupied cube of the last step tested (emitted untested).
    occupied_until: usize,
    /// The octant the ray heads into (bit 2: x grows, bit 1: y, bit 0: z), whose cubes it jumps.
    octant: u8,
    /// Test every step (rays the skipping does not handle: non-finite inputs, or a
    /// non-positive interval).
    every: bool,
    /// Steps tested so far (the work skipping saves).
    tested: usize,
}

impl RayMarch {
    /// A ray from `origin` along `direction` marched through `segments` (at least one), each
    /// step's sample at `shift` (0.5: the middle) of its interval.
    fn new(skipper: &Skipper, segments: &[Segment], origin: [f32; 3], direction: [f32; 3], shift: f32) -> Self {
        let s = segments[0];
        let mut march = Self::segment(skipper, March { origin, direction, near: s.start, interval: s.interval, steps: s.steps, shift }, 0);
        march.settle(skipper, segments);
        march
    }

    /// Move on to the next segment while this one is marched (so that [`Self::finished`] says
    /// whether the whole ray is).
    fn settle(&mut self, skipper: &Skipper, segments: &[Segment]) {
        while self.k >= self.end && self.segment + 1 < segments.len() {
            let s = segments[self.segment + 1];
            let tested = self.tested;
            *self = Self::segment(skipper, March { near: s.start, interval: s.interval, steps: s.steps, ..self.ray }, self.segment + 1);
            self.tested += tested;
        }
    }

    /// The marching of `ray`, segment `segment` of its list.
    fn segment(skipper: &Skipper, ray: March, segment: usize) -> Self {
        let finite = ray.origin.iter().chain(&ray.direction).chain([&ray.near, &ray.shift]).all(|v| v.is_finite());
        let (o, d) = (ray.origin.map(f64::from), ray.direction.map(f64::from));
        // A NaN interval fails `> 0` too.
        if !finite || ray.interval.is_infinite() || ray.interval <= 0.0 || ray.interval.is_nan() {
            return RayMarch { end: ray.steps, ray, segment, o, d, inv_d: [0.0; 3], margin: 0.0, k: 0, occupied_until: 0, octant: 0, every: true, tested: 0 };
        }
        let grid = skipper.grid;
        let r = grid.resolution();
        // The largest coordinate magnitude a sample reaches bounds its rounding error.
        let t_max = ray.t(ray.steps).abs().max(ray.near.abs()) as f64;
        let scale = (0..3).map(|a| o[a].abs() + t_max * d[a].abs()).fold(grid.bound() as f64, f64::max);
        let margin = 1e-3 * skipper.cell_side + 64.0 * f32::EPSILON as f64 * scale;
        let (k, end) = if grid.contraction().is_some() {
            (0, ray.steps)
        } else {
            let (lo, hi) = skipper.cell_box([0; 3], [r; 3], margin);
            let (enter, leave) = slab(o, d, lo, hi);
            // Finite inputs: the slab's ends are numbers (±∞ at most), never NaN.
            if enter > leave { (0, 0) } else { (ray.step_at(enter, -1.0), ray.step_at(leave, 1.0)) }
        };
        let octant = (d[0] > 0.0) as u8 * 4 + (d[1] > 0.0) as u8 * 2 + (d[2] > 0.0) as u8;
        RayMarch { ray, segment, o, d, inv_d: d.map(|v| 1.0 / v), margin, k, end, occupied_until: 0, octant, every: false, tested: 0 }
    }

    /// Whether every step of every segment has been marched.
    fn finished(&self) -> bool {
        self.k >= self.end
    }

    /// Emit (t, point, interval) for the ray's next steps in occupied cells, at most `max` of
    /// them, crossing into later segments as needed; returns how many.
    fn advance(&mut self, skipper: &Skipper, segments: &[Segment], max: usize, emit: &mut impl FnMut(f32, [f32; 3], f32)) -> usize {
        let mut emitted = 0;
        loop {
            emitted += self.advance_in_segment(skipper, max - emitted, emit);
            self.settle(skipper, segments);
            if emitted >= max || self.finished() {
                return emitted;
            }
        }
    }

    /// [`Self::advance`] within the current segment.
    fn advance_in_segment(&mut self, skipper: &Skipper, max: usize, emit: &mut impl FnMut(f32, [f32; 3], f32)) -> usize {
        let (ray, grid, r) = (&self.ray, skipper.grid, skipper.grid.resolution());
        let cubes = grid.corner_reach(self.octant as usize);
        let interval = ray.interval;
        let mut emitted = 0;
        while self.k < self.end && emitted < max {
            let k = self.k;
            let t = ray.t(k);
            let p = point_at(ray.origin, ray.direction, t);
            if k < self.occupied_until {
                emit(t, p, interval);
                emitted += 1;
                self.k += 1;
                continue;
            }
            let cell = grid.cell_coordinates(p).map(|[i, j, k]| ([i, j, k], (i * r + j) * r + k));
            self.tested += 1;
            // `OccupancyGrid::is_occupied`, from the cubes' table.
            let occupied = cell.is_some_and(|(_, c)| cubes[c] & OCCUPIED_CUBE != 0);
            // The steps from this one up to the first at or after `run_end` share its state.
            let run_end = match cell {
                Some((cell, c)) if !self.every => {
                    // The cube of cells in this cell's state from the cell on, shrunk by the
                    // margin: where the exact line at t lies inside it, every step up to its
                    // exit does too, so lies in cells of the same state.
                    let (lo, hi) = skipper.corner_cells(cell, (cubes[c] & !OCCUPIED_CUBE) as usize, self.octant);
                    let (lo, hi) = skipper.cell_box(lo, hi, -self.margin);
                    let tt = t as f64;
                    let mut exit = f64::INFINITY;
                    // The cube lies where cells are world boxes (`corner_cells` cuts it there); a
                    // cell outside (a contracted shell) gets a box that misses it, so no jump.
                    let mut inside = true;
                    for a in 0..3 {
                        let x = self.o[a] + tt * self.d[a];
                        inside &= lo[a] <= x && x <= hi[a];
                        if self.d[a] != 0.0 {
                            exit = exit.min(((if self.d[a] > 0.0 { hi[a] } else { lo[a] }) - self.o[a]) * self.inv_d[a]);
                        }
                    }
                    if inside { ray.step_at(exit, 0.0) } else { k + 1 }
                }
                _ => k + 1,
            };
            if occupied {
                emit(t, p, interval);
                emitted += 1;
                self.occupied_until = run_end;
                self.k += 1;
            } else {
                self.k = run_end.max(k + 1);
            }
        }
        emitted
    }
}

/// Emit (t, point, interval) for each of the ray's occupied steps, in order ([`RayMarch`]);
/// returns how many steps it tested.
fn march_ray(skipper: &Skipper, segments: &[Segment], origin: [f32; 3], direction: [f32; 3], shift: f32, emit: &mut impl FnMut(f32, [f32; 3], f32)) -> usize {
    let mut march = RayMarch::new(skipper, segments, origin, direction, shift);
    march.advance(skipper, segments, usize::MAX, emit);
    march.tested
}

/// Rays per parallel task of [`occupied_samples`].
const MARCH_RAYS_PER_TASK: usize = 256;

/// Rays per parallel task of [`render_rays`]' rounds.
const ROUND_RAYS_PER_TASK: usize = 512;

/// A ray still marching in [`render_rays`]: its index, its marching and its compositing.
struct LiveRay {
    r: usize,
    march: RayMarch,
    ray: RayAccumulator,
    /// Finished (its output written), waiting to be dropped from the list.
    done: bool,
}

/// One task's share of a round: its rays' next samples, packed ray by ray.
#[derive(Default)]
struct RoundPart {
    points: Vec<[f32; 3]>,
    dirs: Vec<[f32; 3]>,
    t: Vec<f32>,
    /// Each sample's interval (its δ over ‖d‖).
    intervals: Vec<f32>,
    counts: Vec<u8>,
}

/// Render `rays` by marching through the grid's occupied cells with the last stage's network
/// (fine if there is one), as [`render_rays_in`] does.
pub fn render_rays<F: Field>(field: &mut F, grid: &OccupancyGrid, rays: &Rays, options: &RenderOptions) -> Result<Vec<RayOutput>, F::Error> {
    render_rays_in(field, &Skipper::new(grid), rays, options)
}

/// Render `rays` through `skipper`'s grid: the samples of [`occupied_samples`] with
/// `options.march_steps` intervals, evaluated front to back in rounds. Each round marches every
/// live ray only as far as its next [`MARCH_SEGMENT`] occupied samples, evaluates all of them in
/// one field call, composites them, and drops the rays whose transmittance fell below
/// `options.min_transmittance` or that ran out of steps: a ray that stops early never marches
/// the rest, and the field calls are those of [`march_front_to_back`] over the precomputed
/// samples, point for point. Compositing is the reference one (exclusive product of
/// 1 − α + 1e-10, white background as rgb + 1 − acc).
///
/// With `options.overlap` the rays march as two halves taking turns: while the field evaluates
/// one half's round (on a device, which leaves the CPU idle), the other half composites its last
/// round and marches its next. The same samples and pixels; half the points per call.
pub fn render_rays_in<F: Field>(field: &mut F, skipper: &Skipper, rays: &Rays, options: &RenderOptions) -> Result<Vec<RayOutput>, F::Error> {
    let s = &options.sampling;
    let stage = if s.n_fine > 0 { Stage::Fine } else { Stage::Coarse };
    let steps = options.march_steps.max(1);
    let round = Round {
        skipper,
        rays,
        viewdirs: rays.view_directions(),
        segments: march_segments(s.near, s.far, steps, skipper.grid.contraction()),
        min_transmittance: options.min_transmittance.unwrap_or(0.0),
        white_background: options.white_background,
    };
    let mut outputs = vec![RayAccumulator::default().finish(options.white_background); rays.len()];
    let mut live: Vec<LiveRay> = (0..rays.len())
        .into_par_iter()
        .with_min_len(ROUND_RAYS_PER_TASK)
        .map(|r| {
            let march = RayMarch::new(skipper, &round.segments, rays.origins[r], rays.directions[r], 0.5);
            LiveRay { r, march, ray: RayAccumulator::default(), done: false }
        })
        .filter(|l| !l.march.finished())
        .collect();
    if !options.overlap {
        // Compositing a round and marching the next in one pass; finished rays stay in the list
        // (skipped) until they are half of it, then a round composites, drops them and marches.
        // The parts and the call's inputs are refilled round after round (fresh buffers each
        // round cost page faults and copies comparable to the marching itself).
        let (mut parts, mut dead, mut done) = (Vec::new(), 0, Vec::new());
        let (mut points, mut dirs) = (Vec::new(), Vec::new());
        round.march(&mut live, &mut parts);
        while !live.is_empty() {
            gather(&parts, &mut points, &mut dirs);
            let out = if points.is_empty() { FieldOutput::default() } else { field.evaluate(stage, &points, &dirs)? };
            if dead * 2 >= live.len() {
                round.composite(&mut live, &parts, &out, &mut outputs);
                round.march(&mut live, &mut parts);
                dead = 0;
            } else {
                round.composite_and_march(&mut live, &mut parts, &out, &mut done);
                dead += done.len();
                for (r, output) in done.drain(..) {
                    outputs[r] = output;
                }
            }
        }
        return Ok(outputs);
    }
    // Two halves: `ready` has marched (its parts wait for the field), `waiting` holds its last
    // round's parts and field output, to composite before it marches again.
    let second = live.split_off(live.len() / 2);
    let mut ready = (live, Vec::new());
    round.march(&mut ready.0, &mut ready.1);
    let mut waiting: (Vec<LiveRay>, Vec<RoundPart>, Option<FieldOutput>) = (second, Vec::new(), None);
    let (mut finished, mut points, mut dirs) = (Vec::new(), Vec::new(), Vec::new());
    loop {
        gather(&ready.1, &mut points, &mut dirs);
        let (out, done) = std::thread::scope(|scope| {
            let other = scope.spawn(|| {
                let (live, parts, out) = &mut waiting;
                let mut done = Vec::new();
                if let Some(out) = out.take() {
                    round.composite_into(live, parts, &out, &mut done);
                    live.retain(|l| !l.done);
                }
                round.march(live, parts);
                done
            });
            let out = if points.is_empty() { Ok(FieldOutput::default()) } else { field.evaluate(stage, &points, &dirs) };
            (out, other.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
        });
        finished.extend(done);
        let out = out?;
        // Swap: the half just evaluated waits to be composited; the other has marched.
        let evaluated = std::mem::replace(&mut ready, (std::mem::take(&mut waiting.0), std::mem::take(&mut waiting.1)));
        waiting = (evaluated.0, evaluated.1, Some(out));
        if ready.0.is_empty() && waiting.0.is_empty() {
            break;
        }
    }
    for (r, output) in finished {
        outputs[r] = output;
    }
    Ok(outputs)
}

/// What every round of [`render_rays_in`] shares.
struct Round<'a> {
    skipper: &'a Skipper<'a>,
    rays: &'a Rays,
    viewdirs: Vec<[f32; 3]>,
    segments: Vec<Segment>,
    min_transmittance: f32,
    white_background: bool,
}

impl Round<'_> {
    /// March each live ray to its next samples (at most [`MARCH_SEGMENT`]), in parallel, into
    /// `parts` (one per task, their buffers reused).
    fn march(&self, live: &mut [LiveRay], parts: &mut Vec<RoundPart>) {
        parts.resize_with(live.len().div_ceil(ROUND_RAYS_PER_TASK), RoundPart::default);
        live.par_chunks_mut(ROUND_RAYS_PER_TASK).zip(parts.par_iter_mut()).for_each(|(chunk, part)| self.march_chunk(chunk, part));
    }

    /// One task's rays' next samples, in place of `part`'s.
    fn march_chunk(&self, chunk: &mut [LiveRay], part: &mut RoundPart) {
        let skipper = self.skipper;
        let most = chunk.len() * MARCH_SEGMENT;
        for v in [&mut part.points, &mut part.dirs] {
            v.clear();
            v.reserve(most);
        }
        for v in [&mut part.t, &mut part.intervals] {
            v.clear();
            v.reserve(most);
        }
        part.counts.clear();
        for l in chunk.iter_mut() {
            if l.done {
                part.counts.push(0);
                continue;
            }
            let n = l.march.advance(skipper, &self.segments, MARCH_SEGMENT, &mut |t, p, interval| {
                part.t.push(t);
                part.points.push(p);
                part.intervals.push(interval);
            });
            part.dirs.extend(std::iter::repeat_n(self.viewdirs[l.r], n));
            part.counts.push(n as u8);
        }
    }

    /// Composite the field's `out` for `parts` (as [`Self::march`] made them from `live`) and
    /// drop the rays that are done, writing their outputs.
    fn composite(&self, live: &mut Vec<LiveRay>, parts: &[RoundPart], out: &FieldOutput, outputs: &mut [RayOutput]) {
        let mut done = Vec::new();
        self.composite_into(live, parts, out, &mut done);
        live.retain(|l| !l.done);
        for (r, output) in done {
            outputs[r] = output;
        }
    }

    /// Composite the field's `out` for `parts` into `live`, the finished rays marked done and
    /// their outputs pushed to `done` (they stay in the list).
    fn composite_into(&self, live: &mut [LiveRay], parts: &[RoundPart], out: &FieldOutput, done: &mut Vec<(usize, RayOutput)>) {
        let starts = part_starts(parts);
        let finished: Vec<Vec<(usize, RayOutput)>> = live
            .par_chunks_mut(ROUND_RAYS_PER_TASK)
            .zip(parts)
            .zip(starts)
            .map(|((chunk, part), start)| self.composite_chunk(chunk, part, out, start))
            .collect();
        finished.into_iter().for_each(|f| done.extend(f));
    }

    /// [`Self::composite_into`] and the next [`Self::march`] in one pass over the rays (the
    /// list unchanged since `parts` were marched from it).
    fn composite_and_march(&self, live: &mut [LiveRay], parts: &mut [RoundPart], out: &FieldOutput, done: &mut Vec<(usize, RayOutput)>) {
        let starts = part_starts(parts);
        let finished: Vec<_> = live
            .par_chunks_mut(ROUND_RAYS_PER_TASK)
            .zip(parts)
            .zip(starts)
            .map(|((chunk, part), start)| {
                let finished = self.composite_chunk(chunk, part, out, start);
                self.march_chunk(chunk, part);
                finished
            })
            .collect();
        finished.into_iter().for_each(|f| done.extend(f));
    }

    /// Composite one task's samples (its part's, from `start` in `out`); returns the rays that
    /// finished, now marked done.
    fn composite_chunk(&self, chunk: &mut [LiveRay], part: &RoundPart, out: &FieldOutput, start: usize) -> Vec<(usize, RayOutput)> {
        let (mut i, mut finished) = (0, Vec::new());
        for (l, &n) in chunk.iter_mut().zip(&part.counts).filter(|(l, _)| !l.done) {
            let norm = length(self.rays.directions[l.r]);
            for _ in 0..n {
                let alpha = alpha_from_density(out.sigma[start + i], part.intervals[i] * norm);
                l.ray.add(alpha, out.rgb[start + i], part.t[i]);
                i += 1;
            }
            if l.ray.transmittance() < self.min_transmittance || l.march.finished() {
                l.done = true;
                finished.push((l.r, l.ray.finish(self.white_background)));
            }
        }
        finished
    }
}

/// Where each part's samples start in the field call.
fn part_starts(parts: &[RoundPart]) -> Vec<usize> {
    parts.iter().scan(0, |at, p| Some(std::mem::replace(at, *at + p.t.len()))).collect()
}

/// The field call's inputs: `parts`' points and directions in order, in place of the last call's.
fn gather(parts: &[RoundPart], points: &mut Vec<[f32; 3]>, dirs: &mut Vec<[f32; 3]>) {
    points.clear();
    dirs.clear();
    for part in parts {
        points.extend_from_slice(&part.points);
        dirs.extend_from_slice(&part.dirs);
    }
}

#[cfg(test)]
mod tests {
    use super::super::{DEFAULT_MARCH_STEPS, render_image};
    use super::super::packed::march_front_to_back;
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

    /// The per-interval loop's samples, packed as [`occupied_samples`] packs them.
    fn every_interval(grid: &OccupancyGrid, rays: &Rays, near: f32, far: f32, steps: usize, shifts: &[f32]) -> PackedSamples {
        let segments = march_segments(near, far, steps, grid.contraction());
        let mut packed = PackedSamples { offsets: vec![0], ..PackedSamples::default() };
        for (r, &shift) in shifts.iter().enumerate() {
            let mut kept = Vec::new();
            march_ray_every_interval(&segments, rays.origins[r], rays.directions[r], shift, &mut |p| grid.is_occupied(p), &mut kept);
            let norm = length(rays.directions[r]);
            packed.t.extend(kept.iter().map(|k| k.0));
            packed.delta.extend(kept.iter().map(|k| k.1 * norm));
            packed.offsets.push(packed.t.len());
        }
        packed
    }

    /// Blocks of cells that [`sparse_grid`] fills or leaves empty.
    const BLOCK: usize = 8;

    /// Bound 1 and resolution 32 (cells of exactly 1/16, blocks of 1/2): occupied cells only in
    /// about a third of the blocks, a tenth of those blocks' cells, so some blocks are empty and
    /// the occupied ones are mostly empty cells.
    fn sparse_grid(seed: u64) -> OccupancyGrid {
        let mut rng = Rng::new(seed);
        let r = 32;
        let nb = r / BLOCK;
        let chosen: Vec<bool> = (0..nb * nb * nb).map(|_| rng.uniform() < 0.35).collect();
        let density: Vec<f32> = (0..r * r * r)
            .map(|c| {
                let (i, j, k) = (c / (r * r) / BLOCK, (c / r) % r / BLOCK, c % r / BLOCK);
                let pick = rng.uniform() < 0.1;
                if chosen[(i * nb + j) * nb + k] && pick { 1.0 } else { 0.0 }
            })
            .collect();
        let mut grid = OccupancyGrid::new(r, 1.0, 0.5);
        grid.update(&density, 1.0);
        grid
    }

    /// Compare both marchings (unjittered and jittered), sample for sample, bit for bit.
    fn assert_same_samples(grid: &OccupancyGrid, rays: &Rays, near: f32, far: f32, steps: usize, what: &str) -> PackedSamples {
        let n = rays.len();
        let fast = occupied_samples(grid, rays, near, far, steps, None);
        assert!(fast == every_interval(grid, rays, near, far, steps, &vec![0.5; n]), "{what}: middles differ");
        let jittered = occupied_samples(grid, rays, near, far, steps, Some(&mut Rng::new(11)));
        let mut rng = Rng::new(11);
        let shifts: Vec<f32> = (0..n).map(|_| rng.uniform()).collect();
        let reference = every_interval(grid, rays, near, far, steps, &shifts);
        for r in 0..n {
            assert_eq!(&jittered.t[jittered.ray(r)], &reference.t[reference.ray(r)], "{what}: jittered ray {r} {:?} {:?}", rays.origins[r], rays.directions[r]);
        }
        assert!(jittered == reference, "{what}: jittered deltas or offsets differ");
        fast
    }

    fn rays(list: Vec<([f32; 3], [f32; 3])>) -> Rays {
        Rays { origins: list.iter().map(|r| r.0).collect(), directions: list.iter().map(|r| r.1).collect(), viewdirs: None }
    }

    #[test]
    fn skipping_marches_the_same_samples_as_every_interval_on_random_rays() {
        for seed in 0..3 {
            let grid = sparse_grid(seed);
            let mut rng = Rng::new(100 + seed);
            let mut u = move || rng.uniform() * 2.0 - 1.0;
            // From a sphere of radius 3 towards points in [−1.2, 1.2]³ (some miss the box);
            // from inside the box too (near 0: the first samples may be occupied).
            let list: Vec<_> = (0..1500)
                .map(|i| {
                    let target = [u() * 1.2, u() * 1.2, u() * 1.2];
                    let origin = if i % 3 == 0 { [u() * 0.9, u() * 0.9, u() * 0.9] } else { [u() * 3.0, u() * 3.0, 3.0] };
                    let scale = 0.5 + u().abs();
                    (origin, std::array::from_fn(|a| (target[a] - origin[a]) * scale))
                })
                .collect();
            let fast = assert_same_samples(&grid, &rays(list), 0.0, 6.0, 2048, &format!("seed {seed}"));
            assert!(fast.t.len() > 5_000, "seed {seed}: {} samples: the rays see occupied cells", fast.t.len());
        }
    }

    #[test]
    fn skipping_marches_the_same_samples_on_rays_along_cell_faces_edges_and_corners() {
        let grid = sparse_grid(7);
        let cell = 1.0 / 16.0;
        let mut list = Vec::new();
        let mut rng = Rng::new(5);
        for _ in 0..600 {
            // A lattice point (a cell corner) and an axis-parallel, face-diagonal or body-diagonal
            // direction through it: rays along faces and edges, through edges and corners.
            let corner: [f32; 3] = std::array::from_fn(|_| -1.0 + rng.below(33) as f32 * cell);
            let pattern = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 0.0], [0.0, 1.0, -1.0], [1.0, -1.0, 1.0], [0.5, 1.0, 0.0], [1.0, 2.0, -1.0]];
            let d = pattern[rng.below(pattern.len())].map(|v| v * (0.5 + rng.uniform()));
            // Start 2 units back along the ray, so it crosses the box's outside first.
            let origin: [f32; 3] = std::array::from_fn(|a| corner[a] - 2.0 * d[a]);
            list.push((origin, d));
            // The same line nudged off the lattice by one ulp and by a little more.
            list.push((origin.map(|v| f32::from_bits(v.to_bits() + 1)), d));
            list.push((origin.map(|v| v + 1e-6), d));
        }
        // Starting on a face inside the box, with near 0.
        for _ in 0..200 {
            let origin: [f32; 3] = std::array::from_fn(|_| -1.0 + (1 + rng.below(31)) as f32 * cell);
            let d = [rng.uniform() - 0.5, 0.0, rng.uniform() - 0.5];
            list.push((origin, d));
        }
        let fast = assert_same_samples(&grid, &rays(list), 0.0, 6.0, 2048, "lattice rays");
        assert!(fast.t.len() > 10_000, "{} samples: the rays see occupied cells", fast.t.len());
        // Rays along x hugging a plane y = const of the lattice, crossing it at a tiny slope
        // inside the box, over stripes of cells occupied where j + k is even: rounding moves the
        // computed samples across the plane up to tens of steps from where the exact line does.
        let mut striped = OccupancyGrid::new(32, 1.0, 0.5);
        striped.update(&(0..32 * 32 * 32).map(|c| if ((c / 32) % 32 + c % 32) % 2 == 0 { 1.0 } else { 0.0 }).collect::<Vec<_>>(), 1.0);
        let list = (0..1000)
            .map(|_| {
                let plane = -1.0 + (1 + rng.below(31)) as f32 * cell;
                let offset = (rng.uniform() - 0.5) * 6e-7;
                let crossing = 1.2 + 1.6 * rng.uniform();
                let z = -1.0 + (rng.below(32) as f32 + 0.5) * cell;
                ([-2.0, plane + offset, z], [1.0, -offset / crossing, 0.0])
            })
            .collect();
        let fast = assert_same_samples(&striped, &rays(list), 0.0, 6.0, 2048, "rays hugging a plane");
        assert!(fast.t.len() > 100_000, "{} samples: the rays see occupied cells", fast.t.len());
    }

    #[test]
    fn skipping_handles_rays_missing_the_box_and_degenerate_rays() {
        let grid = sparse_grid(2);
        let list = vec![
            ([-3.0, 1.5, 0.0], [1.0, 0.0, 0.0]),         // parallel to the box, above it
            ([-3.0, 1.0, 0.0], [1.0, 0.0, 0.0]),         // along its top face
            ([3.0, 3.0, 3.0], [1.0, 1.0, 1.0]),          // away from it
            ([-3.0, 0.1, 0.2], [0.0, 0.0, 0.0]),         // no direction
            ([-3.0, 0.1, 0.2], [f32::NAN, 0.0, 0.0]),    // not a number
            ([-3.0, 0.1, 0.2], [f32::INFINITY, 1.0, 0.0]),
        ];
        let fast = assert_same_samples(&grid, &rays(list), 0.0, 6.0, 512, "degenerate rays");
        assert!(fast.t.is_empty());
        // far < near (a negative interval) and near = far fall back to testing every interval.
        // Along x through the centre of an occupied cell.
        let c = (0..grid.len()).find(|&c| grid.is_cell_occupied(c)).unwrap();
        let centre = |i: usize| -1.0 + (i as f32 + 0.5) / 16.0;
        let one = rays(vec![([-2.0, centre((c / 32) % 32), centre(c % 32)], [1.0, 0.0, 0.0])]);
        assert!(!every_interval(&grid, &one, 0.0, 6.0, 64, &[0.5]).t.is_empty(), "the ray sees the grid");
        for (near, far) in [(6.0, 0.0), (2.0, 2.0)] {
            assert!(occupied_samples(&grid, &one, near, far, 64, None) == every_interval(&grid, &one, near, far, 64, &[0.5]), "near {near} far {far}");
        }
    }

    #[test]
    fn contracted_marching_steps_grow_four_times_a_segment() {
        // 1024 steps → segments of 256; the first interval 2/256; starts 0.1, 2.1, 10.1, 42.1,
        // 170.1 (the next, 682.1, lies past far = 200).
        let segments = march_segments(0.1, 200.0, 1024, Some(Contraction::Linf));
        let intervals: Vec<f32> = segments.iter().map(|s| s.interval).collect();
        assert_eq!(intervals, [0.0078125, 0.03125, 0.125, 0.5, 2.0]);
        for (s, start) in segments.iter().zip([0.1, 2.1, 10.1, 42.1, 170.1]) {
            assert!((s.start - start).abs() < 1e-4 && s.steps == 256, "{s:?}");
        }
        assert_eq!(march_segments(0.1, 200.0, 1024, None), [Segment { start: 0.1, interval: (200.0 - 0.1) / 1024.0, steps: 1024 }]);
        assert_eq!(march_segments(0.0, f32::INFINITY, 2, Some(Contraction::Linf)).len(), MAX_SEGMENTS);
        assert_eq!(march_segments(0.0, f32::NAN, 8, Some(Contraction::Linf)).len(), 1);
    }

    /// 32³ cells over the contracted cube ±2: occupied cells in a third of the 4³-cell blocks,
    /// a fifth of those blocks' cells, so the inner cube and the shell both hold empty blocks.
    fn sparse_contracted_grid(seed: u64) -> OccupancyGrid {
        let mut rng = Rng::new(seed);
        let r = 32;
        let density: Vec<f32> = (0..r * r * r).map(|_| rng.uniform()).collect();
        let blocks: Vec<bool> = (0..512).map(|_| rng.uniform() < 0.35).collect();
        let density: Vec<f32> = density
            .iter()
            .enumerate()
            .map(|(c, &u)| {
                let b = ((c / (r * r) / 4) * 8 + (c / r) % r / 4) * 8 + c % r / 4;
                if blocks[b] && u < 0.2 { 1.0 } else { 0.0 }
            })
            .collect();
        let mut grid = OccupancyGrid::new(r, 2.0, 0.5).with_contraction(Some(Contraction::Linf));
        grid.update(&density, 1.0);
        grid
    }

    #[test]
    fn contracted_skipping_marches_the_same_samples_as_every_interval() {
        for seed in 0..2 {
            let grid = sparse_contracted_grid(seed);
            let mut rng = Rng::new(200 + seed);
            let mut u = move || rng.uniform() * 2.0 - 1.0;
            // Cameras inside the inner cube looking anywhere, and from far outside it.
            let list: Vec<_> = (0..800)
                .map(|i| {
                    let origin = if i % 4 == 0 { [u() * 30.0, u() * 30.0, u() * 30.0] } else { [u(), u(), u()] };
                    (origin, [u(), u(), u()].map(|v| v * 1.3))
                })
                .collect();
            let fast = assert_same_samples(&grid, &rays(list), 0.05, 200.0, 256, &format!("contracted seed {seed}"));
            assert!(fast.t.len() > 10_000, "{} samples", fast.t.len());
            let far = fast.t.iter().filter(|&&t| t > 10.0).count();
            assert!(far > 1_000, "{far} samples past t = 10: the shell is marched");
        }
        // Rays along the inner cube's faces and through its edges, where the skipping stops.
        let grid = sparse_contracted_grid(5);
        let list = vec![
            ([-0.5, 1.0, 0.2], [1.0, 0.0, 0.0]),
            ([1.0, 1.0, -3.0], [0.0, 0.0, 1.0]),
            ([0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
            ([0.999, -0.3, 0.0], [0.001, 0.0, -1.0]),
            ([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
        ];
        assert_same_samples(&grid, &rays(list), 0.05, 200.0, 512, "contracted faces");
    }

    #[test]
    fn contracted_skipping_tests_fewer_steps_inside_the_inner_cube() {
        // One occupied cell of 32³ over ±2 (its centre at 0.0625 per axis), rays through it
        // from inside the inner cube: empty cubes are jumped inside it, each step tested beyond.
        let r = 32;
        let mut density = vec![0.0; r * r * r];
        density[(16 * r + 16) * r + 16] = 1.0;
        let mut grid = OccupancyGrid::new(r, 2.0, 0.5).with_contraction(Some(Contraction::Linf));
        grid.update(&density, 1.0);
        let skipper = Skipper::new(&grid);
        let segments = march_segments(0.0, 10.0, 1024, grid.contraction());
        let total: usize = segments.iter().map(|s| s.steps).sum();
        let (mut tested, mut samples) = (0, Vec::new());
        for i in 0..50 {
            let s = i as f32 / 50.0;
            tested += march_ray(&skipper, &segments, [-0.9, 0.07, 0.07 + 0.01 * s], [1.0, 0.0, 0.0], s, &mut |t, _, _| samples.push(t));
        }
        assert!(samples.len() >= 50 * 10, "{} samples", samples.len());
        // Segment 0: 256 steps over t ∈ [0, 2], x from −0.9 to 1.1 (243 inside the inner cube,
        // 13 past it); segment 1: 256 steps, all in the shell, each tested. Of the 243 inside,
        // fewer than 100 are tested.
        assert_eq!(total, 512);
        assert!(tested < 50 * (256 + 13 + 100), "{tested} tests for 50 rays of {total} steps");
        assert!(tested >= 50 * (256 + 13), "{tested}: the shell's steps are each tested");
    }

    #[test]
    fn skipping_tests_far_fewer_steps_on_a_mostly_empty_grid() {
        // One occupied cell in a 64³ grid at the centre; rays through it from outside.
        let r = 64;
        let mut density = vec![0.0; r * r * r];
        density[(32 * r + 32) * r + 32] = 1.0;
        let mut grid = OccupancyGrid::new(r, 1.0, 0.5);
        grid.update(&density, 1.0);
        let skipper = Skipper::new(&grid);
        let (steps, mut tested, mut samples) = (2048, 0, Vec::new());
        let segments = march_segments(0.0, 6.0, steps, None);
        for i in 0..100 {
            let s = i as f32 / 100.0;
            tested += march_ray(&skipper, &segments, [-3.0, 0.01 + 0.001 * s, 0.02], [1.0, 0.0, 0.001 * s], s, &mut |t, _, _| samples.push(t));
        }
        // Each ray has ~ 680 steps in the box: one occupied cell (~ 11 steps), and empty cubes of
        // up to 17 cells a side before and after it, each skipped with one test.
        assert!(samples.len() >= 100 * 10, "{} samples", samples.len());
        assert!(tested < 100 * 50, "{tested} occupancy tests for 100 rays of {steps} steps");
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

    /// A faint fog coloured as the ball, recording each call's points.
    struct Recorded(Vec<Vec<[f32; 3]>>);

    impl Field for Recorded {
        type Error = std::convert::Infallible;
        fn evaluate(&mut self, stage: Stage, points: &[[f32; 3]], dirs: &[[f32; 3]]) -> Result<FieldOutput, Self::Error> {
            self.0.push(points.to_vec());
            let mut out = Ball(0).evaluate(stage, points, dirs)?;
            // A faint fog instead of the ball: rays take several rounds to stop.
            out.sigma.iter_mut().for_each(|s| *s = 3.0);
            Ok(out)
        }
    }

    #[test]
    fn rounds_make_the_same_calls_and_pixels_as_marching_every_sample_first() {
        // The precomputed path: every sample first, then `march_front_to_back` over them.
        // Half the cells occupied, at random.
        let mut rng = Rng::new(9);
        let mut grid = OccupancyGrid::new(32, 1.0, 0.5);
        grid.update(&(0..grid.len()).map(|_| if rng.uniform() < 0.5 { 1.0 } else { 0.0 }).collect::<Vec<_>>(), 1.0);
        let mut u = move || rng.uniform() * 2.0 - 1.0;
        let list: Vec<_> = (0..1500)
            .map(|_| {
                let origin = [u() * 3.0, u() * 3.0, 3.0];
                let target = [u() * 0.6, u() * 0.6, u() * 0.6];
                (origin, std::array::from_fn(|a| target[a] - origin[a]))
            })
            .collect();
        let rays = rays(list);
        let sampling = SamplingConfig { near: 0.5, far: 6.0, n_coarse: 64, n_fine: 0, ..Default::default() };
        for (min_transmittance, white_background) in [(Some(1e-4), true), (Some(0.3), false), (None, true)] {
            let options = RenderOptions { sampling: sampling.clone(), white_background, chunk: 1500, min_transmittance, march_steps: 1024, overlap: false };
            let samples = occupied_samples(&grid, &rays, 0.5, 6.0, 1024, None);
            let mut before = Recorded(Vec::new());
            let expected = march_front_to_back(&mut before, Stage::Coarse, &rays, &rays.view_directions(), &samples, min_transmittance.unwrap_or(0.0), white_background).unwrap();
            let mut after = Recorded(Vec::new());
            let got = render_rays(&mut after, &grid, &rays, &options).unwrap();
            assert_eq!(got, expected.rays, "{min_transmittance:?}: pixels");
            // Overlapped: half the rays per call, the same samples and pixels.
            let mut halves = Recorded(Vec::new());
            let overlapped = render_rays(&mut halves, &grid, &rays, &RenderOptions { overlap: true, ..options.clone() }).unwrap();
            assert_eq!(overlapped, expected.rays, "{min_transmittance:?}: overlapped pixels");
            let points = |calls: &[Vec<[f32; 3]>]| {
                let mut all: Vec<[u32; 3]> = calls.iter().flatten().map(|p| p.map(f32::to_bits)).collect();
                all.sort_unstable();
                all
            };
            assert!(points(&halves.0) == points(&before.0), "{min_transmittance:?}: the same points evaluated");
            assert!(halves.0.iter().all(|c| c.len() <= 750 * MARCH_SEGMENT) && halves.0.len() > before.0.len(), "halves per call");
            // Rounds may end with a call of no points (rays whose last segment was full).
            let calls: Vec<_> = after.0.into_iter().filter(|c| !c.is_empty()).collect();
            assert!(calls == before.0, "{min_transmittance:?}: {} calls against {}", calls.len(), before.0.len());
            if min_transmittance != Some(0.3) {
                assert!(before.0.len() > 3 && samples.t.len() > 20_000, "the rays see occupied cells over several rounds: {} calls, {} samples", before.0.len(), samples.t.len());
            } else {
                let evaluated: usize = calls.iter().map(Vec::len).sum();
                assert!(evaluated * 5 < samples.t.len() * 3, "stopping early: {evaluated} of {} samples evaluated", samples.t.len());
            }
        }
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
            overlap: false,
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
