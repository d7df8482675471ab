// The marched render path's per-sample loops in WebAssembly (AssemblyScript, built into
// src/wasm.gen.ts by scripts/wasm.mjs): marching through the occupancy grid (straight, as
// core/src/render/grid.rs's occupied_samples; contracted, over march_segments), gathering a field
// call's samples, and compositing. The arithmetic is that of the TypeScript it replaced, bit for
// bit (f32 where that used Math.fround, f64 elsewhere); the tests compare the samples with
// testing every interval and the frames with the reference renderer. Why WebAssembly: chromium
// ran these loops as JavaScript at 70–85 ns a sample, against 51 in Node; the loop around the
// field of a lego-ngp frame went from 0.24–0.30 to 0.17–0.18 s (docs/viewer.md, Speed).
//
// Memory is laid out by src/marcher.ts: every array is a byte offset into linear memory,
// handed over once per grid (setGrid: the occupancy and a table of 8 pointers to the octants'
// cube tables, filled as rays first head into an octant) and once per frame (setRays or
// setContractedRays, then setState).

import { contractionFactor } from "./contraction";
import { f32At, f64At, i32At, setF32, setI32 } from "./memory";

// The grid: occupancy bytes (R³), per octant the cube table of cornerReach (R³; 0: not made).
let OCC: usize = 0, CUBES: usize = 0, RES: i32 = 0, BOUND: f32 = 0, CONTRACTED = false;
// The frame's rays: o, d [n, 3]; t of each step [steps]; per ray cursor, end, occupiedUntil
// (i32), the margin of its slab tests (f64; straight grids), its octant (u8).
let O: usize = 0, D: usize = 0, STEP_T: usize = 0, CURSOR: usize = 0, END: usize = 0, UNTIL: usize = 0, MARGIN: usize = 0, OCTANT: usize = 0;
let NEAR: f64 = 0, INTERVAL: f64 = 0, STEPS: i32 = 0;
// Contracted grids: each step's interval [steps]; per segment its first step ([segments + 1],
// the last the number of steps), start, interval (f32) and steps.
let STEP_INTERVAL: usize = 0, FIRST: usize = 0, SEG_START: usize = 0, SEG_INTERVAL: usize = 0, SEG_STEPS: usize = 0, SEGMENTS: i32 = 0;
/** Steps tested since the last setRays (the work skipping saves). */
export let tested: f64 = 0;

/** An occupied cell's bit in a cube table's value (march.ts's OCCUPIED_CUBE). */
const OCCUPIED_CUBE: i32 = 0x80;

/** The grid every later frame marches: occupancy.bin's cells at `occ` (R³ bytes), `cubes` 8
 *  pointers to cube tables (march.ts's cornerReach; 0 until made), `contracted` for NERFOCC2. */
export function setGrid(occ: usize, cubes: usize, res: i32, bound: f32, contracted: bool): void {
  OCC = occ; CUBES = cubes; RES = res; BOUND = bound; CONTRACTED = contracted;
}

/** The octant (dx, dy, dz) heads into: bit 2 set where x grows, bit 1 y, bit 0 z (march.ts's octantOf). */
@inline function octantOf(dx: f32, dy: f32, dz: f32): i32 {
  return (dx > 0 ? 4 : 0) | (dy > 0 ? 2 : 0) | (dz > 0 ? 1 : 0);
}

/** A straight grid's frame: rays o, d [n, 3] (pointers), `steps` equal intervals from `near`.
 *  Fills t, and per ray its octant, margin, cursor and end (the caller has made the cube tables
 *  of the octants the rays head into). */
