// Marching a contracted grid (nerf-rs-scene-3), as core/src/render/grid.rs's RayMarch over
// march_segments: every segment's steps one after the other (a ray's steps numbered across its
// segments), a sample at each middle, kept where its contracted point lies in an occupied cell:
// exactly the samples of testing every step. Cubes of cells (cornerReach) are jumped through only
// inside the inner cube |x|∞ ≤ 1, where the contraction leaves points as they are, so a cube of
// cells is a box of the world there (a cube is cut at the inner cube's faces); beyond it every
// step is tested, as in Rust. Pure.

import { type Segment, contractionFactor } from "./contraction";
import { type Grid, type Marcher, OCCUPIED_CUBE, raysCubes } from "./march";

const f = Math.fround;

/** One axis of the cube of `s` cells from cell c reaching up (or down) that axis, cut to the inner
 *  cube's cells [first, end) (a contracted grid over ±b): where o + t·d leaves it shrunk by
 *  `margin` (∞ for d = 0), or NaN when the exact point at `tt` lies outside the shrunk cube (as
 *  in a cell outside the inner cube: no jump). In f64. */
function axisExit(b: number, side: number, margin: number, c: number, s: number, up: number, first: number, end: number,
  o: number, d: number, tt: number): number {
  const lo = -b + Math.max(up ? c : c + 1 - s, first) * side, hi = -b + Math.min(up ? c + s : c + 1, end) * side;
  const x = o + tt * d;
  if (!(lo + margin <= x && x <= hi - margin)) return NaN;
  return d > 0 ? (hi - margin - o) / d : d < 0 ? (lo + margin - o) / d : Infinity;
}

/** Every ray's march through a contracted `grid` along `segments` (marchSegments(…, true)).
 *  Step k (over all segments) samples t[k] with interval[k]. Shapes: o, d [n, 3]. */
export class ContractedMarch implements Marcher {
  readonly t: Float32Array;
  /** Each step's interval, its segment's (δ = interval · ‖d‖). */
  readonly interval: Float32Array;
  readonly cursor: Int32Array;
  /** All the steps, for every ray: a contracted grid's box is the whole world. */
  readonly end: Int32Array;
  tested = 0;
  /** Per ray: steps before this one lie in the occupied cube of the last step tested. */
  private readonly occupiedUntil: Int32Array;
  /** The first step of each segment, then the number of steps: [segments + 1]. */
  private readonly first: Int32Array;
  private readonly cellSide: number;
  /** The cells [innerFirst, innerEnd) per axis inside the inner cube: cell i spans −2 + 4i/R ..
   *  −2 + 4(i + 1)/R, inside ±1 from ⌈R/4⌉ to ⌊3R/4⌋. */
  private readonly innerFirst: number;
  private readonly innerEnd: number;
  /** Per ray: the octant it heads into, and per octant its cubes (raysCubes). */
  private readonly octant: Uint8Array;
  private readonly cubes: Uint8Array[];

  constructor(private readonly grid: Grid, private readonly o: Float32Array, private readonly d: Float32Array,
    private readonly segments: Segment[]) {
    const steps = segments.reduce((sum, s) => sum + s.steps, 0);
    this.t = new Float32Array(steps);
    this.interval = new Float32Array(steps);
    this.first = new Int32Array(segments.length + 1);
    let k = 0;
    segments.forEach((s, i) => {
      this.first[i] = k;
      // grid.rs's March::t, in f32.
      for (let j = 0; j < s.steps; j++, k++) { this.t[k] = f(s.start + f(f(j + 0.5) * s.interval)); this.interval[k] = s.interval; }
    });
    this.first[segments.length] = steps;
    const n = o.length / 3;
    this.cursor = new Int32Array(n);
    this.end = new Int32Array(n).fill(steps);
    this.occupiedUntil = new Int32Array(n);
    this.cellSide = (2 * f(grid.bound)) / grid.res;
    this.innerFirst = Math.ceil(grid.res / 4);
    this.innerEnd = Math.floor((3 * grid.res) / 4);
    ({ octant: this.octant, cubes: this.cubes } = raysCubes(grid, d));
  }

  /** The segment holding step k. */
  private segmentOf(k: number): number {
    let s = 0;
    while (k >= this.first[s + 1] && s + 1 < this.segments.length) s++;
    return s;
  }

