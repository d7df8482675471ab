// Contracted bundles (nerf-rs-scene-3): the contraction and the marching segments against values
// worked out by hand (float32, as core/src/sample/contraction.rs and core/src/render/grid.rs),
// the contracted marcher against testing every step of every segment one ray at a time (as
// grid.rs's march_ray_every_interval), a marched render against compositing those samples, and
// NERFOCC2 / scene.json parsing and refusals.
import { readFileSync } from "node:fs";
import { join } from "node:path";
import { describe, expect, it } from "vitest";
import { checkGridContraction, checkScene, isContracted, parseGrid, wholeBox } from "../../src/bundle";
import { norm3 } from "../../src/camera";
import { ContractedMarch } from "../../src/marcher";
import { MAX_SEGMENTS, type Segment, contract, marchSegments } from "../../src/contraction";
import { type Grid, isOccupied } from "../../src/march";
import { type Field, renderMarch } from "../../src/render";

const f = Math.fround;
const FIXTURE = join(import.meta.dirname, "../fixtures/ngp-contracted");

/** A seeded uniform draw in [0, 1) (Park–Miller). */
function rng(seed: number) {
  let s = seed;
  return () => (s = (s * 16807) % 2147483647) / 2147483647;
}

describe("the L∞ contraction", () => {
  it("matches hand-computed float32 values", () => {
    const f3 = (p: number[]) => p.map(f);
    // Inside the unit cube: unchanged, bit for bit.
    expect(contract(f3([0.3, -1, 0.999]))).toEqual(f3([0.3, -1, 0.999]));
    // ‖x‖∞ = 2: f = (2 − 0.5)·0.5 = 0.75; ‖x‖∞ = 4: f = 1.75·0.25 = 0.4375.
    expect(contract([2, -1, 0.5])).toEqual([1.5, -0.75, 0.375]);
    expect(contract([0, 0, -4])).toEqual([0, 0, -1.75]);
    // ‖x‖∞ = 3: r = f32(1/3), f = f32(f32(2 − r)·r) = 0.5555555820465088 (not 5/9 in f64).
    expect(contract(f3([3, 0.1, 0]))).toEqual([1.6666667461395264, 0.055555559694767, 0]);
    expect(contract(f3([1.5, -0.25, 1.25]))).toEqual([1.3333332538604736, -0.2222222089767456, 1.111111044883728]);
    expect(contract(f3([-7.3, 2.2, 0.4]))).toEqual([-1.863013744354248, 0.5614562034606934, 0.10208294540643692]);
    // Far away: towards the face at 2; past ≈ 10⁷ onto it, never past it.
    expect(contract([1e3, 5e2, 0])).toEqual([1.999000072479248, 0.999500036239624, 0]);
    expect(contract([1e30, -1e30, 0])).toEqual([2, -2, 0]);
    expect(contract([NaN, 0, 0])[0]).toBeNaN();
  });

  it("finds the cells of contracted points (occupancy.rs's hand-worked cells)", () => {
    // 4 cells per axis over ±2, cell side 1: (3, 0, 0) → (1.667, 0, 0) → cell (3, 2, 2);
    // (0.5, −1.5, 0) → f = 8/9 → (0.444, −1.333, 0) → (2, 0, 2); (−1e20, 0, 1e19) → (0, 2, 2).
    for (const [p, cell] of [[[3, 0, 0], [3, 2, 2]], [[0.5, -1.5, 0], [2, 0, 2]], [[-1e20, 0, 1e19], [0, 2, 2]], [[0.5, 0.5, 0.5], [2, 2, 2]]]) {
      const occupied = new Uint8Array(64);
      occupied[(cell[0] * 4 + cell[1]) * 4 + cell[2]] = 1;
      const g: Grid = { res: 4, bound: 2, occupied, contracted: true };
      expect(isOccupied(g, p[0], p[1], p[2]), `${p}`).toBe(true);
      expect(isOccupied({ ...g, occupied: occupied.map((v) => 1 - v) }, p[0], p[1], p[2]), `${p}`).toBe(false);
    }
    // Uncontracted, (3, 0, 0) lies outside the same cube.
    expect(isOccupied({ res: 4, bound: 2, occupied: new Uint8Array(64).fill(1) }, 3, 0, 0)).toBe(false);
  });
});