export function setRays(n: i32, o: usize, d: usize, t: usize, cursor: usize, end: usize, until: usize, margin: usize,
  octant: usize, near: f64, interval: f64, steps: i32): void {
  O = o; D = d; STEP_T = t; CURSOR = cursor; END = end; UNTIL = until; MARGIN = margin; OCTANT = octant;
  NEAR = near; INTERVAL = interval; STEPS = steps; tested = 0;
  const fn = <f32>near, fi = <f32>interval;
  for (let k = 0; k < steps; k++) setF32(t, k, fn + <f32>(<f64>k + 0.5) * fi);
  const bd = <f64>BOUND, R = RES, cellSide: f64 = (2 * bd) / <f64>R;
  for (let r = 0; r < n; r++) {
    const ox = <f64>f32At(o, 3 * r), oy = <f64>f32At(o, 3 * r + 1), oz = <f64>f32At(o, 3 * r + 2);
    const dx = f32At(d, 3 * r), dy = f32At(d, 3 * r + 1), dz = f32At(d, 3 * r + 2);
    store<u8>(octant + <usize>r, <u8>octantOf(dx, dy, dz));
    setI32(until, r, 0);
    const m = marginOf(r, near, interval, steps);
    store<f64>(margin + (<usize>r << 3), m);
    if (isNaN(m)) { setI32(cursor, r, 0); setI32(end, r, steps); continue; }
    const ddx = <f64>dx, ddy = <f64>dy, ddz = <f64>dz;
    const lo = -bd - m, hi = -bd + <f64>R * cellSide + m;
    // The slab test against the grid's box grown by the margin.
    let enter: f64 = -Infinity, leave: f64 = Infinity, miss = false;
    if (ddx == 0) { if (ox < lo || ox > hi) miss = true; }
    else { const u = (lo - ox) / ddx, v = (hi - ox) / ddx; enter = max(enter, min(u, v)); leave = min(leave, max(u, v)); }
    if (ddy == 0) { if (oy < lo || oy > hi) miss = true; }
    else { const u = (lo - oy) / ddy, v = (hi - oy) / ddy; enter = max(enter, min(u, v)); leave = min(leave, max(u, v)); }
    if (ddz == 0) { if (oz < lo || oz > hi) miss = true; }
    else { const u = (lo - oz) / ddz, v = (hi - oz) / ddz; enter = max(enter, min(u, v)); leave = min(leave, max(u, v)); }
    if (miss || enter > leave) { setI32(cursor, r, 0); setI32(end, r, 0); continue; }
    setI32(cursor, r, stepAt(enter, -1));
    setI32(end, r, stepAt(leave, 1));
  }
}

/** grid.rs's margin of ray r's slab tests over `steps` intervals of `interval` from `start` (a
 *  straight grid's march, or a segment of a contracted one): far above the f32 error of a
 *  step's t and position there. NaN: those steps are tested one by one (non-finite inputs). */
function marginOf(r: i32, start: f64, interval: f64, steps: i32): f64 {
  let sum: f64 = 0;
  for (let a = 0; a < 3; a++) sum += <f64>f32At(O, 3 * r + a);
  for (let a = 0; a < 3; a++) sum += <f64>f32At(D, 3 * r + a);
  if (!isFinite(sum + start) || !(interval > 0) || !isFinite(interval)) return NaN;
  // The largest coordinate magnitude a sample reaches bounds its rounding error.
  const tMax = max(abs(<f64>(<f32>start + <f32>(<f64>steps + 0.5) * <f32>interval)), abs(start));
  let scale = <f64>BOUND;
  for (let a = 0; a < 3; a++) scale = max(scale, abs(<f64>f32At(O, 3 * r + a)) + tMax * abs(<f64>f32At(D, 3 * r + a)));
  return 1e-3 * ((2 * <f64>BOUND) / <f64>RES) + 64 * 1.1920928955078125e-7 * scale;
}

/** The first step whose exact t is at or after `t`, moved by `by`, clamped to 0..=steps. */
function stepAt(t: f64, by: i32): i32 {
  const k = Math.ceil((t - NEAR) / INTERVAL - 0.5) + <f64>by;
  return k >= <f64>STEPS ? STEPS : k > 0 ? <i32>k : 0;
}

/** Ray r's next (at most `limit`) occupied samples through a straight grid: positions into
 *  pts[3·at…], step indices into ks[at…]; returns how many (fewer than `limit`: none left).
 *  march.ts's former RayMarch.next: slab tests against the largest cube of cells in the tested
 *  cell's state (cornerReach), shrunk by the ray's margin; the steps up to its exit skipped
 *  (empty) or emitted untested (occupied). */
