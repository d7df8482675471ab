// Marching and compositing a marched frame, in WebAssembly (assembly/march.ts; its arithmetic
// and samples are those of core/src/render/grid.rs, see there). A MarchWasm is one instance
// with its own memory: the grid copied in once per grid (occupancy, then the cube tables of the
// octants rays have headed into), each frame's arrays laid out above it. renderMarch takes one
// from a pool per frame, so frames in flight never share buffers.

import { BASE, Layout, instantiate, reserve } from "./wasm";
import { type Grid, cornerReach, octantOf } from "./march";
import type { Segment } from "./contraction";

const f = Math.fround;

/** At most this many points per field (onnxruntime) call: WASM memory caps one call near 64k. */
export const MAX_POINTS = 65536;

// assembly/march.ts's expAlpha table: 2^(i/32) for i in −EXP_STEPS..0.
const EXP_STEPS = 4832;

/** assembly/march.ts's exports (pointers are byte offsets into `memory`). */
interface Exports {
  tested: WebAssembly.Global;
  setGrid(occ: number, cubes: number, res: number, bound: number, contracted: boolean): void;
  setRays(n: number, o: number, d: number, t: number, cursor: number, end: number, until: number, margin: number, octant: number,
    near: number, interval: number, steps: number): void;
  setContractedRays(n: number, o: number, d: number, segStart: number, segInterval: number, segSteps: number, segments: number,
    t: number, stepInterval: number, first: number, cursor: number, end: number, until: number, octant: number): void;
  next(r: number, limit: number, pts: number, ks: number, at: number): number;
  setState(rays: number, rgb: number, depth: number, acc: number, trans: number, done: number, dNorm: number, stepLen: number,
    view: number, queue: number, ring: number, segment: number, minTransmittance: number, pts: number, dirs: number, ks: number,
    callRays: number, counts: number, alphas: number, maxPoints: number): number;
  setExpTable(table: number): void;
  expAlphaOf(x: number): number;
  gather(chunk: number): number;
  composite(sigma: number, rgb: number, batch: number): number;
  addWhite(): void;
}

/** One frame's arrays (byte offsets). */
interface FramePtrs {
  o: number; d: number; view: number; t: number; stepInterval: number; first: number; segStart: number; segInterval: number; segSteps: number;
  cursor: number; end: number; until: number; margin: number; octant: number;
  rgb: number; depth: number; acc: number; trans: number; done: number; dNorm: number; stepLen: number; queue: number; ring: number;
  pts: number; dirs: number; ks: number; callRays: number; counts: number; alphas: number; sigma: number; col: number;
}

/** One instance of assembly/march.ts with its memory. */
export class MarchWasm {
  private static readonly idle: MarchWasm[] = [];
  private readonly x: Exports & { memory: WebAssembly.Memory };
  private readonly cubeTable: number;
  private grid: Grid | null = null;
  /** Where the grid's part of memory ends (frames are laid out above). */
  private gridTop = 0;
  /** The octants whose cube tables are in memory (bit q). */
  private octants = 0;
  private p: FramePtrs | null = null;
  private rays = 0;

  constructor() {
    this.x = instantiate<Exports>("march");
    const at = new Layout(BASE), expTable = at.take(8 * (EXP_STEPS + 1));
    this.cubeTable = at.take(4 * 8);
    this.gridTop = at.top;
    this.reserve(at.top);
    const table = new Float64Array(this.x.memory.buffer, expTable, EXP_STEPS + 1);
    for (let i = 0; i <= EXP_STEPS; i++) table[i] = 2 ** ((i - EXP_STEPS) / 32);
    this.x.setExpTable(expTable);
  }

  /** Compositing's exp(x) for x = −σ·δ (Math.exp outside −104 < x ≤ 0): for the tests. */
  expAlpha(x: number): number { return this.x.expAlphaOf(x); }

  /** An idle instance (or a new one); give it back after the frame. */
  static take(): MarchWasm { return MarchWasm.idle.pop() ?? new MarchWasm(); }
  give(): void { MarchWasm.idle.push(this); }

  private reserve(top: number): void { reserve(this.x.memory, top, "marching"); }

  private get buffer(): ArrayBuffer { return this.x.memory.buffer; }
  private f32(at: number, len: number): Float32Array { return new Float32Array(this.buffer, at, len); }
  private i32(at: number, len: number): Int32Array { return new Int32Array(this.buffer, at, len); }

