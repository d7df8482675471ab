// scene.json and occupancy.bin of a scene bundle (formats nerf-rs-scene-1 and -2), as
// render_rays.py reads them: graph files by role, the bounded flag, the occupancy grid.

import type { Grid } from "./render";

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
  need(!!scene.poses, "poses: missing");
}

/** occupancy.bin: "NERFOCC1", u32 resolution, f32 bound, f32 threshold, then R³ f32 densities. */
export function parseGrid(buf: ArrayBuffer): Grid {
  const bytes = new Uint8Array(buf);
  const magic = String.fromCharCode(...bytes.subarray(0, 8));
  if (buf.byteLength < 20 || magic !== "NERFOCC1") throw new Error("occupancy.bin: not an occupancy grid (missing NERFOCC1 header)");
  const view = new DataView(buf);
  const res = view.getUint32(8, true), bound = view.getFloat32(12, true), threshold = view.getFloat32(16, true);
  if (res < 1 || res > 512) throw new Error(`occupancy.bin: resolution ${res} is outside 1..512`);
  const want = 20 + 4 * res ** 3;
  if (buf.byteLength !== want) throw new Error(`occupancy.bin: ${buf.byteLength} bytes, expected ${want} for a ${res}³ grid (truncated?)`);
  const occupied = new Uint8Array(res ** 3);
  for (let i = 0; i < occupied.length; i++) occupied[i] = view.getFloat32(20 + 4 * i, true) > threshold ? 1 : 0;
  return { res, bound, occupied };
}

/** The grid a bounded field is marched through without occupancy.bin (--dense): one occupied cell. */
export function wholeBox(bound: number): Grid {
  return { res: 1, bound, occupied: new Uint8Array([1]) };
}