function nextStraight(r: i32, limit: i32, pts: usize, ks: usize, at: i32): i32 {
  const R = RES, Rf = <f64>R, Rs = <f32>R, b = BOUND, bd = <f64>b, two: f32 = 2 * b;
  const ox = f32At(O, 3 * r), oy = f32At(O, 3 * r + 1), oz = f32At(O, 3 * r + 2);
  const dx = f32At(D, 3 * r), dy = f32At(D, 3 * r + 1), dz = f32At(D, 3 * r + 2);
  const oxd = <f64>ox, oyd = <f64>oy, ozd = <f64>oz;
  // Reciprocals: the slab's t differ from grid.rs's quotients by an ulp of f64, far inside the margin.
  const ix: f64 = 1 / <f64>dx, iy: f64 = 1 / <f64>dy, iz: f64 = 1 / <f64>dz;
  const margin = f64At(MARGIN, r), skip = !isNaN(margin);
  // The box faces' constant parts: the grid's low corner, moved in by the margin.
  const lo0 = -bd + margin, hi0 = -bd - margin, perInterval: f64 = 1 / INTERVAL;
  // Cells per unit, and how near a cell face the f64 u may not decide the cell (2⁻²⁰·R: 16
  // times the f32 error of u < R).
  const perCell: f64 = Rf / <f64>two, faceGap: f64 = Rf * 9.5367431640625e-7;
  const q = <i32>load<u8>(OCTANT + <usize>r), cubes = <usize>load<u32>(CUBES + (<usize>q << 2));
  const side: f64 = (2 * bd) / Rf, near = NEAR, steps = STEPS, stepsF = <f64>steps;
  const upX = q & 4, upY = q & 2, upZ = q & 1;
  let k = i32At(CURSOR, r), n = 0, nt = 0, occupiedUntil = i32At(UNTIL, r);
  const end = i32At(END, r);
  while (k < end && n < limit) {
    if (k < occupiedUntil) {
      // The steps left in the occupied cube of the last test, emitted untested.
      const stop = min(min(occupiedUntil, end), k + limit - n);
      let p = at + n;
      n += stop - k;
      for (; k < stop; k++, p++) {
        const tk = f32At(STEP_T, k);
        setF32(pts, 3 * p, ox + tk * dx); setF32(pts, 3 * p + 1, oy + tk * dy); setF32(pts, 3 * p + 2, oz + tk * dz);
        setI32(ks, p, k);
      }
      continue;
    }
    const tk = f32At(STEP_T, k);
    const x: f32 = ox + tk * dx, y: f32 = oy + tk * dy, z: f32 = oz + tk * dz;
    nt++;
    // The cell is that of the f32 u = (x + b)/2b·R. In f64 with a multiplication u is off by at
    // most a few f32 ulps (3·2⁻²⁴ relative), so where it lies farther than `faceGap` from every
    // cell face its floor is the f32 u's; only the rare step that close to a face (or NaN, or
    // outside) takes the f32 operations themselves.
    const su = (<f64>x + bd) * perCell, sv = (<f64>y + bd) * perCell, sw = (<f64>z + bd) * perCell;
    const fi = Math.floor(su), fj = Math.floor(sv), fl = Math.floor(sw);
    let i: i32, j: i32, l: i32;
    if (su - fi > faceGap && fi + 1 - su > faceGap && sv - fj > faceGap && fj + 1 - sv > faceGap && sw - fl > faceGap && fl + 1 - sw > faceGap
      && fi >= 0 && fi < Rf && fj >= 0 && fj < Rf && fl >= 0 && fl < Rf) {
      i = <i32>fi; j = <i32>fj; l = <i32>fl;
    } else {
      const u: f32 = ((x + b) / two) * Rs, v: f32 = ((y + b) / two) * Rs, w: f32 = ((z + b) / two) * Rs;
      if (!(u >= 0 && u < Rs && v >= 0 && v < Rs && w >= 0 && w < Rs)) { k++; continue; }
      i = <i32>u; j = <i32>v; l = <i32>w; // floor: 0 ≤ u < R
    }
    const c = (i * R + j) * R + l;
    const occupied = load<u8>(OCC + <usize>c) != 0;
    if (occupied) {
      const p = at + n;
      setF32(pts, 3 * p, x); setF32(pts, 3 * p + 1, y); setF32(pts, 3 * p + 2, z);
      setI32(ks, p, k); n++;
    }
    if (!skip) { k++; continue; }
    // Jump to where the ray leaves the cube of cells in this cell's state from the cell on,
    // reaching along the ray, shrunk by the margin (a slab test written out per axis).
    const e = (<i32>load<u8>(cubes + <usize>c) & ~OCCUPIED_CUBE) - 1;
    const lx = lo0 + <f64>(upX ? i : i - e) * side, hx = hi0 + <f64>(upX ? i + e + 1 : i + 1) * side;
    const ly = lo0 + <f64>(upY ? j : j - e) * side, hy = hi0 + <f64>(upY ? j + e + 1 : j + 1) * side;
    const lz = lo0 + <f64>(upZ ? l : l - e) * side, hz = hi0 + <f64>(upZ ? l + e + 1 : l + 1) * side;
    let enter: f64 = -Infinity, leave: f64 = Infinity;
    if (dx == 0) { if (oxd < lx || oxd > hx) leave = -Infinity; }
    else { const a = (lx - oxd) * ix, a2 = (hx - oxd) * ix; enter = min(a, a2); leave = max(a, a2); }
    if (dy == 0) { if (oyd < ly || oyd > hy) leave = -Infinity; }
    else { const a = (ly - oyd) * iy, a2 = (hy - oyd) * iy; enter = max(enter, min(a, a2)); leave = min(leave, max(a, a2)); }
    if (dz == 0) { if (ozd < lz || ozd > hz) leave = -Infinity; }
    else { const a = (lz - ozd) * iz, a2 = (hz - ozd) * iz; enter = max(enter, min(a, a2)); leave = min(leave, max(a, a2)); }
    // Every step whose exact t is before the exit lies inside the shrunk cube, so in the cube;
    // the jump lands on the first step at or after the exit (grid.rs lands one step short; not
    // needed here: a step's f32 t and position are off the exact ones by far less than the margin).
    const tkd = <f64>tk, inside = enter <= tkd && tkd <= leave;
    const kl: f64 = inside ? Math.ceil((leave - near) * perInterval - 0.5) : 0;
    if (occupied) {
      occupiedUntil = kl < stepsF ? <i32>kl : steps;
      k++;
    } else k = kl > <f64>(k + 1) ? (kl < stepsF ? <i32>kl : steps) : k + 1;
  }
  setI32(CURSOR, r, k);
  setI32(UNTIL, r, occupiedUntil);
  tested += <f64>nt;
  return n;
}

