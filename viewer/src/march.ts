// The samples marching takes, as core/src/render/grid.rs's occupied_samples: `steps` equal
// intervals over [near, far], a sample at each middle, kept where it lies in an occupied cell.
// Space is crossed by slab tests as grid.rs does it (boxes grown or shrunk by a margin far above
// f32 rounding), so the samples are those of testing every interval: at a tested step, the box
// is the largest cube of cells in the cell's state with the cell at its corner, reaching along
// the ray (cornerReach, grid.rs's OccupancyGrid::corner_reach); the steps up to where the ray
// leaves it (shrunk by the margin) are skipped (empty) or emitted untested (occupied). Rays
// march lazily: `next` hands out a ray's next few samples and remembers where it stopped, so a
// ray that terminates early never marches the rest.
// A contracted grid (nerf-rs-scene-3) is marched in segments by contracted.ts.


import { contractionFactor } from "./contraction";

const f = Math.fround;

/** Occupied cells of occupancy.bin: cell (i, j, k) of p is floor((p + b) / 2b · R); outside is empty.
 *  `contracted` (NERFOCC2): p is contracted first (contraction.ts) and b is 2. */
export interface Grid { res: number; bound: number; occupied: Uint8Array; contracted?: boolean }

/** Is point (x, y, z) in an occupied cell? */
export function isOccupied(g: Grid, x: number, y: number, z: number): boolean {
  if (g.contracted) {
    const s = contractionFactor(x, y, z);
    x = f(x * s); y = f(y * s); z = f(z * s);
  }
  const b = f(g.bound), two = f(2 * b), R = g.res;
  const u = f(f(f(x + b) / two) * R), v = f(f(f(y + b) / two) * R), w = f(f(f(z + b) / two) * R);
  if (!(u >= 0 && u < R && v >= 0 && v < R && w >= 0 && w < R)) return false;
  return g.occupied[(Math.floor(u) * R + Math.floor(v)) * R + Math.floor(w)] !== 0;
}

/** The sides (in cells) of the cubes cornerReach records, as grid.rs's CORNER_SIDES (and the
 *  Python package's): each at most doubles the one before. */
export const CORNER_SIDES = [1, 2, 3, 4, 6, 8, 12, 16, 24, 32];
/** The bit of a cornerReach value that marks an occupied cell (the rest is the cube's side). */
export const OCCUPIED_CUBE = 0x80;

const corners = new WeakMap<Grid, (Uint8Array | undefined)[]>();

/** The octant direction (dx, dy, dz) heads into: bit 2 set where x grows, bit 1 y, bit 0 z. */
export function octantOf(dx: number, dy: number, dz: number): number {
  return (dx > 0 ? 4 : 0) | (dy > 0 ? 2 : 0) | (dz > 0 ? 1 : 0);
}

/** Per ray of directions `d` [n, 3], the octant it heads into (octantOf), and per octant its
 *  cubes (cornerReach), made for the octants the rays head into. */
export function raysCubes(g: Grid, d: Float32Array): { octant: Uint8Array; cubes: Uint8Array[] } {
  const n = d.length / 3, octant = new Uint8Array(n), cubes: Uint8Array[] = [];
  for (let r = 0; r < n; r++) {
    const q = (octant[r] = octantOf(d[3 * r], d[3 * r + 1], d[3 * r + 2]));
    cubes[q] ??= cornerReach(g, q);
  }
  return { octant, cubes };
}

/** cornerReach's step along x or y: the R lines of `len` cells from `start` in `cube` (32-bit
 *  words of 4 cells when `len` is a multiple of 4), each ANDed in place with the line `shift`
 *  on (up) or back, a line past the block counting as `past` (in every byte). */
