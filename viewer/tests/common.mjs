// Helpers shared by the browser tests: the native renderer's frames and how far a page's frame
// is from one, and a free loopback port.
import assert from "node:assert/strict";
import { execFileSync } from "node:child_process";
import { mkdtempSync, readFileSync, rmSync } from "node:fs";
import { createServer } from "node:net";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";

export const REPO = resolve(import.meta.dirname, "../..");

/** float32 [H, W, C] from a .npy file (format versions 1–3, little-endian f4, C order). */
export function readNpy(path) {
  const buf = readFileSync(path);
  assert.equal(buf.subarray(0, 6).toString("latin1"), "\x93NUMPY");
  const v = buf[6], len = v === 1 ? buf.readUInt16LE(8) : buf.readUInt32LE(8), start = v === 1 ? 10 : 12;
  const header = buf.subarray(start, start + len).toString("latin1");
  assert.match(header, /'descr': '<f4'/);
  assert.match(header, /'fortran_order': False/);
  const shape = header.match(/'shape': \(([^)]*)\)/)[1].split(",").filter((s) => s.trim()).map(Number);
  const data = new Float32Array(buf.buffer.slice(buf.byteOffset + start + len, buf.byteOffset + buf.length));
  return { shape, data };
}

/** Run nerf-render with `args` (NERF_RENDER, else $CARGO_TARGET_DIR/release/nerf-render after
 * scripts/env.sh); its stdout. */
export function nerfRender(args) {
  const bin = process.env.NERF_RENDER;
  if (bin) return execFileSync(bin, args, { stdio: "pipe" }).toString();
  return execFileSync("bash", ["-c", '. scripts/env.sh && exec "$CARGO_TARGET_DIR/release/nerf-render" "$@"', "nerf-render", ...args], { cwd: REPO, stdio: "pipe" }).toString();
}

/** nerf-render's exact output for test pose 0 at width (height keeps the aspect): [H, W, 5]. */
export function nativeFrame(bundle, width, dense) {
  const out = mkdtempSync(join(tmpdir(), "nerf-native-"));
  try {
    nerfRender(["--bundle", bundle, "--split", "test", "--limit", "1", "--width", String(width), "--out", out, "--npy", ...(dense ? ["--dense"] : [])]);
    return readNpy(join(out, "r_0.npy"));
  } finally { rmSync(out, { recursive: true, force: true }); }
}

/** nerf-render's exact output for each of scene.json's test poses, at `width` (default: the
 * camera's size): [{ name, frame: [H, W, 5] }] in pose order. */
export function nativeTestFrames(bundle, width) {
  const out = mkdtempSync(join(tmpdir(), "nerf-native-"));
  try {
    nerfRender(["--bundle", bundle, "--split", "test", "--out", out, "--npy", ...(width ? ["--width", String(width)] : [])]);
    const poses = JSON.parse(readFileSync(join(bundle, "scene.json"), "utf8")).poses.test;
    return poses.map((p) => ({ name: p.name, frame: readNpy(join(out, `${p.name}.npy`)) }));
  } finally { rmSync(out, { recursive: true, force: true }); }
}

/** A page's rgb [H·W·3] against a native [H, W, C] frame: { maxDiff, psnr }. */
export function frameError(rgb, native) {
  const [h, w, c] = native.shape;
  assert.equal(rgb.length, h * w * 3);
  let maxDiff = 0, se = 0;
  for (let p = 0; p < h * w; p++) for (let k = 0; k < 3; k++) {
    const e = rgb[3 * p + k] - native.data[c * p + k];
    maxDiff = Math.max(maxDiff, Math.abs(e)); se += e * e;
  }
  return { maxDiff, psnr: 10 * Math.log10(1 / Math.max(se / (h * w * 3), 1e-30)) };
}

export async function freePort() {
  const s = createServer();
  await new Promise((ok) => s.listen(0, "127.0.0.1", ok));
  const port = s.address().port;
  await new Promise((ok) => s.close(ok));
  return port;
}
