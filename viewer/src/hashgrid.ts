// The hash-grid encoding of an `ngp` field graph, evaluated here so that onnxruntime-web runs
// only the graph's head (the MLPs): what nerf-render does with the core's Rust encoding
// (runtime/src/network.rs), for the same reason (onnxruntime's gathers of the table's rows are
// the slow part of the whole graph). The encoding is core/src/field/ngp/hash_grid's and
// spherical_harmonics.rs's: the unit point and each level's corner positions in float32 as Rust
// computes them (Math.fround after each operation), so the same corners are read; the trilinear
// weights and their sum in float64, rounded to float32 once (1.6× faster than rounding after
// each operation; the features differ from Rust's by float32 rounding). The head is cut from
// the bundle's own graph (bundle/src/ngp.rs head_graph), node for node. Pure.

import { contractionFactor } from "./contraction";
import { ModelReader, concatBytes, lengthDelimited, packedVarints, stringField, varintField } from "./proto";

const f = Math.fround;

/** The graph's tensors the head starts from (bundle/src/ngp.rs FEATURES_TENSOR, SH_TENSOR). */
export const FEATURES_TENSOR = "grid.features";
export const SH_TENSOR = "sh.output";
/** Degree-4 spherical harmonics per direction. */
export const SH4_DIM = 16;

/** tiny-cuda-nn's hash primes y, z as int32 for Math.imul (x's is 1). */
const PRIME_Y = 2654435761 | 0, PRIME_Z = 805459861;

/** SH4_CONSTANTS of spherical_harmonics.rs, as float32. */
const SH = [0.2820948, 0.4886025, 1.0925484, 0.9461747, 0.31539157, 0.5462742, 0.5900436, 2.8906114, 0.4570458, 0.3731763, 1.4453057].map(f);

/** HashGridConfig (the `grid` of the graph's nerf.ngp metadata). */
export interface HashGridConfig {
  levels: number; features_per_level: number; log2_table_size: number; base_resolution: number; max_resolution: number;
}

/** One level as LevelLayout (config.rs), with its first row and its rows in the table. */
export interface Level { scale: number; resolution: number; entries: number; dense: boolean; row: number; rows: number }

/** The levels of `c` (LevelLayout::layout: scale N_min·bˡ − 1 in float64 rounded to float32,
 *  resolution ⌈scale⌉ + 1, entries min(res³ rounded up to 8, T), dense where res³ fits), each
 *  level's scale taken from `scales` where the graph gives them (its `grid.level_scales`, the
 *  float32 values it computes with). `graphLayout`: the rows as the compiler arranges them
 *  (ngp.rs, layout 2: hashed levels first, then dense levels padded to res³ + res² + res + 1
 *  rows); otherwise the trained order, level after level. */
export function levelLayout(c: HashGridConfig, graphLayout: boolean, scales?: ArrayLike<number>): Level[] {
  const growth = c.levels <= 1 ? 1 : Math.pow(Math.exp(Math.log(c.max_resolution) - Math.log(c.base_resolution)), 1 / (c.levels - 1));
  const log2b = Math.log2(growth), t = 2 ** c.log2_table_size;
  const levels: Level[] = [];
  for (let l = 0; l < c.levels; l++) {
    const scale = scales ? f(scales[l]) : f(2 ** (l * log2b) * c.base_resolution - 1);
    const resolution = Math.ceil(scale) + 1, size = resolution ** 3;
    const entries = Math.min(Math.ceil(size / 8) * 8, t);
    const dense = size <= entries;
    // ngp.rs padded_dense_rows: every x + y·res + z·res² for coordinates ≤ res.
    const rows = graphLayout && dense ? size + resolution ** 2 + resolution + 1 : entries;
    levels.push({ scale, resolution, entries, dense, row: 0, rows });
  }
  let row = 0;
  const order = graphLayout ? [...levels.filter((v) => !v.dense), ...levels.filter((v) => v.dense)] : levels;
  for (const level of order) { level.row = row; row += level.rows; }
  return levels;
}

/** The degree-4 harmonics of the unit direction dirs[i..i + 3] (sh4), into out[at..at + 16].
 *  Read from the array rather than passed as three numbers: V8 does not inline this into the
 *  encoder's loop, and a call boxes each number argument (a scavenge every 20,000 points). */