  /** Marching `grid` from now on, its cube tables for the octants of `octants` (bits) in memory. */
  private useGrid(grid: Grid, octants: number): void {
    const cells = grid.res ** 3;
    if (this.grid !== grid) {
      const at = new Layout(this.cubeTable + 32);
      const occ = at.take(cells);
      this.reserve(at.top);
      new Uint8Array(this.buffer, occ, cells).set(grid.occupied);
      this.i32(this.cubeTable, 8).fill(0);
      this.grid = grid; this.gridTop = at.top; this.octants = 0;
      this.x.setGrid(occ, this.cubeTable, grid.res, f(grid.bound), !!grid.contracted);
    }
    for (let q = 0; q < 8; q++) {
      if (!(octants & (1 << q)) || this.octants & (1 << q)) continue;
      const after = new Layout(this.gridTop), at = after.take(cells);
      this.gridTop = after.top;
      this.reserve(this.gridTop);
      new Uint8Array(this.buffer, at, cells).set(cornerReach(grid, q));
      this.i32(this.cubeTable, 8)[q] = at;
      this.octants |= 1 << q;
    }
  }

  /** Lays out a frame of rays o, d [n, 3] over `steps` steps (`segments` of a contracted grid)
   *  and copies the rays in. */
  private layout(grid: Grid, o: Float32Array, d: Float32Array, steps: number, segments: number): FramePtrs {
    this.useGrid(grid, octantsOf(d));
    const n = o.length / 3, at = new Layout(this.gridTop), M = MAX_POINTS;
    const p: FramePtrs = {
      o: at.take(12 * n), d: at.take(12 * n), view: at.take(12 * n), t: at.take(4 * steps), stepInterval: at.take(4 * steps),
      first: at.take(4 * (segments + 1)), segStart: at.take(4 * segments), segInterval: at.take(4 * segments), segSteps: at.take(4 * segments),
      cursor: at.take(4 * n), end: at.take(4 * n), until: at.take(4 * n), margin: at.take(8 * n), octant: at.take(n),
      rgb: at.take(12 * n), depth: at.take(4 * n), acc: at.take(4 * n), trans: at.take(4 * n), done: at.take(4 * n), dNorm: at.take(4 * n),
      stepLen: at.take(4 * n), queue: at.take(4 * Math.max(n, 1)), ring: at.take(16),
      pts: at.take(12 * M), dirs: at.take(12 * M), ks: at.take(4 * M), callRays: at.take(4 * M), counts: at.take(4 * M), alphas: at.take(4 * M),
      sigma: at.take(4 * M), col: at.take(12 * M),
    };
    this.reserve(at.top);
    this.f32(p.o, 3 * n).set(o);
    this.f32(p.d, 3 * n).set(d);
    this.p = p; this.rays = n;
    return p;
  }

  /** A straight grid's frame: `steps` equal intervals from `near` (RayMarch). */
  straight(grid: Grid, o: Float32Array, d: Float32Array, near: number, interval: number, steps: number): void {
    const p = this.layout(grid, o, d, steps, 0);
    this.x.setRays(this.rays, p.o, p.d, p.t, p.cursor, p.end, p.until, p.margin, p.octant, near, interval, steps);
  }

  /** A contracted grid's frame along `segments` (ContractedMarch). */
  contracted(grid: Grid, o: Float32Array, d: Float32Array, segments: Segment[]): number {
    const steps = segments.reduce((sum, s) => sum + s.steps, 0), k = segments.length;
    const p = this.layout(grid, o, d, steps, k);
    this.f32(p.segStart, k).set(segments.map((s) => s.start));
    this.f32(p.segInterval, k).set(segments.map((s) => s.interval));
    this.i32(p.segSteps, k).set(segments.map((s) => s.steps));
    this.x.setContractedRays(this.rays, p.o, p.d, p.segStart, p.segInterval, p.segSteps, k, p.t, p.stepInterval, p.first, p.cursor, p.end, p.until, p.octant);
    return steps;
  }

  private get ptrs(): FramePtrs {
    if (!this.p) throw new Error("MarchWasm: no frame laid out");
    return this.p;
  }

  /** Views of the frame's step t and each step's interval (contracted). */
  t(steps: number): Float32Array { return this.f32(this.ptrs.t, steps); }
  stepInterval(steps: number): Float32Array { return this.f32(this.ptrs.stepInterval, steps); }
  get tested(): number { return this.x.tested.value as number; }

  /** Ray r's next (at most `max` ≤ MAX_POINTS) occupied samples, copied into pts[3·at…] and ks[at…]. */
  next(r: number, max: number, pts: Float32Array, ks: Int32Array, at: number): number {
    if (max > MAX_POINTS) throw new Error(`MarchWasm.next: ${max} samples asked, at most ${MAX_POINTS}`);
    const p = this.ptrs, c = this.x.next(r, max, p.pts, p.ks, 0);
    pts.set(this.f32(p.pts, 3 * c), 3 * at);
    ks.set(this.i32(p.ks, c), at);
    return c;
  }

