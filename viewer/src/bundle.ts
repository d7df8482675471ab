// scene.json and occupancy.bin of a scene bundle (formats nerf-rs-scene-1, -2 and -3, the last
// a contracted field's), as render_rays.py reads them: graph files by role, the bounded flag,
// the contraction, the occupancy grid (NERFOCC1, or NERFOCC2 over a contracted world).

import { CONTRACTED_HALF_SIZE } from "./contraction";
import type { Grid } from "./march";
import { ModelReader } from "./proto";

/** The format of a contracted field's scene.json, and only of one. */
export const SCENE_FORMAT_CONTRACTED = "nerf-rs-scene-3";

/** Whether scene.json's field is contracted ("contraction": "linf", the only one there is). */
export function isContracted(scene: any): boolean {
  const c = scene.contraction;
  if (c === undefined || c === null) return false;
  if (c !== "linf") throw new Error(`scene.json: contraction: ${JSON.stringify(c)} is unknown (this viewer knows "linf")`);
  return true;
}

/** A field defined inside its grid's box only: "bounded", or a version-1 hash-grid bundle. */
export function isBounded(scene: any): boolean {
  return scene.bounded === true || (scene.format === "nerf-rs-scene-1" && (scene.field ?? "mlp") === "ngp");
}

/** A file name from scene.json must be a plain name inside the bundle. */
function plainName(name: unknown, field: string): string {
  if (typeof name !== "string" || name === "" || name === "." || name === ".." || /[\/\\\0]/.test(name))
    throw new Error(`scene.json: ${field}: ${JSON.stringify(name)} is not a plain file name inside the bundle`);
  return name;
}

/** {role: file}: "graphs" by role, or nerf-rs-scene-1's "networks". */
export function graphFiles(scene: any): Record<string, string> {
  const out: Record<string, string> = {};
  if (scene.graphs && Object.keys(scene.graphs).length) {
    for (const [role, name] of Object.entries(scene.graphs)) out[role] = plainName(name, `graphs.${role}`);
    return out;
  }
  const nets = scene.networks;
  if (!nets || !nets.coarse) throw new Error("scene.json: neither graphs nor networks names a graph");
  out[isBounded(scene) ? "field" : "coarse"] = plainName(nets.coarse, "networks.coarse");
  if (nets.fine) out.fine = plainName(nets.fine, "networks.fine");
  return out;
}

/** Checks of the fields the renderer relies on (a subset of check_scene), with readable messages. */
export function checkScene(scene: any): void {
  const need = (ok: boolean, msg: string) => { if (!ok) throw new Error(`scene.json: ${msg}`); };
  need(scene && typeof scene === "object", "not a JSON object");
  need(scene.camera && scene.camera.width > 0 && scene.camera.height > 0, "camera: missing width/height");
  const s = scene.sampling;
  need(s && Number.isFinite(s.near) && Number.isFinite(s.far) && s.near < s.far, "sampling: need finite near < far");
  need(s.n_coarse >= 1 && s.n_fine >= 0 && s.n_coarse + s.n_fine <= 4096, "sampling: n_coarse + n_fine outside 1..4096");
  const steps = scene.march_steps ?? 256;
  need(steps >= 1 && steps <= 4096, `march_steps: ${steps} is outside 1..4096`);
  need(!isBounded(scene) || !!scene.occupancy, "occupancy: a bounded field needs its occupancy grid");
  // A reader that marched a contracted field as an uncontracted one would draw it wrong: the two
  // go together (bundle/src/scene.rs).
  const contracted = isContracted(scene);
  need(contracted === (scene.format === SCENE_FORMAT_CONTRACTED),
    `contraction: ${JSON.stringify(scene.contraction ?? null)} with format ${JSON.stringify(scene.format)}: a contracted field is ${SCENE_FORMAT_CONTRACTED}, and only it`);
  need(!contracted || !scene.occupancy || scene.occupancy.bound === CONTRACTED_HALF_SIZE,
    `occupancy: a contracted grid covers [-2, 2]^3, scene.json says bound ${scene.occupancy?.bound}`);
  need(!!scene.poses, "poses: missing");
}

/** occupancy.bin: "NERFOCC1", u32 resolution, f32 bound, f32 threshold, then R³ f32 densities;
 *  or "NERFOCC2" (a contracted world): the same, then u32 contraction (1: L∞) before the cells
 *  (24 header bytes), bound 2. */