export function sh4(dirs: ArrayLike<number>, i: number, out: Float32Array, at: number): void {
  const x = dirs[i], y = dirs[i + 1], z = dirs[i + 2];
  const c = SH, xy = f(x * y), yz = f(y * z), xz = f(x * z), x2 = f(x * x), y2 = f(y * y), z2 = f(z * z);
  out[at] = c[0];
  out[at + 1] = f(-c[1] * y);
  out[at + 2] = f(c[1] * z);
  out[at + 3] = f(-c[1] * x);
  out[at + 4] = f(c[2] * xy);
  out[at + 5] = f(-c[2] * yz);
  out[at + 6] = f(f(c[3] * z2) - c[4]);
  out[at + 7] = f(-c[2] * xz);
  out[at + 8] = f(f(c[5] * x2) - f(c[5] * y2));
  out[at + 9] = f(f(c[6] * y) * f(f(-3 * x2) + y2));
  out[at + 10] = f(f(c[7] * xy) * z);
  out[at + 11] = f(f(c[8] * y) * f(1 - f(5 * z2)));
  out[at + 12] = f(f(c[9] * z) * f(f(5 * z2) - 3));
  out[at + 13] = f(f(c[8] * x) * f(1 - f(5 * z2)));
  out[at + 14] = f(f(c[10] * z) * f(x2 - y2));
  out[at + 15] = f(f(c[6] * x) * f(-x2 + f(3 * y2)));
}

/** The harmonics (sh4) of `n` unit directions [n, 3] into sh [n, 16]. */
function sh4Rows(viewdirs: Float32Array, n: number, sh: Float32Array): void {
  for (let i = 0; i < n; i++) sh4(viewdirs, 3 * i, sh, SH4_DIM * i);
}

/** A dense level's entry e < 2·entries modulo entries: one subtraction (the graph's padded rows
 *  hold the same value there too). At module level: a closure made in the per-point loop is an
 *  object per point that V8 does not elide (a scavenge every few thousand points). */
function wrap(e: number, entries: number): number {
  return e >= entries ? e - entries : e;
}

/** A graph's hash grid and the box it covers (GridBound), evaluated as the Rust encoding. */
export class HashEncoder {
  /** Features per point, L·F. */
  readonly width: number;
  private unit = new Float32Array(0);

  constructor(readonly levels: Level[], readonly features: number, readonly table: Float32Array,
    readonly min: number[], readonly scale: number[], readonly contracted: boolean) {
    this.width = levels.length * features;
  }

  /** features [n, L·F] (row-major, level-major within a row) and the harmonics [n, 16] of
   *  world `points` [n, 3] and unit `viewdirs` [n, 3]. */
  encode(points: Float32Array, viewdirs: Float32Array, n: number, features: Float32Array, sh: Float32Array): void {
    if (this.unit.length < 3 * n) this.unit = new Float32Array(3 * n);
    this.toUnit(points, n);
    // Level by level, so a level's part of the table is reused from cache across the points.
    for (let l = 0; l < this.levels.length; l++) this.encodeLevel(l, n, features);
    sh4Rows(viewdirs, n, sh);
  }

  /** GridBound::to_unit of `points` [n, 3] into this.unit: contracted first where the field is,
   *  then (p − min)·scale. Each loop of encode is a function of its own, for the reason
   *  render.ts's alphaPass gives (chromium's --trace-deopt: encode's compiled first loop fell out
   *  at the levels' loop 14 to 38 times in four lego-ngp frames). */
  private toUnit(points: Float32Array, n: number): void {
    const unit = this.unit, m0 = this.min[0], m1 = this.min[1], m2 = this.min[2], s0 = this.scale[0], s1 = this.scale[1], s2 = this.scale[2];
    const contracted = this.contracted;
    for (let i = 0; i < n; i++) {
      let x = points[3 * i], y = points[3 * i + 1], z = points[3 * i + 2];
      if (contracted) { const k = contractionFactor(x, y, z); x = f(x * k); y = f(y * k); z = f(z * k); }
      unit[3 * i] = f(f(x - m0) * s0); unit[3 * i + 1] = f(f(y - m1) * s1); unit[3 * i + 2] = f(f(z - m2) * s2);
    }
  }