  /** Starts compositing: view directions [n, 3] (unit), segments of `segment` samples, stop below
   *  `minTransmittance`. Returns how many rays have samples to march. */
  start(view: Float32Array, segment: number, minTransmittance: number): number {
    const p = this.ptrs;
    this.f32(p.view, 3 * this.rays).set(view);
    return this.x.setState(this.rays, p.rgb, p.depth, p.acc, p.trans, p.done, p.dNorm, p.stepLen, p.view, p.queue, p.ring, segment,
      minTransmittance, p.pts, p.dirs, p.ks, p.callRays, p.counts, p.alphas, MAX_POINTS);
  }

  /** The next field call's samples (each queued ray's next `chunk` at most): how many rays, and
   *  views of their positions and view directions. */
  gather(chunk: number): { batch: number; points: number; pts: Float32Array; dirs: Float32Array } {
    const p = this.ptrs, batch = this.x.gather(chunk), points = this.i32(p.ring, 3)[2];
    return { batch, points, pts: this.f32(p.pts, 3 * points), dirs: this.f32(p.dirs, 3 * points) };
  }

  /** Composites the field's σ [m] and rgb [m, 3] for the last gather's `batch` rays; returns how
   *  many rays still have samples to march. */
  composite(sigma: Float32Array, rgb: Float32Array, points: number, batch: number): number {
    const p = this.ptrs;
    this.f32(p.sigma, points).set(sigma.subarray(0, points));
    this.f32(p.col, 3 * points).set(rgb.subarray(0, 3 * points));
    return this.x.composite(p.sigma, p.col, batch);
  }

  /** The frame (copies): rgb [n, 3] (over white where `white`), depth, acc [n]. */
  frame(white: boolean): { rgb: Float32Array; depth: Float32Array; acc: Float32Array } {
    const p = this.ptrs, n = this.rays;
    if (white) this.x.addWhite();
    return { rgb: this.f32(p.rgb, 3 * n).slice(), depth: this.f32(p.depth, n).slice(), acc: this.f32(p.acc, n).slice() };
  }
}

/** The octants directions `d` [n, 3] head into (bit q for octant q). */
function octantsOf(d: Float32Array): number {
  let mask = 0;
  for (let r = 0; r < d.length; r += 3) mask |= 1 << octantOf(d[r], d[r + 1], d[r + 2]);
  return mask;
}

/** A march of every ray through a grid, in one MarchWasm, as the tests drive it (renderMarch
 *  drives the MarchWasm itself): `t[k]` of each step; `next` hands out a ray's next samples. */
abstract class Marcher {
  abstract readonly t: Float32Array;
  constructor(private readonly wasm: MarchWasm) {}
  /** Steps tested so far, all rays together (the work skipping saves). */
  get tested(): number { return this.wasm.tested; }
  /** Ray r's next (at most `max`) occupied samples: positions into pts[3·at…], step indices
   *  into ks[at…]; returns how many. Fewer than `max` means the ray has none left. */
  next(r: number, max: number, pts: Float32Array, ks: Int32Array, at: number): number { return this.wasm.next(r, max, pts, ks, at); }
}

/** Every ray's march through a straight `grid`: step k samples t[k] = near + (k + 0.5)·interval
 *  (in f32), only in occupied cells, crossing space by slab tests against cubes of cells in one
 *  state (march.ts's cornerReach): the samples of testing every interval. Shapes: o, d [n, 3]. */
export class RayMarch extends Marcher {
  readonly t: Float32Array;
  constructor(grid: Grid, o: Float32Array, d: Float32Array, near: number, interval: number, steps: number, wasm = new MarchWasm()) {
    super(wasm);
    wasm.straight(grid, o, d, near, interval, steps);
    this.t = wasm.t(steps);
  }
}

/** Every ray's march through a contracted `grid` along `segments` (marchSegments(…, true)): step
 *  k (over all segments) samples t[k] with interval[k]; cubes of cells are jumped through only
 *  inside the inner cube, where the contraction leaves points as they are. Shapes: o, d [n, 3]. */
export class ContractedMarch extends Marcher {
  readonly t: Float32Array;
  /** Each step's interval, its segment's (δ = interval · ‖d‖). */
  readonly interval: Float32Array;
  constructor(grid: Grid, o: Float32Array, d: Float32Array, segments: Segment[], wasm = new MarchWasm()) {
    super(wasm);
    const steps = wasm.contracted(grid, o, d, segments);
    this.t = wasm.t(steps);
    this.interval = wasm.stepInterval(steps);
  }
}