function andLines(cube: Uint8Array, words: Uint32Array | null, start: number, len: number, R: number, shift: number, up: number,
  past: number): void {
  const a = words ?? cube, w = words ? 4 : 1, l = len / w, s0 = start / w, pastAll = words ? past * 0x01010101 : past;
  for (let step = 0; step < R; step++) {
    const m = up ? step : R - 1 - step, partner = up ? m + shift : m - shift, at = s0 + m * l;
    if (partner >= 0 && partner < R) {
      const from = s0 + partner * l;
      for (let i = 0; i < l; i++) a[at + i] &= a[from + i];
    } else for (let i = 0; i < l; i++) a[at + i] &= pastAll;
  }
}

/** grid.rs's OccupancyGrid::corner_reach: for rays heading into `octant`, per cell, the largest
 *  side s of CORNER_SIDES such that the cube of s cells a side with this cell at its corner,
 *  reaching along the octant's directions, is all in the cell's state (all empty, cells past the
 *  grid counting as empty, or all occupied): s, with OCCUPIED_CUBE set for an occupied cell.
 *  Made once per grid and octant (R³ bytes), when a ray first heads into it. By ANDs with the
 *  cube `shift` cells on, one axis at a time (the cube of side + shift is the 8 cubes of side at
 *  c + shift·{0, 1}³), both states at once: bit 0 of a cell stays set while its cube is all
 *  empty, bit 1 while all occupied; 4 cells a 32-bit word where the rows allow. */
export function cornerReach(g: Grid, octant: number): Uint8Array {
  let tables = corners.get(g);
  if (!tables) corners.set(g, (tables = []));
  const made = tables[octant];
  if (made) return made;
  const R = g.res, n = R ** 3, past = 1;
  const cube = new Uint8Array(n), level = new Uint8Array(n);
  for (let c = 0; c < n; c++) cube[c] = g.occupied[c] ? 2 : 1;
  const words = R % 4 === 0 ? new Uint32Array(cube.buffer) : null, levels = words ? new Uint32Array(level.buffer) : null;
  for (let t = 1; t < CORNER_SIDES.length; t++) {
    const shift = CORNER_SIDES[t] - CORNER_SIDES[t - 1];
    for (let axis = 0; axis < 2; axis++) {
      const up = (octant >> (2 - axis)) & 1, len = axis === 0 ? R * R : R;
      for (let start = 0; start < n; start += len * R) andLines(cube, words, start, len, R, shift, up, past);
    }
    // Along z, a row at a time, in place in the order that reads a cell before it is written.
    const keep = Math.max(R - shift, 0);
    if (octant & 1) {
      for (let row = 0; row < n; row += R) {
        for (let k = 0; k < keep; k++) cube[row + k] &= cube[row + k + shift];
        for (let k = keep; k < R; k++) cube[row + k] &= past;
      }
    } else {
      for (let row = 0; row < n; row += R) {
        for (let k = R - 1; k >= R - keep; k--) cube[row + k] &= cube[row + k - shift];
        for (let k = 0; k < R - keep; k++) cube[row + k] &= past;
      }
    }
    // How many sides each cell's cube has passed (a cell's own bit still set: it passed this one).
    if (words && levels) for (let i = 0; i < words.length; i++) { const x = words[i]; levels[i] += (x | (x >>> 1)) & 0x01010101; }
    else for (let c = 0; c < n; c++) level[c] += cube[c] ? 1 : 0;
  }
  const sides = level;
  for (let c = 0; c < n; c++) sides[c] = CORNER_SIDES[level[c]] | (g.occupied[c] ? OCCUPIED_CUBE : 0);
  tables[octant] = sides;
  return sides;
}

// The slab test's result, kept here so the hot loop allocates nothing.
let slabEnter = 0, slabLeave = 0;