  /** One level of every point (grid.rs corners and forward_level), the 8 corners unrolled. */
  private encodeLevel(l: number, n: number, out: Float32Array): void {
    const { scale, resolution: r, entries, dense, row } = this.levels[l];
    const F = this.features, W = this.width, unit = this.unit, t = this.table;
    const mask = entries - 1, base = row * F;
    // Per axis, the corner terms: x·1, y·res, z·res² (dense) or the hash's x·1, y·P1, z·P2.
    const sy = dense ? r : PRIME_Y, sz = dense ? r * r : PRIME_Z;
    for (let i = 0; i < n; i++) {
      // Clamped to [0, 1] (NaN to 0, as f32::max); pos ≥ 0.5, so truncation is the floor.
      let u = unit[3 * i], v = unit[3 * i + 1], w = unit[3 * i + 2];
      u = f(f((u > 0 ? (u < 1 ? u : 1) : 0) * scale) + 0.5);
      v = f(f((v > 0 ? (v < 1 ? v : 1) : 0) * scale) + 0.5);
      w = f(f((w > 0 ? (w < 1 ? w : 1) : 0) * scale) + 0.5);
      const cx = u | 0, cy = v | 0, cz = w | 0;
      const fx = u - cx, fy = v - cy, fz = w - cz, gx = 1 - fx, gy = 1 - fy, gz = 1 - fz;
      const x0 = cx, x1 = cx + 1, y0 = Math.imul(cy, sy), y1 = Math.imul(cy + 1, sy), z0 = Math.imul(cz, sz), z1 = Math.imul(cz + 1, sz);
      // Corner k = (bx, by, bz) = bits 0, 1, 2; weight wx · wy · wz (float64 from here on).
      const w00 = gx * gy, w10 = fx * gy, w01 = gx * fy, w11 = fx * fy;
      const k0 = w00 * gz, k1 = w10 * gz, k2 = w01 * gz, k3 = w11 * gz, k4 = w00 * fz, k5 = w10 * fz, k6 = w01 * fz, k7 = w11 * fz;
      let e0, e1, e2, e3, e4, e5, e6, e7;
      if (dense) {
        e0 = wrap(x0 + y0 + z0, entries); e1 = wrap(x1 + y0 + z0, entries); e2 = wrap(x0 + y1 + z0, entries); e3 = wrap(x1 + y1 + z0, entries);
        e4 = wrap(x0 + y0 + z1, entries); e5 = wrap(x1 + y0 + z1, entries); e6 = wrap(x0 + y1 + z1, entries); e7 = wrap(x1 + y1 + z1, entries);
      } else {
        e0 = (x0 ^ y0 ^ z0) & mask; e1 = (x1 ^ y0 ^ z0) & mask; e2 = (x0 ^ y1 ^ z0) & mask; e3 = (x1 ^ y1 ^ z0) & mask;
        e4 = (x0 ^ y0 ^ z1) & mask; e5 = (x1 ^ y0 ^ z1) & mask; e6 = (x0 ^ y1 ^ z1) & mask; e7 = (x1 ^ y1 ^ z1) & mask;
      }
      e0 = base + e0 * F; e1 = base + e1 * F; e2 = base + e2 * F; e3 = base + e3 * F;
      e4 = base + e4 * F; e5 = base + e5 * F; e6 = base + e6 * F; e7 = base + e7 * F;
      const o = i * W + l * F;
      for (let q = 0; q < F; q++) {
        out[o + q] = k0 * t[e0 + q] + k1 * t[e1 + q] + k2 * t[e2 + q] + k3 * t[e3 + q] + k4 * t[e4 + q] + k5 * t[e5 + q] + k6 * t[e6 + q] + k7 * t[e7 + q];
      }
    }
  }
}

/** float16 bits → float32 values, through a table of all 65,536 (made once). */
let halves: Float32Array | null = null;
function halfToFloat(bits: Uint16Array): Float32Array {
  if (!halves) {
    halves = new Float32Array(65536);
    for (let h = 0; h < 65536; h++) {
      const sign = h & 0x8000 ? -1 : 1, exp = (h >> 10) & 0x1f, frac = h & 0x3ff;
      halves[h] = exp === 0 ? sign * frac * 2 ** -24 : exp === 31 ? (frac ? NaN : sign * Infinity) : sign * (1024 + frac) * 2 ** (exp - 25);
    }
  }
  const out = new Float32Array(bits.length), lut = halves;
  for (let i = 0; i < bits.length; i++) out[i] = lut[bits[i]];
  return out;
}

/** The nerf.ngp metadata's grid and bound within the ranges HashGridConfig::validate and
 *  GridBound::validate allow, or an error naming the file and the field. */