/** A contracted grid's frame (nerf-rs-scene-3): rays o, d [n, 3] marched along `segments`
 *  segments (start and interval f32, steps i32 each: contraction.ts's marchSegments). Fills t
 *  and the interval of every step, each segment's first step, and per ray its octant, cursor (0)
 *  and end (every step), as setRays. */
export function setContractedRays(n: i32, o: usize, d: usize, segStart: usize, segInterval: usize, segSteps: usize, segments: i32,
  t: usize, stepInterval: usize, first: usize, cursor: usize, end: usize, until: usize, octant: usize): void {
  O = o; D = d; STEP_T = t; CURSOR = cursor; END = end; UNTIL = until; OCTANT = octant; MARGIN = 0; NEAR = 0; INTERVAL = 0;
  STEP_INTERVAL = stepInterval; FIRST = first; SEG_START = segStart; SEG_INTERVAL = segInterval; SEG_STEPS = segSteps; SEGMENTS = segments;
  tested = 0;
  let k = 0;
  for (let s = 0; s < segments; s++) {
    setI32(first, s, k);
    const start = f32At(segStart, s), interval = f32At(segInterval, s), steps = i32At(segSteps, s);
    // grid.rs's March::t, in f32.
    for (let j = 0; j < steps; j++, k++) { setF32(t, k, start + <f32>(<f64>j + 0.5) * interval); setF32(stepInterval, k, interval); }
  }
  setI32(first, segments, k);
  STEPS = k;
  for (let r = 0; r < n; r++) {
    store<u8>(octant + <usize>r, <u8>octantOf(f32At(d, 3 * r), f32At(d, 3 * r + 1), f32At(d, 3 * r + 2)));
    setI32(cursor, r, 0); setI32(end, r, k); setI32(until, r, 0);
  }
}