  /** grid.rs's margin of ray r's slab tests in segment s: far above the f32 error of a step's t
   *  and position there. NaN: the segment is tested step by step (non-finite inputs). */
  private margin(r: number, s: number): number {
    const { start, interval, steps } = this.segments[s], o = this.o, d = this.d;
    const finite = Number.isFinite(o[3 * r] + o[3 * r + 1] + o[3 * r + 2] + d[3 * r] + d[3 * r + 1] + d[3 * r + 2] + start);
    if (!finite || !(interval > 0) || !Number.isFinite(interval)) return NaN;
    const tMax = Math.max(Math.abs(f(start + f(f(steps + 0.5) * interval))), Math.abs(start));
    let scale = f(this.grid.bound);
    for (let a = 0; a < 3; a++) scale = Math.max(scale, Math.abs(o[3 * r + a]) + tMax * Math.abs(d[3 * r + a]));
    return 1e-3 * this.cellSide + 64 * 2 ** -23 * scale;
  }

  /** The first step of segment s whose exact t is at or after `t` (grid.rs's step_at). */
  private stepAt(s: number, t: number): number {
    const { start, interval, steps } = this.segments[s];
    const x = Math.min(Math.max((t - start) / interval - 0.5, -2), steps + 2);
    return this.first[s] + Math.min(Math.max(Math.ceil(x), 0), steps);
  }

  /** Ray r's next (at most `max`) occupied samples, crossing into later segments: positions into
   *  pts[3·at…], step indices into ks[at…]; returns how many (fewer than `max`: none left). */
  next(r: number, max: number, pts: Float32Array, ks: Int32Array, at: number): number {
    const g = this.grid, R = g.res, occ = g.occupied, b = f(g.bound), two = f(2 * b), t = this.t;
    const side = this.cellSide, end = this.end[r], first = this.innerFirst, last = this.innerEnd;
    const ox = this.o[3 * r], oy = this.o[3 * r + 1], oz = this.o[3 * r + 2];
    const dx = this.d[3 * r], dy = this.d[3 * r + 1], dz = this.d[3 * r + 2];
    const q = this.octant[r], cubes = this.cubes[q];
    let k = this.cursor[r], n = 0, tested = 0, occupiedUntil = this.occupiedUntil[r];
    let s = this.segmentOf(k), segmentEnd = this.first[s + 1], margin = this.margin(r, s);
    while (k < end && n < max) {
      if (k >= segmentEnd) { s = this.segmentOf(k); segmentEnd = this.first[s + 1]; margin = this.margin(r, s); }
      const tk = t[k];
      const x = f(ox + f(tk * dx)), y = f(oy + f(tk * dy)), z = f(oz + f(tk * dz));
      if (k < occupiedUntil) {
        const p = at + n;
        pts[3 * p] = x; pts[3 * p + 1] = y; pts[3 * p + 2] = z;
        ks[p] = k; n++; k++;
        continue;
      }
      tested++;
      // The cell of the contracted point (OccupancyGrid::cell_coordinates).
      const sc = contractionFactor(x, y, z);
      const u = f(f(f(f(x * sc) + b) / two) * R), v = f(f(f(f(y * sc) + b) / two) * R), w = f(f(f(f(z * sc) + b) / two) * R);
      if (!(u >= 0 && u < R && v >= 0 && v < R && w >= 0 && w < R)) { k++; continue; }
      const i = u | 0, j = v | 0, l = w | 0; // floor: 0 ≤ u < R ≤ 512
      const c = (i * R + j) * R + l, occupied = occ[c] !== 0;
      if (occupied) {
        const p = at + n;
        pts[3 * p] = x; pts[3 * p + 1] = y; pts[3 * p + 2] = z;
        ks[p] = k; n++;
      }
      // The steps up to where the exact line leaves the cube of cells in this cell's state from
      // the cell on, reaching along the ray (shrunk by the margin), share its state: emitted
      // untested, or skipped. NaN: no jump.
      const s3 = cubes[c] & ~OCCUPIED_CUBE;
      const exit = Number.isNaN(margin) ? NaN : Math.min(axisExit(b, side, margin, i, s3, q & 4, first, last, ox, dx, tk),
        axisExit(b, side, margin, j, s3, q & 2, first, last, oy, dy, tk), axisExit(b, side, margin, l, s3, q & 1, first, last, oz, dz, tk));
      const run = Number.isNaN(exit) ? k + 1 : this.stepAt(s, exit);
      if (occupied) { occupiedUntil = run; k++; }
      else k = run > k + 1 ? run : k + 1;
    }
    this.cursor[r] = k;
    this.occupiedUntil[r] = occupiedUntil;
    this.tested += tested;
    return n;
  }
}