/** The t range [slabEnter, slabLeave] over which o + t·d lies in the box [lo, hi] (empty: enter > leave), in f64. */
function slab(ox: number, oy: number, oz: number, dx: number, dy: number, dz: number,
  lx: number, ly: number, lz: number, hx: number, hy: number, hz: number): void {
  let enter = -Infinity, leave = Infinity;
  // Per axis; a zero component keeps that coordinate exactly o (o + t·0 rounds to o). Written
  // out three times: a helper closure would allocate in the hot loop.
  if (dx === 0) { if (ox < lx || ox > hx) { slabEnter = Infinity; slabLeave = -Infinity; return; } }
  else { const u = (lx - ox) / dx, v = (hx - ox) / dx; enter = Math.max(enter, Math.min(u, v)); leave = Math.min(leave, Math.max(u, v)); }
  if (dy === 0) { if (oy < ly || oy > hy) { slabEnter = Infinity; slabLeave = -Infinity; return; } }
  else { const u = (ly - oy) / dy, v = (hy - oy) / dy; enter = Math.max(enter, Math.min(u, v)); leave = Math.min(leave, Math.max(u, v)); }
  if (dz === 0) { if (oz < lz || oz > hz) { slabEnter = Infinity; slabLeave = -Infinity; return; } }
  else { const u = (lz - oz) / dz, v = (hz - oz) / dz; enter = Math.max(enter, Math.min(u, v)); leave = Math.min(leave, Math.max(u, v)); }
  slabEnter = enter; slabLeave = leave;
}

/** t of each step's middle, near + (k + 0.5)·interval in f32, k < steps. A function of its own
 *  for the reason render.ts's alphaPass gives. */
function stepMiddles(near: number, interval: number, steps: number): Float32Array {
  const t = new Float32Array(steps);
  for (let k = 0; k < steps; k++) t[k] = f(near + f(f(k + 0.5) * interval));
  return t;
}

/** What renderMarch asks of a march over every ray: `t[k]` of each step k (over all segments),
 *  `cursor[r]` the next step ray r tests, `end[r]` one past its last, and `next` (see RayMarch). */
export interface Marcher {
  readonly t: Float32Array;
  readonly cursor: Int32Array;
  readonly end: Int32Array;
  tested: number;
  next(r: number, max: number, pts: Float32Array, ks: Int32Array, at: number): number;
}

/** Every ray's march through `grid`: step k samples t[k] = near + (k + 0.5)·interval (in f32);
 *  `cursor[r]` is the next step ray r tests, `end[r]` one past its last. Shapes: o, d [n, 3]. */
export class RayMarch implements Marcher {
  /** t of each step: [steps]. */
  readonly t: Float32Array;
  readonly cursor: Int32Array;
  readonly end: Int32Array;
  /** Per ray: steps before this one lie in the occupied cube of the last step tested. */
  private readonly occupiedUntil: Int32Array;
  /** Steps tested so far, all rays together (the work skipping saves). */
  tested = 0;
  /** Per ray: the margin of its slab tests; NaN where the ray tests every step (non-finite input). */
  private readonly margin: Float64Array;
  /** Per ray: the octant it heads into, and per octant its cubes (raysCubes). */
  private readonly octant: Uint8Array;
  private readonly cubes: Uint8Array[];
  private readonly cellSide: number;