/** The segment holding step k. */
function segmentOf(k: i32): i32 {
  let s = 0;
  while (k >= i32At(FIRST, s + 1) && s + 1 < SEGMENTS) s++;
  return s;
}

/** marginOf segment s. */
function segmentMargin(r: i32, s: i32): f64 {
  return marginOf(r, <f64>f32At(SEG_START, s), <f64>f32At(SEG_INTERVAL, s), i32At(SEG_STEPS, s));
}

/** The first step of segment s whose exact t is at or after `t` (grid.rs's step_at). */
function segmentStepAt(s: i32, t: f64): i32 {
  const start = <f64>f32At(SEG_START, s), interval = <f64>f32At(SEG_INTERVAL, s), steps = i32At(SEG_STEPS, s);
  const x = min(max((t - start) / interval - 0.5, -2), <f64>steps + 2);
  return i32At(FIRST, s) + <i32>min(max(Math.ceil(x), 0), <f64>steps);
}

/** One axis of the cube of `s` cells from cell c reaching up (or down) that axis, cut to the
 *  inner cube's cells [first, end) (a contracted grid over ±b): where o + t·d leaves it shrunk
 *  by `margin` (∞ for d = 0), or NaN when the exact point at `tt` lies outside the shrunk cube
 *  (as in a cell outside the inner cube: no jump). In f64. */
function axisExit(b: f64, side: f64, margin: f64, c: i32, s: i32, up: i32, first: i32, end: i32, o: f64, d: f64, tt: f64): f64 {
  const lo = -b + <f64>max(up ? c : c + 1 - s, first) * side, hi = -b + <f64>min(up ? c + s : c + 1, end) * side;
  const x = o + tt * d;
  if (!(lo + margin <= x && x <= hi - margin)) return NaN;
  return d > 0 ? (hi - margin - o) / d : d < 0 ? (lo + margin - o) / d : Infinity;
}

/** Ray r's next (at most `limit`) occupied samples through a contracted grid, crossing into
 *  later segments (contracted.ts's former ContractedMarch.next): cubes of cells are jumped
 *  through only inside the inner cube |x|∞ ≤ 1, where the contraction leaves points as they
 *  are; beyond it every step is tested, as in Rust. */
function nextContracted(r: i32, limit: i32, pts: usize, ks: usize, at: i32): i32 {
  const R = RES, Rs = <f32>R, b = BOUND, bd = <f64>b, two: f32 = 2 * b, side: f64 = (2 * bd) / <f64>R;
  const end = i32At(END, r), innerFirst = <i32>Math.ceil(<f64>R / 4), innerEnd = <i32>Math.floor((3 * <f64>R) / 4);
  const ox = f32At(O, 3 * r), oy = f32At(O, 3 * r + 1), oz = f32At(O, 3 * r + 2);
  const dx = f32At(D, 3 * r), dy = f32At(D, 3 * r + 1), dz = f32At(D, 3 * r + 2);
  const q = <i32>load<u8>(OCTANT + <usize>r), cubes = <usize>load<u32>(CUBES + (<usize>q << 2));
  let k = i32At(CURSOR, r), n = 0, nt = 0, occupiedUntil = i32At(UNTIL, r);
  let s = segmentOf(k), segmentEnd = i32At(FIRST, s + 1), margin = segmentMargin(r, s);
  while (k < end && n < limit) {
    if (k >= segmentEnd) { s = segmentOf(k); segmentEnd = i32At(FIRST, s + 1); margin = segmentMargin(r, s); }
    const tk = f32At(STEP_T, k);
    const x: f32 = ox + tk * dx, y: f32 = oy + tk * dy, z: f32 = oz + tk * dz;
    if (k < occupiedUntil) {
      const p = at + n;
      setF32(pts, 3 * p, x); setF32(pts, 3 * p + 1, y); setF32(pts, 3 * p + 2, z);
      setI32(ks, p, k); n++; k++;
      continue;
    }
    nt++;
    // The cell of the contracted point (OccupancyGrid::cell_coordinates).
    const sc = contractionFactor(x, y, z);
    const u: f32 = ((x * sc + b) / two) * Rs, v: f32 = ((y * sc + b) / two) * Rs, w: f32 = ((z * sc + b) / two) * Rs;
    if (!(u >= 0 && u < Rs && v >= 0 && v < Rs && w >= 0 && w < Rs)) { k++; continue; }
    const i = <i32>u, j = <i32>v, l = <i32>w; // floor: 0 ≤ u < R
    const c = (i * R + j) * R + l, occupied = load<u8>(OCC + <usize>c) != 0;
    if (occupied) {
      const p = at + n;
      setF32(pts, 3 * p, x); setF32(pts, 3 * p + 1, y); setF32(pts, 3 * p + 2, z);
      setI32(ks, p, k); n++;
    }
    // The steps up to where the exact line leaves the cube of cells in this cell's state from
    // the cell on, reaching along the ray (shrunk by the margin), share its state: emitted
    // untested, or skipped. NaN: no jump.
    const s3 = <i32>load<u8>(cubes + <usize>c) & ~OCCUPIED_CUBE, tkd = <f64>tk;
    const exit = isNaN(margin) ? NaN : min(min(axisExit(bd, side, margin, i, s3, q & 4, innerFirst, innerEnd, <f64>ox, <f64>dx, tkd),
      axisExit(bd, side, margin, j, s3, q & 2, innerFirst, innerEnd, <f64>oy, <f64>dy, tkd)),
      axisExit(bd, side, margin, l, s3, q & 1, innerFirst, innerEnd, <f64>oz, <f64>dz, tkd));
    const run = isNaN(exit) ? k + 1 : segmentStepAt(s, exit);
    if (occupied) { occupiedUntil = run; k++; }
    else k = run > k + 1 ? run : k + 1;
  }
  setI32(CURSOR, r, k);
  setI32(UNTIL, r, occupiedUntil);
  tested += <f64>nt;
  return n;
}