describe("marching segments", () => {
  it("grow 4× a segment from near while they start before far", () => {
    // 1024 steps → segments of 256; the first interval 2/256; starts 0.1, 2.1, 10.1, 42.1,
    // 170.1 in f32 (the next, 682.1, lies past far = 200).
    const s = marchSegments(0.1, 200, 1024, true);
    expect(s.map((g) => g.interval)).toEqual([0.0078125, 0.03125, 0.125, 0.5, 2]);
    expect(s.map((g) => g.start)).toEqual([0.10000000149011612, 2.0999999046325684, 10.100000381469727, 42.099998474121094, 170.10000610351562]);
    expect(s.every((g) => g.steps === 256)).toBe(true);
    // The fixture's: near 0.033333335, far 100, 512 steps → 4 segments of 128.
    expect(marchSegments(0.033333335, 100, 512, true)).toEqual([
      { start: 0.03333333507180214, interval: 0.015625, steps: 128 }, { start: 2.0333333015441895, interval: 0.0625, steps: 128 },
      { start: 10.033332824707031, interval: 0.25, steps: 128 }, { start: 42.03333282470703, interval: 1, steps: 128 }]);
    // At least one interval a segment; at most MAX_SEGMENTS; a NaN far stops after the first.
    expect(marchSegments(0.5, 3, 3, true)).toEqual([{ start: 0.5, interval: 2, steps: 1 }, { start: 2.5, interval: 8, steps: 1 }]);
    expect(marchSegments(0, Infinity, 2, true).length).toBe(MAX_SEGMENTS);
    expect(marchSegments(0, NaN, 8, true).length).toBe(1);
    // Uncontracted: one segment of equal intervals over [near, far].
    expect(marchSegments(0.1, 200, 1024, false)).toEqual([{ start: f(0.1), interval: f(f(200 - f(0.1)) / 1024), steps: 1024 }]);
  });
});

/** 32³ cells over the contracted cube ±2: occupied cells in a third of the 4³-cell blocks, a
 *  fifth of those blocks' cells, so the inner cube and the shell both hold empty blocks. */
function sparseContracted(seed: number): Grid {
  const u = rng(seed), R = 32, chosen = Array.from({ length: 512 }, () => u() < 0.35), occupied = new Uint8Array(R ** 3);
  for (let c = 0; c < R ** 3; c++) {
    const b = (Math.floor(c / (R * R) / 4) * 8 + Math.floor(((c / R) | 0) % R / 4)) * 8 + Math.floor((c % R) / 4);
    occupied[c] = chosen[b] && u() < 0.2 ? 1 : 0;
  }
  return { res: R, bound: 2, occupied, contracted: true };
}

/** One ray at a time, every step of every segment tested with isOccupied: [t, interval] kept. */
function everyStep(g: Grid, segments: Segment[], o: number[], d: number[]): [number, number][] {
  const out: [number, number][] = [];
  for (const s of segments) for (let k = 0; k < s.steps; k++) {
    const t = f(s.start + f(f(k + 0.5) * s.interval));
    if (isOccupied(g, f(o[0] + f(t * d[0])), f(o[1] + f(t * d[1])), f(o[2] + f(t * d[2])))) out.push([t, s.interval]);
  }
  return out;
}

type Ray = [number[], number[]];

/** The marcher's samples per ray, `chunk` at a time, with the positions it wrote checked. */
function marched(g: Grid, segments: Segment[], list: Ray[], chunk: number) {
  const o = Float32Array.from(list.flatMap((r) => r[0])), d = Float32Array.from(list.flatMap((r) => r[1]));
  const m = new ContractedMarch(g, o, d, segments), pts = new Float32Array(3 * chunk), ks = new Int32Array(chunk);
  const rays = list.map((_, r) => {
    const all: [number, number][] = [];
    for (;;) {
      const c = m.next(r, chunk, pts, ks, 0);
      for (let i = 0; i < c; i++) {
        const t = m.t[ks[i]];
        for (let a = 0; a < 3; a++) expect(pts[3 * i + a]).toBe(f(o[3 * r + a] + f(t * d[3 * r + a])));
        all.push([t, m.interval[ks[i]]]);
      }
      if (c < chunk) break;
    }
    return all;
  });
  return { rays, tested: m.tested };
}