  constructor(private readonly grid: Grid, private readonly o: Float32Array, private readonly d: Float32Array,
    private readonly near: number, private readonly interval: number, private readonly steps: number) {
    const n = o.length / 3;
    this.t = stepMiddles(near, interval, steps);
    this.cursor = new Int32Array(n); this.end = new Int32Array(n); this.margin = new Float64Array(n);
    this.occupiedUntil = new Int32Array(n);
    ({ octant: this.octant, cubes: this.cubes } = raysCubes(grid, d));
    const b = f(grid.bound), R = grid.res;
    this.cellSide = (2 * b) / R;
    // The largest coordinate magnitude a sample reaches bounds its rounding error.
    const tMax = Math.max(Math.abs(f(near + f(f(steps + 0.5) * interval))), Math.abs(near));
    const intervalOk = Number.isFinite(interval) && interval > 0 && Number.isFinite(near);
    for (let r = 0; r < n; r++) {
      const ox = o[3 * r], oy = o[3 * r + 1], oz = o[3 * r + 2], dx = d[3 * r], dy = d[3 * r + 1], dz = d[3 * r + 2];
      if (!intervalOk || !Number.isFinite(ox + oy + oz + dx + dy + dz)) {
        this.margin[r] = NaN; this.cursor[r] = 0; this.end[r] = steps;
        continue;
      }
      const scale = Math.max(b, Math.abs(ox) + tMax * Math.abs(dx), Math.abs(oy) + tMax * Math.abs(dy), Math.abs(oz) + tMax * Math.abs(dz));
      const margin = 1e-3 * this.cellSide + 64 * 2 ** -23 * scale;
      this.margin[r] = margin;
      const lo = -b - margin, hi = -b + R * this.cellSide + margin;
      slab(ox, oy, oz, dx, dy, dz, lo, lo, lo, hi, hi, hi);
      if (slabEnter > slabLeave) continue; // misses the grid: cursor = end = 0
      this.cursor[r] = this.stepAt(slabEnter, -1);
      this.end[r] = this.stepAt(slabLeave, 1);
    }
  }

  /** The first step whose exact t is at or after `t`, moved by `by`, clamped to 0..=steps. */
  private stepAt(t: number, by: number): number {
    const k = Math.ceil((t - this.near) / this.interval - 0.5) + by;
    return k >= this.steps ? this.steps : k > 0 ? k : 0;
  }