/** Ray r's next (at most `limit`) occupied samples, through the grid of setGrid along the rays
 *  of setRays or setContractedRays: positions into pts[3·at…] and step indices into ks[at…]
 *  (pointers); returns how many. Fewer than `limit` means the ray has none left. */
export function next(r: i32, limit: i32, pts: usize, ks: usize, at: i32): i32 {
  return CONTRACTED ? nextContracted(r, limit, pts, ks, at) : nextStraight(r, limit, pts, ks, at);
}

// Compositing's state (setState): per ray rgb [n, 3], depth, acc, transmittance, the samples
// composited (i32), |d| and a straight step's length interval·|d|; the view direction [n, 3];
// the ring of rays waiting for samples (queue, n long) and RING = [head, queued, points].
let RGB: usize = 0, DEPTH: usize = 0, ACC: usize = 0, TRANS: usize = 0, DONE: usize = 0, DNORM: usize = 0, STEP_LEN: usize = 0;
let VIEW: usize = 0, QUEUE: usize = 0, RING: usize = 0, RAYS = 0;
let SEGMENT: i32 = 16, MIN_TRANSMITTANCE: f32 = 1e-4;
// One field call's samples: positions, view directions [MAX, 3], steps, the rays and their
// counts in call order, and α (compositing's first pass).
let PTS: usize = 0, DIRS: usize = 0, KS: usize = 0, CALL_RAYS: usize = 0, COUNTS: usize = 0, ALPHAS: usize = 0, MAX_POINTS: i32 = 0;
// expAlpha's table: 2^(i/32) for i in −EXP_STEPS..0 (−EXP_STEPS/32 < −104/ln 2), made by the
// caller (setExpTable) with JavaScript's 2 ** x.
const EXP_STEPS: i32 = 4832;
let EXP_TABLE: usize = 0;

/** expAlpha's table (EXP_STEPS + 1 f64) is at `table`. */
export function setExpTable(table: usize): void { EXP_TABLE = table; }

/** The frame's compositing state and one call's buffers (see above), after setRays or
 *  setContractedRays: zeroes the sums, sets every transmittance to 1, each ray's |d| and step
 *  length, and queues the rays with steps left; returns how many. */