/** The marcher and the every-step reference take the same samples; returns their count and the tests made. */
function same(g: Grid, list: Ray[], near: number, far: number, steps: number, chunk = 16) {
  const segments = marchSegments(near, far, steps, true);
  const f32 = list.map(([o, d]): Ray => [o.map(f), d.map(f)]);
  const got = marched(g, segments, f32, chunk), wrong: string[] = [];
  let samples = 0;
  f32.forEach(([o, d], r) => {
    const want = everyStep(g, segments, o, d);
    samples += want.length;
    if (want.join() !== got.rays[r].join()) wrong.push(`ray ${r} o ${o} d ${d}: ${got.rays[r].length} samples, want ${want.length}`);
  });
  expect(wrong.slice(0, 5)).toEqual([]);
  return { samples, tested: got.tested };
}

describe("marching a contracted grid", () => {
  it("takes the samples of testing every step of every segment on random rays", () => {
    for (const seed of [1, 2]) {
      const g = sparseContracted(seed), u = rng(200 + seed), s = () => u() * 2 - 1;
      // Cameras inside the inner cube looking anywhere, and from far outside it.
      const list: Ray[] = Array.from({ length: 800 }, (_, i) => [
        i % 4 === 0 ? [s() * 30, s() * 30, s() * 30] : [s(), s(), s()], [s() * 1.3, s() * 1.3, s() * 1.3]]);
      const segments = marchSegments(0.05, 200, 256, true);
      const { samples } = same(g, list, 0.05, 200, 256, [16, 5][seed - 1]);
      expect(samples).toBeGreaterThan(10_000);
      const far = list.reduce((n, [o, d]) => n + everyStep(g, segments, o.map(f), d.map(f)).filter(([t]) => t > 10).length, 0);
      expect(far, "the shell is marched").toBeGreaterThan(1000);
    }
  }, 60_000);

  it("takes the same samples along the inner cube's faces and edges and through cell corners", () => {
    const g = sparseContracted(5), u = rng(9), below = (n: number) => Math.floor(u() * n), cell = 0.125;
    const list: Ray[] = [
      [[-0.5, 1, 0.2], [1, 0, 0]], [[1, 1, -3], [0, 0, 1]], [[0, 0, 0], [1, 1, 1]],
      [[0.999, -0.3, 0], [0.001, 0, -1]], [[0, 0, 0], [0, 0, 0]], [[-3, 0.1, 0.2], [NaN, 0, 0]], [[-3, 0.1, 0.2], [Infinity, 1, 0]],
    ];
    // Along each face of the inner cube, on it and just off it, straight and at a tiny slope.
    for (let i = 0; i < 300; i++) {
      const a = below(3), b = (a + 1 + below(2)) % 3, side = below(2) ? 1 : -1;
      const off = [0, 1e-7, -1e-7, 1e-6, -1e-6, 3e-8][below(6)], slope = below(2) ? 0 : (u() - 0.5) * 1e-6;
      const o = [0, 1, 2].map(() => (u() - 0.5) * 2.4), d = [0, 0, 0];
      o[a] = side + off; o[b] = -1.5; d[b] = 0.5 + u(); d[a] = slope;
      list.push([o, d]);
    }
    // Lattice directions through cell corners inside the inner cube, and nudged off the lattice.
    const pattern = [[1, 0, 0], [0, -1, 0], [1, 1, 0], [0, 1, -1], [1, -1, 1], [0.5, 1, 0], [1, 2, -1]];
    for (let i = 0; i < 200; i++) {
      const corner = [0, 1, 2].map(() => -1 + below(17) * cell), d = pattern[below(pattern.length)].map((v) => f(v * (0.5 + u())));
      const o = corner.map((c, a) => f(c - 0.3 * d[a]));
      list.push([o, d], [o.map((v) => v + 1e-6), d]);
    }
    expect(same(g, list, 0.05, 200, 512).samples).toBeGreaterThan(20_000);
  }, 60_000);

  it("jumps empty space inside the inner cube and tests every step beyond it", () => {
    // One occupied cell of 32³ over ±2 (x, y, z in [0, 0.125)); rays along x through it from
    // x = −0.9: segment 0 holds 256 steps over t ∈ [0, 2] (243 inside the inner cube, 13 past
    // it), segment 1 256 steps in the shell, each tested. Of the 243 inside, few are tested.
    const R = 32, occupied = new Uint8Array(R ** 3);
    occupied[(16 * R + 16) * R + 16] = 1;
    const list: Ray[] = Array.from({ length: 50 }, (_, i) => [[-0.9, 0.07, 0.07 + 0.001 * i], [1, 0, 0]]);
    const { samples, tested } = same({ res: R, bound: 2, occupied, contracted: true }, list, 0, 10, 1024);
    expect(marchSegments(0, 10, 1024, true).length).toBe(2);
    expect(samples).toBeGreaterThanOrEqual(50 * 10);
    expect(tested).toBeLessThan(50 * (256 + 13 + 100));
    expect(tested).toBeGreaterThanOrEqual(50 * (256 + 13));
  });
});