export function parseGrid(buf: ArrayBuffer): Grid {
  const bytes = new Uint8Array(buf);
  const magic = String.fromCharCode(...bytes.subarray(0, 8));
  const contracted = magic === "NERFOCC2" && buf.byteLength >= 24;
  if (!contracted && (buf.byteLength < 20 || magic !== "NERFOCC1")) throw new Error("occupancy.bin: not an occupancy grid (missing NERFOCC1 or NERFOCC2 header)");
  const view = new DataView(buf), header = contracted ? 24 : 20;
  const res = view.getUint32(8, true), bound = view.getFloat32(12, true), threshold = view.getFloat32(16, true);
  if (res < 1 || res > 512) throw new Error(`occupancy.bin: resolution ${res} is outside 1..512`);
  if (contracted) checkContractedHeader(view.getUint32(20, true), bound);
  const want = header + 4 * res ** 3;
  if (buf.byteLength !== want) throw new Error(`occupancy.bin: ${buf.byteLength} bytes, expected ${want} for a ${res}³ grid (truncated?)`);
  const occupied = new Uint8Array(res ** 3);
  for (let i = 0; i < occupied.length; i++) occupied[i] = view.getFloat32(header + 4 * i, true) > threshold ? 1 : 0;
  return contracted ? { res, bound, occupied, contracted } : { res, bound, occupied };
}

/** A NERFOCC2 header's contraction and bound, as core/src/sample/occupancy.rs checks them. */
function checkContractedHeader(contraction: number, bound: number): void {
  if (contraction !== 1) throw new Error(`occupancy.bin: unknown contraction ${contraction} in the NERFOCC2 header (this viewer knows 1: L-infinity)`);
  if (bound !== CONTRACTED_HALF_SIZE) throw new Error(`occupancy.bin: a contracted grid covers [-2, 2]^3, the header says bound ${bound}`);
}

/** The grid file must be contracted exactly when scene.json's field is (bundle/src/lib.rs). */
export function checkGridContraction(scene: any, grid: Grid): void {
  const name = (c: boolean) => (c ? '"linf"' : "none");
  const contracted = isContracted(scene);
  if (!!grid.contracted !== contracted)
    throw new Error(`scene.json: occupancy: the grid file's contraction is ${name(!!grid.contracted)}, scene.json's ${name(contracted)}`);
}

/** The grid a bounded field is marched through without occupancy.bin (--dense): one occupied
 *  cell over its box, or over the whole contracted world (every step of every segment). */
export function wholeBox(bound: number, contracted = false): Grid {
  if (contracted) return { res: 1, bound: CONTRACTED_HALF_SIZE, occupied: new Uint8Array([1]), contracted };
  return { res: 1, bound, occupied: new Uint8Array([1]) };
}

/** What a consumer needs to know about an ONNX graph before picking where to run it. */
export interface GraphInfo {
  /** The operator types of the main graph's nodes. */
  ops: Set<string>;
  /** Whether an initializer is float16 (a hash grid's table stored in float16). */
  float16: boolean;
  /** metadata_props (nerf.hash_lowering, nerf.grid_table, …). */
  metadata: Record<string, string>;
}

/** Reads the parts of an ONNX ModelProto GraphInfo names, walking the protobuf wire format
 *  (ModelProto.graph = 7, metadata_props = 14; GraphProto.node = 1, initializer = 5;
 *  NodeProto.op_type = 4; TensorProto.data_type = 2, FLOAT16 = 10) and skipping the rest by
 *  length, so the weights are never decoded. `name` goes into the error of a malformed file. */
export function graphInfo(bytes: Uint8Array, name: string): GraphInfo {
  const info: GraphInfo = { ops: new Set(), float16: false, metadata: {} };
  const reader = new ModelReader(bytes, name), { walk, str, bad } = reader;
  walk(0, bytes.length, (n, s, e) => {
    if (n === 14) {
      const [key, value] = reader.entry(s, e);
      info.metadata[key] = value;
    } else if (n === 7) {
      walk(s, e, (m, a, b) => {
        if (m === 1) walk(a, b, (k, c, d) => { if (k === 4) info.ops.add(str(c, d)); });
        else if (m === 5) walk(a, b, () => {}, (k, v) => { if (k === 2 && v === 10) info.float16 = true; });
      });
    }
  });
  if (info.ops.size === 0) bad("no graph nodes");
  return info;
}