export function setState(rays: i32, rgb: usize, depth: usize, acc: usize, trans: usize, done: usize, dNorm: usize, stepLen: usize,
  view: usize, queue: usize, ring: usize, segment: i32, minTransmittance: f32, pts: usize, dirs: usize, ks: usize, callRays: usize,
  counts: usize, alphas: usize, maxPoints: i32): i32 {
  RAYS = rays; RGB = rgb; DEPTH = depth; ACC = acc; TRANS = trans; DONE = done; DNORM = dNorm; STEP_LEN = stepLen; VIEW = view;
  QUEUE = queue; RING = ring; SEGMENT = segment; MIN_TRANSMITTANCE = minTransmittance; PTS = pts; DIRS = dirs; KS = ks;
  CALL_RAYS = callRays; COUNTS = counts; ALPHAS = alphas; MAX_POINTS = maxPoints;
  const interval = <f32>INTERVAL;
  let queued = 0;
  for (let r = 0; r < rays; r++) {
    setF32(rgb, 3 * r, 0); setF32(rgb, 3 * r + 1, 0); setF32(rgb, 3 * r + 2, 0);
    setF32(depth, r, 0); setF32(acc, r, 0); setF32(trans, r, 1); setI32(done, r, 0);
    const dn = norm3(f32At(D, 3 * r), f32At(D, 3 * r + 1), f32At(D, 3 * r + 2));
    setF32(dNorm, r, dn); setF32(stepLen, r, interval * dn);
    if (i32At(CURSOR, r) < i32At(END, r)) setI32(queue, queued++, r);
  }
  setI32(ring, 0, 0); setI32(ring, 1, queued); setI32(ring, 2, 0);
  return queued;
}

/** |(x, y, z)| in f32 as camera.ts's norm3 (squares summed in f32, the root rounded). */
@inline function norm3(x: f32, y: f32, z: f32): f32 {
  return <f32>Math.sqrt(<f64>(x * x + y * y + z * z));
}

/** Gather the next occupied samples of as many queued rays as fit in one field call (each at
 *  most `chunk`, MAX_POINTS in all) into the call's buffers; rays with no samples left leave
 *  the queue. Returns how many rays; RING[2] the samples. */
export function gather(chunk: i32): i32 {
  const n = RAYS;
  let m = 0, batch = 0, head = i32At(RING, 0), queued = i32At(RING, 1);
  while (queued > 0 && m + chunk <= MAX_POINTS) {
    const r = i32At(QUEUE, head);
    head = head + 1 == n ? 0 : head + 1; queued--;
    const c = next(r, chunk, PTS, KS, m);
    if (c == 0) continue; // no samples left: done
    const vx = f32At(VIEW, 3 * r), vy = f32At(VIEW, 3 * r + 1), vz = f32At(VIEW, 3 * r + 2);
    for (let p = m; p < m + c; p++) { setF32(DIRS, 3 * p, vx); setF32(DIRS, 3 * p + 1, vy); setF32(DIRS, 3 * p + 2, vz); }
    setI32(CALL_RAYS, batch, r); setI32(COUNTS, batch, c); batch++; m += c;
  }
  setI32(RING, 0, head); setI32(RING, 1, queued); setI32(RING, 2, m);
  return batch;
}

// ln 2 / 32 in two parts (fdlibm's ln2_hi, exact in a product with |n| < 2²¹, and ln2_lo).
const LN2_32_HI: f64 = 6.93147180369123816490e-01 / 32, LN2_32_LO: f64 = 1.90821492927058770002e-10 / 32, PER_LN2_32: f64 = 32 / Math.LN2;

/** exp(x) for compositing's x = −σ·δ ≤ 0, within 3e-15 (relative) of Math.exp, which cost
 *  V8 13 ns a sample against 7 for this when compositing was JavaScript: 2^(n/32) from a table
 *  times a degree-5 polynomial of the remainder, |r| < ln 2 / 32. Below −104 the f32 α is 1
 *  either way; anything else (x > 0, NaN) takes Math.exp. */
@inline function expAlpha(x: f64): f64 {
  if (!(x > -104 && x <= 0)) return Math.exp(x);
  const n = <i32>(x * PER_LN2_32 - 0.5); // rounds: x·32/ln 2 ≤ 0
  const r = x - <f64>n * LN2_32_HI - <f64>n * LN2_32_LO;
  return f64At(EXP_TABLE, n + EXP_STEPS) * (1 + r * (1 + r * (0.5 + r * (1.0 / 6 + r * (1.0 / 24 + r / 120)))));
}