describe("a marched render of a contracted grid", () => {
  /** A field whose density falls with distance from the origin, so rays stop at various depths. */
  const field: Field = async (p, v, n) => {
    const rgb = new Float32Array(3 * n), sigma = new Float32Array(n);
    for (let i = 0; i < n; i++) {
      const r2 = p[3 * i] ** 2 + p[3 * i + 1] ** 2 + p[3 * i + 2] ** 2;
      sigma[i] = 150 / (1 + r2);
      for (let a = 0; a < 3; a++) rgb[3 * i + a] = 0.5 + 0.4 * Math.sin(p[3 * i + a] + v[3 * i + a]);
    }
    return { rgb, sigma };
  };

  it("composites the every-step samples front to back with each segment's δ, stopping as nerf-render", async () => {
    const g = sparseContracted(3), u = rng(11), s = () => u() * 2 - 1, n = 300;
    const o = Float32Array.from({ length: 3 * n }, (_, i) => f(i % 3 === 2 ? 0.5 * s() : 2 * s()));
    const d = Float32Array.from({ length: 3 * n }, () => f(s()));
    const sampling = { near: 0.05, far: 100, n_coarse: 64, n_fine: 0, lindisp: false };
    const frame = (await renderMarch(sampling, 256, true, g, field, o, d, d))!;
    const segments = marchSegments(0.05, 100, 256, true);
    let stopped = 0;
    for (let r = 0; r < n; r++) {
      const or = Array.from(o.subarray(3 * r, 3 * r + 3)), dr = Array.from(d.subarray(3 * r, 3 * r + 3));
      const samples = everyStep(g, segments, or, dr), norm = norm3(dr[0], dr[1], dr[2]);
      let T = 1, cr = 0, cg = 0, cb = 0, z = 0, a = 0, k = 0;
      for (const [t, interval] of samples) {
        const p = Float32Array.from(or.map((v, i) => f(v + f(t * dr[i]))));
        const out = await field(p, Float32Array.from(dr.map((v) => f(v / norm))), 1);
        const alpha = f(1 - f(Math.exp(f(-Math.max(out.sigma[0], 0) * f(interval * norm)))));
        const w = f(alpha * T);
        cr = f(cr + f(w * out.rgb[0])); cg = f(cg + f(w * out.rgb[1])); cb = f(cb + f(w * out.rgb[2]));
        z = f(z + f(w * t)); a = f(a + w);
        T = f(T * f(f(1 - alpha) + f(1e-10)));
        // nerf-render's rounds: 16 occupied samples a ray, then the transmittance test.
        if (++k % 16 === 0 && T < 1e-4) { stopped++; break; }
      }
      const bg = f(1 - a);
      expect([frame.rgb[3 * r], frame.rgb[3 * r + 1], frame.rgb[3 * r + 2], frame.depth[r], frame.acc[r]], `ray ${r}`)
        .toEqual([f(cr + bg), f(cg + bg), f(cb + bg), z, a]);
    }
    expect(stopped, "some rays stop early").toBeGreaterThan(10);
    expect(frame.depth.some((z, r) => z / Math.max(frame.acc[r], 1e-6) > 2.5), "some rays reach the shell").toBe(true);
  });
});

/** occupancy.bin bytes: magic, resolution, bound, threshold, [contraction,] cells. */
function gridBytes(magic: string, res: number, bound: number, cells: number[], contraction?: number): ArrayBuffer {
  const header = contraction === undefined ? 20 : 24, buf = new ArrayBuffer(header + 4 * cells.length), v = new DataView(buf);
  magic.split("").forEach((c, i) => v.setUint8(i, c.charCodeAt(0)));
  v.setUint32(8, res, true); v.setFloat32(12, bound, true); v.setFloat32(16, 0.5, true);
  if (contraction !== undefined) v.setUint32(20, contraction, true);
  cells.forEach((c, i) => v.setFloat32(header + 4 * i, c, true));
  return buf;
}