function checkSpec(spec: any, name: string): void {
  const g = spec?.grid, b = spec?.bound;
  const int = (v: unknown, lo: number, hi: number) => Number.isInteger(v) && (v as number) >= lo && (v as number) <= hi;
  if (!(g && int(g.levels, 1, 32) && [1, 2, 4, 8].includes(g.features_per_level) && int(g.log2_table_size, 3, 30)
    && int(g.base_resolution, 1, 65536) && int(g.max_resolution, g.base_resolution, 65536)))
    throw new Error(`${name}: nerf.ngp: grid ${JSON.stringify(g)} is outside what a hash grid can be (levels 1–32, ` +
      "features_per_level 1, 2, 4 or 8, log2_table_size 3–30, 1 ≤ base_resolution ≤ max_resolution ≤ 65536)");
  const axes = (a: unknown) => Array.isArray(a) && a.length === 3 && a.every((v) => Number.isFinite(v));
  if (!(b && axes(b.min) && axes(b.max) && [0, 1, 2].every((d) => b.max[d] > b.min[d])))
    throw new Error(`${name}: nerf.ngp: bound ${JSON.stringify(b)} needs finite min < max on each of 3 axes`);
}

/** What the split path needs of a hash-grid graph: the encoder and the head's ONNX bytes. */
export interface SplitGraph { encoder: HashEncoder; head: Uint8Array }

/** A node's inputs and outputs, and its bytes (NodeProto: input 1, output 2). */
interface NodeInfo { inputs: string[]; outputs: string[]; start: number; end: number }

/** Split a hash-grid field graph written by nerf export into the encoder and the head, or say
 *  why it cannot be (written before its encodings' outputs were named, a table this reader does
 *  not know); null for a graph that is not a hash grid. The caller then runs the whole graph.
 *  `name` goes into the error of a malformed file. */