/** expAlpha, for the tests. */
export function expAlphaOf(x: f64): f64 { return expAlpha(x); }

/** Composite one field call (`batch` rays as gather left them) given its σ [m] and rgb [m, 3]
 *  (pointers), with RayAccumulator's f32 arithmetic: α of every sample, then each ray's samples
 *  in order; the segment count runs over a ray's occupied samples, and a ray stops after the
 *  segment where its transmittance falls below the threshold, or after its last. The rays that
 *  go on join the queue; returns its length. */
export function composite(sigma: usize, rgb: usize, batch: i32): i32 {
  alphaPass(sigma, batch);
  return sumPass(rgb, batch);
}

function alphaPass(sig: usize, batch: i32): void {
  let p = 0;
  for (let q = 0; q < batch; q++) {
    const r = i32At(CALL_RAYS, q), e = p + i32At(COUNTS, q), len = f32At(STEP_LEN, r), dn = f32At(DNORM, r);
    if (!CONTRACTED) for (; p < e; p++) {
      const x: f32 = -max(f32At(sig, p), <f32>0) * len;
      setF32(ALPHAS, p, <f32>1 - <f32>expAlpha(<f64>x));
    }
    else for (; p < e; p++) {
      const x: f32 = -max(f32At(sig, p), <f32>0) * (f32At(STEP_INTERVAL, i32At(KS, p)) * dn);
      setF32(ALPHAS, p, <f32>1 - <f32>expAlpha(<f64>x));
    }
  }
}

function sumPass(col: usize, batch: i32): i32 {
  const n = RAYS, segment = SEGMENT, minTransmittance = MIN_TRANSMITTANCE;
  const head = i32At(RING, 0);
  let queued = i32At(RING, 1), p = 0;
  for (let q = 0; q < batch; q++) {
    const r = i32At(CALL_RAYS, q), p0 = p, count = i32At(COUNTS, q);
    let T = f32At(TRANS, r), stopped = false, cr = f32At(RGB, 3 * r), cg = f32At(RGB, 3 * r + 1), cb = f32At(RGB, 3 * r + 2);
    let z = f32At(DEPTH, r), a = f32At(ACC, r), nd = i32At(DONE, r);
    // Samples to the end of the ray's current segment (a countdown, not a modulo per sample).
    let toSegmentEnd = segment - (nd % segment);
    for (let c = 0; c < count; c++, p++) {
      const alpha = f32At(ALPHAS, p), w: f32 = alpha * T;
      cr = cr + w * f32At(col, 3 * p); cg = cg + w * f32At(col, 3 * p + 1); cb = cb + w * f32At(col, 3 * p + 2);
      z = z + w * f32At(STEP_T, i32At(KS, p));
      a = a + w;
      T = T * ((<f32>1 - alpha) + <f32>1e-10);
      nd++;
      if (--toSegmentEnd == 0) {
        toSegmentEnd = segment;
        if (T < minTransmittance) { stopped = true; break; }
      }
    }
    setF32(RGB, 3 * r, cr); setF32(RGB, 3 * r + 1, cg); setF32(RGB, 3 * r + 2, cb);
    setF32(DEPTH, r, z); setF32(ACC, r, a); setI32(DONE, r, nd); setF32(TRANS, r, T);
    p = p0 + count;
    // A ray also stops after its last (partial) segment; cursor at the end means no samples left.
    if (!stopped && i32At(CURSOR, r) < i32At(END, r)) { setI32(QUEUE, (head + queued) % n, r); queued++; }
  }
  setI32(RING, 1, queued);
  return queued;
}

/** A white background: each ray's rgb + (1 − acc). */
export function addWhite(): void {
  for (let r = 0; r < RAYS; r++) {
    const bg: f32 = <f32>1 - f32At(ACC, r);
    for (let a = 0; a < 3; a++) setF32(RGB, 3 * r + a, f32At(RGB, 3 * r + a) + bg);
  }
}

/** Where this module's own static data ends: the caller's arrays start above it. */
export function heapBase(): usize { return __heap_base; }
