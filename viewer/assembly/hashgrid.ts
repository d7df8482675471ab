// The hash grid of an `ngp` field (src/hashgrid.ts's HashEncoder) in WebAssembly: the unit
// point, each level's corners and trilinear weights and the degree-4 harmonics of
// core/src/field/ngp/hash_grid and spherical_harmonics.rs, with the arithmetic of the
// TypeScript it replaced: positions and corners in f32 as Rust computes them, the weights and
// their sum in f64 rounded to f32 once. Why WebAssembly: see assembly/march.ts.
//
// Memory is laid out by src/hashgrid.ts: the table and the levels once (setGrid), a call's
// inputs and outputs above them.

import { contractionFactor } from "./contraction";
import { f32At, i32At, setF32 } from "./memory";

/** tiny-cuda-nn's hash primes y, z (x's is 1), as i32 (products wrap as Math.imul's). */
const PRIME_Y: i32 = <i32>2654435761, PRIME_Z: i32 = 805459861;

// The table's rows (F f32 each); per level its scale (f32), resolution, entries, whether it is
// dense (0/1) and its first row (i32 each); the box: min and scale per axis; L, F.
let TABLE: usize = 0, SCALES: usize = 0, RESOLUTIONS: usize = 0, ENTRIES: usize = 0, DENSE: usize = 0, ROWS: usize = 0;
let LEVELS: i32 = 0, F: i32 = 0, CONTRACTED = false;
let MIN0: f32 = 0, MIN1: f32 = 0, MIN2: f32 = 0, SCALE0: f32 = 0, SCALE1: f32 = 0, SCALE2: f32 = 0;

/** The grid every later call encodes: the table, `levels` levels (arrays of that length: scale,
 *  resolution, entries, dense, first row), `features` per level; the box's min and scale
 *  (GridBound::to_unit); `contracted` where the field contracts its input first. */
export function setGrid(table: usize, levels: i32, features: i32, scales: usize, resolutions: usize, entries: usize, dense: usize, rows: usize,
  min0: f32, min1: f32, min2: f32, scale0: f32, scale1: f32, scale2: f32, contracted: bool): void {
  TABLE = table; LEVELS = levels; F = features; SCALES = scales; RESOLUTIONS = resolutions; ENTRIES = entries; DENSE = dense; ROWS = rows;
  MIN0 = min0; MIN1 = min1; MIN2 = min2; SCALE0 = scale0; SCALE1 = scale1; SCALE2 = scale2; CONTRACTED = contracted;
}

/** features [n, L·F] (row-major, level-major within a row) and the harmonics [n, 16] of world
 *  `points` [n, 3] and unit `viewdirs` [n, 3] (pointers; `unit` [n, 3] is scratch). */
export function encode(points: usize, viewdirs: usize, n: i32, unit: usize, features: usize, sh: usize): void {
  toUnit(points, n, unit);
  // Level by level, so a level's part of the table is reused from cache across the points.
  for (let l = 0; l < LEVELS; l++) encodeLevel(l, unit, n, features);
  for (let i = 0; i < n; i++) sh4(viewdirs + (<usize>(3 * i) << 2), sh + (<usize>(16 * i) << 2));
}

/** GridBound::to_unit: contracted first where the field is, then (p − min)·scale. */
function toUnit(points: usize, n: i32, unit: usize): void {
  for (let i = 0; i < n; i++) {
    let x = f32At(points, 3 * i), y = f32At(points, 3 * i + 1), z = f32At(points, 3 * i + 2);
    if (CONTRACTED) { const k = contractionFactor(x, y, z); x = x * k; y = y * k; z = z * k; }
    setF32(unit, 3 * i, (x - MIN0) * SCALE0); setF32(unit, 3 * i + 1, (y - MIN1) * SCALE1); setF32(unit, 3 * i + 2, (z - MIN2) * SCALE2);
  }
}

