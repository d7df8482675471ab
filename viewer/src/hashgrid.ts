// The hash-grid encoding of an `ngp` field graph, evaluated here so that onnxruntime-web runs
// only the graph's head (the MLPs): what nerf-render does with the core's Rust encoding
// (runtime/src/network.rs), for the same reason (onnxruntime's gathers of the table's rows are
// the slow part of the whole graph). The encoding is core/src/field/ngp/hash_grid's and
// spherical_harmonics.rs's, evaluated in WebAssembly (assembly/hashgrid.ts): the unit point and
// each level's corner positions in float32 as Rust computes them, so the same corners are read;
// the trilinear weights and their sum in float64, rounded to float32 once (the features differ
// from Rust's by float32 rounding). The head is cut from the bundle's own graph
// (bundle/src/ngp.rs head_graph), node for node.

import { BASE, Layout, instantiate, reserve } from "./wasm";
import { ModelReader, concatBytes, lengthDelimited, packedVarints, stringField, varintField } from "./proto";

const f = Math.fround;

/** The graph's tensors the head starts from (bundle/src/ngp.rs FEATURES_TENSOR, SH_TENSOR). */
export const FEATURES_TENSOR = "grid.features";
export const SH_TENSOR = "sh.output";
/** Degree-4 spherical harmonics per direction. */
export const SH4_DIM = 16;

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

/** assembly/hashgrid.ts's exports (pointers are byte offsets into its memory). */
interface Exports {
  setGrid(table: number, levels: number, features: number, scales: number, resolutions: number, entries: number, dense: number, rows: number,
    min0: number, min1: number, min2: number, scale0: number, scale1: number, scale2: number, contracted: boolean): void;
  encode(points: number, viewdirs: number, n: number, unit: number, features: number, sh: number): void;
}

/** A graph's hash grid and the box it covers (GridBound), evaluated as the Rust encoding, in
 *  WebAssembly (assembly/hashgrid.ts): the table is copied into the instance's memory at the
 *  first call, each call's points in and its features out. */
export class HashEncoder {
  /** Features per point, L·F. */
  readonly width: number;
  private wasm: (Exports & { memory: WebAssembly.Memory }) | null = null;
  /** Where the table and levels end; the current call buffers' room (points) and offsets. */
  private top = 0;
  private room = 0;
  private call = { points: 0, viewdirs: 0, unit: 0, features: 0, sh: 0 };

  constructor(readonly levels: Level[], readonly features: number, readonly table: Float32Array,
    readonly min: number[], readonly scale: number[], readonly contracted: boolean) {
    this.width = levels.length * features;
  }

  /** features [n, L·F] (row-major, level-major within a row) and the harmonics [n, 16] of
   *  world `points` [n, 3] and unit `viewdirs` [n, 3]. */
  encode(points: Float32Array, viewdirs: Float32Array, n: number, features: Float32Array, sh: Float32Array): void {
    const x = this.instance(n), c = this.call, buf = () => x.memory.buffer;
    new Float32Array(buf(), c.points, 3 * n).set(points.subarray(0, 3 * n));
    new Float32Array(buf(), c.viewdirs, 3 * n).set(viewdirs.subarray(0, 3 * n));
    x.encode(c.points, c.viewdirs, n, c.unit, c.features, c.sh);
    features.set(new Float32Array(buf(), c.features, this.width * n));
    sh.set(new Float32Array(buf(), c.sh, SH4_DIM * n));
  }

  /** The instance, made at the first call (an encoder that never encodes holds no copy of the
   *  table), with room for calls of `n` points. */
  private instance(n: number): Exports & { memory: WebAssembly.Memory } {
    let x = this.wasm;
    if (!x) {
      x = instantiate<Exports>("hashgrid");
      const L = this.levels.length, at = new Layout(BASE), table = at.take(4 * this.table.length);
      const scales = at.take(4 * L), resolutions = at.take(4 * L), entries = at.take(4 * L), dense = at.take(4 * L), rows = at.take(4 * L);
      reserve(x.memory, at.top, "the hash grid's table");
      const buf = x.memory.buffer;
      new Float32Array(buf, table, this.table.length).set(this.table);
      new Float32Array(buf, scales, L).set(this.levels.map((v) => v.scale));
      new Int32Array(buf, resolutions, L).set(this.levels.map((v) => v.resolution));
      new Int32Array(buf, entries, L).set(this.levels.map((v) => v.entries));
      new Int32Array(buf, dense, L).set(this.levels.map((v) => (v.dense ? 1 : 0)));
      new Int32Array(buf, rows, L).set(this.levels.map((v) => v.row));
      const [m0, m1, m2] = this.min.map(f), [s0, s1, s2] = this.scale.map(f);
      x.setGrid(table, L, this.features, scales, resolutions, entries, dense, rows, m0, m1, m2, s0, s1, s2, this.contracted);
      this.wasm = x; this.top = at.top;
    }
    if (n > this.room) {
      const room = Math.max(n, 1024), at = new Layout(this.top);
      this.call = { points: at.take(12 * room), viewdirs: at.take(12 * room), unit: at.take(12 * room), features: at.take(4 * this.width * room),
        sh: at.take(4 * SH4_DIM * room) };
      reserve(x.memory, at.top, "the hash grid's calls");
      this.room = room;
    }
    return x;
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