  /** Ray r's next (at most `max`) occupied samples: positions into pts[3·at…], step indices into
   *  ks[at…]; returns how many. Fewer than `max` means the ray has none left. */
  next(r: number, max: number, pts: Float32Array, ks: Int32Array, at: number): number {
    const g = this.grid, R = g.res, occ = g.occupied, b = f(g.bound), two = f(2 * b), t = this.t;
    const ox = this.o[3 * r], oy = this.o[3 * r + 1], oz = this.o[3 * r + 2];
    const dx = this.d[3 * r], dy = this.d[3 * r + 1], dz = this.d[3 * r + 2];
    // Reciprocals: the slab's t differ from grid.rs's quotients by an ulp of f64, far inside the margin.
    const ix = 1 / dx, iy = 1 / dy, iz = 1 / dz;
    const margin = this.margin[r], skip = !Number.isNaN(margin);
    // The box faces' constant parts: the grid's low corner, moved in by the margin.
    const lo0 = -b + margin, hi0 = -b - margin, perInterval = 1 / this.interval;
    // Cells per unit, and how near a cell face the float64 u may not decide the cell (2⁻²⁰·R:
    // 16 times the float32 error of u < R).
    const perCell = R / two, faceGap = R * 2 ** -20;
    const q = this.octant[r], cubes = this.cubes[q], side = this.cellSide, near = this.near, interval = this.interval, steps = this.steps;
    const upX = q & 4, upY = q & 2, upZ = q & 1;
    let k = this.cursor[r], n = 0, tested = 0, occupiedUntil = this.occupiedUntil[r];
    const end = this.end[r];
    while (k < end && n < max) {
      if (k < occupiedUntil) {
        // The steps left in the occupied cube of the last test, emitted untested.
        const stop = Math.min(occupiedUntil, end, k + max - n), first = at + n;
        n += stop - k;
        for (let p = first; k < stop; k++, p++) {
          const tk = t[k];
          pts[3 * p] = f(ox + f(tk * dx)); pts[3 * p + 1] = f(oy + f(tk * dy)); pts[3 * p + 2] = f(oz + f(tk * dz));
          ks[p] = k;
        }
        continue;
      }
      const tk = t[k];
      const x = f(ox + f(tk * dx)), y = f(oy + f(tk * dy)), z = f(oz + f(tk * dz));
      tested++;
      // The cell is that of the float32 u = (x + b)/2b·R. In float64 with a multiplication u is
      // off by at most a few float32 ulps (3·2⁻²⁴ relative), so where it lies farther than `faceGap`
      // from every cell face its floor is the float32 u's; only the rare step that close to a
      // face (or NaN, or outside) takes the float32 operations themselves.
      const su = (x + b) * perCell, sv = (y + b) * perCell, sw = (z + b) * perCell;
      let i = Math.floor(su), j = Math.floor(sv), l = Math.floor(sw);
      if (!(su - i > faceGap && i + 1 - su > faceGap && sv - j > faceGap && j + 1 - sv > faceGap && sw - l > faceGap && l + 1 - sw > faceGap
        && i >= 0 && i < R && j >= 0 && j < R && l >= 0 && l < R)) {
        const u = f(f(f(x + b) / two) * R), v = f(f(f(y + b) / two) * R), w = f(f(f(z + b) / two) * R);
        if (!(u >= 0 && u < R && v >= 0 && v < R && w >= 0 && w < R)) { k++; continue; }
        i = u | 0; j = v | 0; l = w | 0; // floor: 0 ≤ u < R ≤ 512
      }
      const c = (i * R + j) * R + l;
      const occupied = occ[c] !== 0;
      if (occupied) {
        const p = at + n;
        pts[3 * p] = x; pts[3 * p + 1] = y; pts[3 * p + 2] = z;
        ks[p] = k; n++;
      }
      if (!skip) { k++; continue; }
      // Jump to where the ray leaves the cube of cells in this cell's state from the cell on,
      // reaching along the ray (occupied: the steps before are emitted untested; empty: skipped),
      // shrunk by the margin (a slab test written out per axis: this is the hot loop).
      const e = (cubes[c] & ~OCCUPIED_CUBE) - 1;
      const lx = lo0 + (upX ? i : i - e) * side, hx = hi0 + (upX ? i + e + 1 : i + 1) * side;
      const ly = lo0 + (upY ? j : j - e) * side, hy = hi0 + (upY ? j + e + 1 : j + 1) * side;
      const lz = lo0 + (upZ ? l : l - e) * side, hz = hi0 + (upZ ? l + e + 1 : l + 1) * side;
      let enter = -Infinity, leave = Infinity;
      if (dx === 0) { if (ox < lx || ox > hx) leave = -Infinity; }
      else { const p = (lx - ox) * ix, q = (hx - ox) * ix; enter = Math.min(p, q); leave = Math.max(p, q); }
      if (dy === 0) { if (oy < ly || oy > hy) leave = -Infinity; }
      else { const p = (ly - oy) * iy, q = (hy - oy) * iy; enter = Math.max(enter, Math.min(p, q)); leave = Math.min(leave, Math.max(p, q)); }
      if (dz === 0) { if (oz < lz || oz > hz) leave = -Infinity; }
      else { const p = (lz - oz) * iz, q = (hz - oz) * iz; enter = Math.max(enter, Math.min(p, q)); leave = Math.min(leave, Math.max(p, q)); }
      // Every step whose exact t is before the exit lies inside the shrunk cube, so in the cube;
      // the jump lands on the first step at or after the exit. (grid.rs lands one step short; not
      // needed here: a step's f32 t and position are off the exact ones by far less than the
      // margin, and the tests compare the samples with testing every interval.)
      const inside = enter <= tk && tk <= leave;
      // (A reciprocal: an ulp of f64 off the quotient, far inside the margin.)
      const kl = inside ? Math.ceil((leave - near) * perInterval - 0.5) : 0;
      if (occupied) {
        occupiedUntil = kl < steps ? kl : steps;
        k++;
      } else k = kl > k + 1 ? (kl < steps ? kl : steps) : k + 1;
    }
    this.cursor[r] = k;
    this.occupiedUntil[r] = occupiedUntil;
    this.tested += tested;
    return n;
  }
}