describe("contracted bundles: NERFOCC2 and scene.json", () => {
  const scene = JSON.parse(readFileSync(join(FIXTURE, "scene.json"), "utf8"));

  it("reads NERFOCC2 grids, and NERFOCC1 ones as before", () => {
    const cells = [0, 1, 0, 0, 0, 0, 0.7, 0];
    expect(parseGrid(gridBytes("NERFOCC2", 2, 2, cells, 1))).toEqual({ res: 2, bound: 2, occupied: Uint8Array.from([0, 1, 0, 0, 0, 0, 1, 0]), contracted: true });
    expect(parseGrid(gridBytes("NERFOCC1", 2, 1.5, cells))).toEqual({ res: 2, bound: 1.5, occupied: Uint8Array.from([0, 1, 0, 0, 0, 0, 1, 0]) });
    const file = readFileSync(join(FIXTURE, "occupancy.bin")), g = parseGrid(file.buffer.slice(file.byteOffset, file.byteOffset + file.length));
    expect([g.res, g.bound, g.contracted]).toEqual([32, 2, true]);
    expect(g.occupied.some((v) => v === 1) && g.occupied.some((v) => v === 0)).toBe(true);
  });

  it("refuses a bad NERFOCC2 header, a truncated grid and an unknown magic", () => {
    const cells = new Array(8).fill(0);
    expect(() => parseGrid(gridBytes("NERFOCC2", 2, 2, cells, 7))).toThrow("occupancy.bin: unknown contraction 7 in the NERFOCC2 header");
    expect(() => parseGrid(gridBytes("NERFOCC2", 2, 1.5, cells, 1))).toThrow("occupancy.bin: a contracted grid covers [-2, 2]^3, the header says bound 1.5");
    expect(() => parseGrid(gridBytes("NERFOCC2", 2, 2, cells, 1).slice(0, 40))).toThrow(/40 bytes, expected 56 .*truncated/);
    expect(() => parseGrid(gridBytes("NERFOCC2", 2, 2, cells, 1).slice(0, 22))).toThrow(/missing NERFOCC1 or NERFOCC2 header/);
    expect(() => parseGrid(gridBytes("NERFOCC3", 2, 2, cells, 1))).toThrow(/missing NERFOCC1 or NERFOCC2 header/);
  });

  it("reads the contraction from scene.json and refuses it with the wrong format or bound", () => {
    expect(() => checkScene(scene)).not.toThrow();
    expect(isContracted(scene)).toBe(true);
    expect(isContracted({ ...scene, contraction: undefined })).toBe(false);
    expect(() => checkScene({ ...scene, contraction: undefined })).toThrow('scene.json: contraction: null with format "nerf-rs-scene-3"');
    expect(() => checkScene({ ...scene, format: "nerf-rs-scene-2" })).toThrow('scene.json: contraction: "linf" with format "nerf-rs-scene-2"');
    expect(() => checkScene({ ...scene, contraction: "l2" })).toThrow('scene.json: contraction: "l2" is unknown');
    expect(() => checkScene({ ...scene, occupancy: { ...scene.occupancy, bound: 1.5 } })).toThrow("a contracted grid covers [-2, 2]^3, scene.json says bound 1.5");
  });

  it("refuses a grid file whose contraction is not scene.json's", () => {
    const contracted = parseGrid(gridBytes("NERFOCC2", 1, 2, [1], 1)), plain = parseGrid(gridBytes("NERFOCC1", 1, 2, [1]));
    expect(() => checkGridContraction(scene, contracted)).not.toThrow();
    expect(() => checkGridContraction(scene, plain)).toThrow(`scene.json: occupancy: the grid file's contraction is none, scene.json's "linf"`);
    const uncontracted = { ...scene, format: "nerf-rs-scene-2", contraction: undefined };
    expect(() => checkGridContraction(uncontracted, contracted)).toThrow(`the grid file's contraction is "linf", scene.json's none`);
    expect(() => checkGridContraction(uncontracted, plain)).not.toThrow();
  });

  it("marches a contracted field without its grid (?dense=1) through the whole world", () => {
    expect(wholeBox(2, true)).toEqual({ res: 1, bound: 2, occupied: Uint8Array.from([1]), contracted: true });
    expect(wholeBox(1.5)).toEqual({ res: 1, bound: 1.5, occupied: Uint8Array.from([1]) });
    // Every step of every segment is a sample, far out too.
    const r = same(wholeBox(2, true), [[[0.1, 0.2, 0.3], [1, -0.5, 0.25]], [[5, 5, 5], [-1, 0, 0]]], 0.05, 100, 64);
    expect(r.samples).toBe(2 * 4 * 16);
  });
});
