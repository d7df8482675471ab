// The occupancy grid marching reads (occupancy.bin's cells, isOccupied: the reference every
// marched sample is tested against) and its cube tables (cornerReach). Marching itself, as
// core/src/render/grid.rs's occupied_samples, is WebAssembly (assembly/march.ts, driven by
// marcher.ts): `steps` equal intervals over [near, far] (a contracted grid: in segments), a
// sample at each middle, kept where it lies in an occupied cell. Space is crossed by slab tests
// as grid.rs does it (boxes grown or shrunk by a margin far above f32 rounding), so the samples
// are those of testing every interval: at a tested step, the box is the largest cube of cells in
// the cell's state with the cell at its corner, reaching along the ray (cornerReach); the steps
// up to where the ray leaves it (shrunk by the margin) are skipped (empty) or emitted untested
// (occupied). Rays march lazily: a ray that terminates early never marches the rest.

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