export function splitHashGrid(bytes: Uint8Array, name: string): SplitGraph | { reason: string } | null {
  const reader = new ModelReader(bytes, name), { walk, str, bad } = reader;
  const metadata: Record<string, string> = {};
  const model: Uint8Array[] = []; // the fields the head keeps, as they are
  let graph: [number, number] | null = null;
  walk(0, bytes.length, (n, s, e) => {
    if (n === 14) {
      const [key, value] = reader.entry(s, e);
      metadata[key] = value;
    } else if (n === 7) graph = [s, e];
    else if (n !== 6) model.push(lengthDelimited(n, bytes.subarray(s, e)));
  }, (n, v) => model.push(varintField(n, v)));
  if (metadata["nerf.field"] !== "ngp") return null;
  if (!graph) return bad("no graph");
  const [gs, ge] = graph as [number, number];
  let spec: any, format: any = null;
  try {
    spec = JSON.parse(metadata["nerf.ngp"]);
    if (metadata["nerf.grid_table"] !== undefined) format = JSON.parse(metadata["nerf.grid_table"]);
  } catch (e) { throw new Error(`${name}: nerf.ngp / nerf.grid_table metadata: ${(e as Error).message}`); }
  checkSpec(spec, name);
  if (format && format.layout !== 2) return { reason: `table layout ${format.layout} is not known here (layout 2 is)` };
  const b = spec.bound;
  if (b.contraction !== undefined && b.contraction !== null && b.contraction !== "linf") return { reason: `contraction ${JSON.stringify(b.contraction)} is not known here` };

  const nodes: NodeInfo[] = [], initializers = new Map<string, [number, number]>(), outputs: [string, number, number][] = [], inputs: string[] = [];
  let graphName = "";
  walk(gs, ge, (n, s, e) => {
    if (n === 1) {
      const node: NodeInfo = { inputs: [], outputs: [], start: s, end: e };
      walk(s, e, (k, a, b) => { if (k === 1) node.inputs.push(str(a, b)); else if (k === 2) node.outputs.push(str(a, b)); });
      nodes.push(node);
    } else if (n === 5) {
      let tensor = "";
      walk(s, e, (k, a, b) => { if (k === 8) tensor = str(a, b); });
      initializers.set(tensor, [s, e]);
    } else if (n === 11 || n === 12) {
      let value = "";
      walk(s, e, (k, a, b) => { if (k === 1) value = str(a, b); });
      if (n === 11) inputs.push(value); else outputs.push([value, s, e]);
    } else if (n === 2) graphName = str(s, e);
  });

  // The table and the level scales the graph computes with.
  const tensor = (tensorName: string) => {
    const at = initializers.get(tensorName);
    if (!at) return null;
    const t = { dims: [] as number[], type: 0, raw: null as Uint8Array | null };
    walk(at[0], at[1], (k, a, b) => {
      if (k === 1) t.dims.push(...packedVarints(bytes, a, b, bad));
      else if (k === 9) t.raw = bytes.subarray(a, b);
    }, (k, v) => { if (k === 1) t.dims.push(v); else if (k === 2) t.type = v; });
    return t;
  };
  const floats = (raw: Uint8Array, type: number): Float32Array | null => {
    // Copied: the model's bytes are not aligned for a typed view.
    const copy = raw.slice();
    if (type === 1) return new Float32Array(copy.buffer, 0, copy.length / 4);
    if (type === 10) return halfToFloat(new Uint16Array(copy.buffer, 0, copy.length / 2));
    return null;
  };
  const grid: HashGridConfig = spec.grid, F = grid.features_per_level;
  const scalesTensor = tensor("grid.level_scales");
  const scales = scalesTensor?.raw && scalesTensor.type === 1 && scalesTensor.raw.length === 4 * grid.levels ? floats(scalesTensor.raw, 1)! : undefined;
  const graphLayout = format !== null;
  const levels = levelLayout(grid, graphLayout, scales);
  const t = tensor("grid.table");
  if (!t || !t.raw) return { reason: "its table is not stored as raw data" };
  const rows = levels.reduce((sum, l) => sum + l.rows, 0);
  if (t.dims.length !== 2 || t.dims[0] !== rows || t.dims[1] !== F)
    throw new Error(`${name}: grid.table is [${t.dims.join(", ")}], the grid's layout needs [${rows}, ${F}]`);
  const table = floats(t.raw, t.type);
  if (!table || table.length !== rows * F) throw new Error(`${name}: grid.table holds ${t.raw.length} bytes of type ${t.type}, expected ${rows * F} float32 or float16 values`);

  // The head: walk back from the outputs, stopping at the two cuts (ngp.rs head_graph).
  const cuts = [FEATURES_TENSOR, SH_TENSOR];
  for (const cut of cuts) if (!nodes.some((nd) => nd.outputs.includes(cut))) return { reason: `no node computes ${cut}` };
  const needed = new Set(outputs.map(([o]) => o)), keep = new Array(nodes.length).fill(false);
  for (let k = nodes.length - 1; k >= 0; k--) {
    if (nodes[k].outputs.some((o) => needed.has(o))) {
      keep[k] = true;
      for (const i of nodes[k].inputs) if (i !== "" && !cuts.includes(i)) needed.add(i);
    }
  }
  const leak = inputs.find((i) => needed.has(i));
  if (leak) return { reason: `the outputs depend on ${leak} other than through ${FEATURES_TENSOR} and ${SH_TENSOR}` };
  const width = levels.length * F;
  const input = (tensorName: string, w: number) => {
    // ValueInfoProto { name, type: TypeProto { tensor_type { elem_type FLOAT, shape [N, w] } } }
    const dims = concatBytes([lengthDelimited(1, stringField(2, "N")), lengthDelimited(1, varintField(1, w))]);
    const type = lengthDelimited(1, concatBytes([varintField(1, 1), lengthDelimited(2, dims)]));
    return lengthDelimited(11, concatBytes([stringField(1, tensorName), lengthDelimited(2, type)]));
  };
  const head = concatBytes([
    ...nodes.filter((_, k) => keep[k]).map((nd) => lengthDelimited(1, bytes.subarray(nd.start, nd.end))),
    stringField(2, `${graphName}.head`),
    ...[...initializers].filter(([n]) => needed.has(n)).map(([, [s, e]]) => lengthDelimited(5, bytes.subarray(s, e))),
    input(FEATURES_TENSOR, width), input(SH_TENSOR, SH4_DIM),
    ...outputs.map(([, s, e]) => lengthDelimited(12, bytes.subarray(s, e))),
  ]);
  const boxScale = [0, 1, 2].map((d) => f(1 / f(b.max[d] - b.min[d])));
  const encoder = new HashEncoder(levels, F, table, b.min.map(f), boxScale, b.contraction === "linf");
  return { encoder, head: concatBytes([...model, lengthDelimited(7, head)]) };
}