/** One level of every point (grid.rs corners and forward_level), the 8 corners unrolled. */
function encodeLevel(l: i32, unit: usize, n: i32, out: usize): void {
  const scale = f32At(SCALES, l), r = i32At(RESOLUTIONS, l), entries = i32At(ENTRIES, l), dense = i32At(DENSE, l) != 0;
  const features = F, width = LEVELS * F, t = TABLE, mask = entries - 1, base = i32At(ROWS, l) * features;
  // Per axis, the corner terms: x·1, y·res, z·res² (dense) or the hash's x·1, y·P1, z·P2.
  const sy = dense ? r : PRIME_Y, sz = dense ? r * r : PRIME_Z;
  for (let i = 0; i < n; i++) {
    // Clamped to [0, 1] (NaN to 0, as f32::max); pos ≥ 0.5, so truncation is the floor.
    let u = f32At(unit, 3 * i), v = f32At(unit, 3 * i + 1), w = f32At(unit, 3 * i + 2);
    u = (u > 0 ? (u < 1 ? u : <f32>1) : <f32>0) * scale + <f32>0.5;
    v = (v > 0 ? (v < 1 ? v : <f32>1) : <f32>0) * scale + <f32>0.5;
    w = (w > 0 ? (w < 1 ? w : <f32>1) : <f32>0) * scale + <f32>0.5;
    const cx = <i32>u, cy = <i32>v, cz = <i32>w;
    const fx = <f64>u - <f64>cx, fy = <f64>v - <f64>cy, fz = <f64>w - <f64>cz, gx = 1 - fx, gy = 1 - fy, gz = 1 - fz;
    const x0 = cx, x1 = cx + 1, y0 = cy * sy, y1 = (cy + 1) * sy, z0 = cz * sz, z1 = (cz + 1) * sz;
    // Corner k = (bx, by, bz) = bits 0, 1, 2; weight wx · wy · wz (f64 from here on).
    const w00 = gx * gy, w10 = fx * gy, w01 = gx * fy, w11 = fx * fy;
    const k0 = w00 * gz, k1 = w10 * gz, k2 = w01 * gz, k3 = w11 * gz, k4 = w00 * fz, k5 = w10 * fz, k6 = w01 * fz, k7 = w11 * fz;
    let e0: i32, e1: i32, e2: i32, e3: i32, e4: i32, e5: i32, e6: i32, e7: i32;
    if (dense) {
      // An entry below 2·entries, modulo entries: one subtraction (the graph's padded rows hold
      // the same value there too).
      e0 = x0 + y0 + z0; e1 = x1 + y0 + z0; e2 = x0 + y1 + z0; e3 = x1 + y1 + z0;
      e4 = x0 + y0 + z1; e5 = x1 + y0 + z1; e6 = x0 + y1 + z1; e7 = x1 + y1 + z1;
      if (e0 >= entries) e0 -= entries; if (e1 >= entries) e1 -= entries; if (e2 >= entries) e2 -= entries; if (e3 >= entries) e3 -= entries;
      if (e4 >= entries) e4 -= entries; if (e5 >= entries) e5 -= entries; if (e6 >= entries) e6 -= entries; if (e7 >= entries) e7 -= entries;
    } else {
      e0 = (x0 ^ y0 ^ z0) & mask; e1 = (x1 ^ y0 ^ z0) & mask; e2 = (x0 ^ y1 ^ z0) & mask; e3 = (x1 ^ y1 ^ z0) & mask;
      e4 = (x0 ^ y0 ^ z1) & mask; e5 = (x1 ^ y0 ^ z1) & mask; e6 = (x0 ^ y1 ^ z1) & mask; e7 = (x1 ^ y1 ^ z1) & mask;
    }
    e0 = base + e0 * features; e1 = base + e1 * features; e2 = base + e2 * features; e3 = base + e3 * features;
    e4 = base + e4 * features; e5 = base + e5 * features; e6 = base + e6 * features; e7 = base + e7 * features;
    const o = i * width + l * features;
    for (let q = 0; q < features; q++) {
      const s = k0 * <f64>f32At(t, e0 + q) + k1 * <f64>f32At(t, e1 + q) + k2 * <f64>f32At(t, e2 + q) + k3 * <f64>f32At(t, e3 + q)
        + k4 * <f64>f32At(t, e4 + q) + k5 * <f64>f32At(t, e5 + q) + k6 * <f64>f32At(t, e6 + q) + k7 * <f64>f32At(t, e7 + q);
      setF32(out, o + q, <f32>s);
    }
  }
}

// SH4_CONSTANTS of spherical_harmonics.rs, as f32.
const C0: f32 = 0.2820948, C1: f32 = 0.4886025, C2: f32 = 1.0925484, C3: f32 = 0.9461747, C4: f32 = 0.31539157, C5: f32 = 0.5462742;
const C6: f32 = 0.5900436, C7: f32 = 2.8906114, C8: f32 = 0.4570458, C9: f32 = 0.3731763, C10: f32 = 1.4453057;

/** The degree-4 harmonics of the unit direction at `dir` (3 f32) into `out` (16 f32). */
function sh4(dir: usize, out: usize): void {
  const x = load<f32>(dir), y = load<f32>(dir, 4), z = load<f32>(dir, 8);
  const xy = x * y, yz = y * z, xz = x * z, x2 = x * x, y2 = y * y, z2 = z * z;
  store<f32>(out, C0);
  store<f32>(out, -C1 * y, 4);
  store<f32>(out, C1 * z, 8);
  store<f32>(out, -C1 * x, 12);
  store<f32>(out, C2 * xy, 16);
  store<f32>(out, -C2 * yz, 20);
  store<f32>(out, C3 * z2 - C4, 24);
  store<f32>(out, -C2 * xz, 28);
  store<f32>(out, C5 * x2 - C5 * y2, 32);
  store<f32>(out, (C6 * y) * (<f32>-3 * x2 + y2), 36);
  store<f32>(out, (C7 * xy) * z, 40);
  store<f32>(out, (C8 * y) * (<f32>1 - <f32>5 * z2), 44);
  store<f32>(out, (C9 * z) * (<f32>5 * z2 - <f32>3), 48);
  store<f32>(out, (C8 * x) * (<f32>1 - <f32>5 * z2), 52);
  store<f32>(out, (C10 * z) * (x2 - y2), 56);
  store<f32>(out, (C6 * x) * (-x2 + <f32>3 * y2), 60);
}

/** Where this module's own static data ends: the caller's arrays start above it. */
export function heapBase(): usize { return __heap_base; }
