// The marcher (src/march.ts) against the reference marching: every interval tested with
// isOccupied, sample for sample, bit for bit (as core/src/render/grid.rs's tests).
import { describe, expect, it } from "vitest";
import { CORNER_SIDES, type Grid, OCCUPIED_CUBE, cornerReach, isOccupied } from "../../src/march";
import { MarchWasm, RayMarch } from "../../src/marcher";

const f = Math.fround;

/** A seeded uniform draw in [0, 1) (Park–Miller). */
function rng(seed: number) {
  let s = seed;
  return () => (s = (s * 16807) % 2147483647) / 2147483647;
}

/** Bound 1, resolution 32 (cells of 1/16, blocks of 1/2): a third of the blocks hold a tenth of
 *  their cells occupied, so some blocks are empty and the occupied ones are mostly empty cells. */
function sparseGrid(seed: number): Grid {
  const u = rng(seed), R = 32, nb = 4, chosen = Array.from({ length: nb ** 3 }, () => u() < 0.35);
  const occupied = new Uint8Array(R ** 3);
  for (let c = 0; c < R ** 3; c++) {
    const i = Math.floor(c / (R * R) / 8), j = Math.floor((c / R) % R / 8), k = Math.floor((c % R) / 8);
    occupied[c] = chosen[(i * nb + j) * nb + k] && u() < 0.1 ? 1 : 0;
  }
  return { res: R, bound: 1, occupied };
}

/** Each ray's occupied steps by testing every interval, as render_rays.py's march does. */
function everyInterval(g: Grid, o: Float32Array, d: Float32Array, near: number, interval: number, steps: number): number[][] {
  const out: number[][] = [];
  for (let r = 0; r < o.length / 3; r++) {
    const ks: number[] = [];
    for (let k = 0; k < steps; k++) {
      const t = f(near + f(f(k + 0.5) * interval));
      if (isOccupied(g, f(o[3 * r] + f(t * d[3 * r])), f(o[3 * r + 1] + f(t * d[3 * r + 1])), f(o[3 * r + 2] + f(t * d[3 * r + 2])))) ks.push(k);
    }
    out.push(ks);
  }
  return out;
}

/** The marcher's steps per ray, asked for `chunk` at a time (resumed), with the positions it wrote checked. */
function marched(g: Grid, o: Float32Array, d: Float32Array, near: number, interval: number, steps: number, chunk: number,
  wasm = new MarchWasm()) {
  const m = new RayMarch(g, o, d, near, interval, steps, wasm), pts = new Float32Array(3 * chunk), ks = new Int32Array(chunk);
  const out: number[][] = [];
  for (let r = 0; r < o.length / 3; r++) {
    const all: number[] = [];
    for (;;) {
      const c = m.next(r, chunk, pts, ks, 0);
      for (let i = 0; i < c; i++) {
        const t = m.t[ks[i]];
        for (let a = 0; a < 3; a++) expect(pts[3 * i + a]).toBe(f(o[3 * r + a] + f(t * d[3 * r + a])));
        all.push(ks[i]);
      }
      if (c < chunk) break;
    }
    out.push(all);
  }
  return { steps: out, tested: m.tested };
}

function same(g: Grid, list: [number[], number[]][], near: number, far: number, steps: number, chunk = 16, wasm?: MarchWasm) {
  const o = Float32Array.from(list.flatMap((r) => r[0])), d = Float32Array.from(list.flatMap((r) => r[1]));
  const interval = f(f(far - near) / f(steps));
  const want = everyInterval(g, o, d, near, interval, steps), got = marched(g, o, d, near, interval, steps, chunk, wasm);
  const wrong: string[] = [];
  for (let r = 0; r < want.length; r++)
    if (want[r].join() !== got.steps[r].join()) wrong.push(`ray ${r} o ${list[r][0]} d ${list[r][1]}: ${got.steps[r].length} samples, want ${want[r].length}`);
  expect(wrong.slice(0, 5)).toEqual([]);
  return { samples: want.reduce((s, k) => s + k.length, 0), tested: got.tested };
}

describe("the cubes marching jumps (cornerReach)", () => {
  it("gives each cell the largest cube of its state from it along the octant, on every cell", () => {
    // 13³ (rows of bytes) and 16³ (4 cells a 32-bit word), a tenth of the cells occupied, a
    // solid 5³ block inside and a 4³ one in a corner of the grid, against the definition cube by
    // cube (past the grid counts as empty: an occupied cube stops at the grid's faces).
    for (const R of [13, 16]) {
      const u = rng(R), occupied = Uint8Array.from({ length: R ** 3 }, () => (u() < 0.1 ? 1 : 0));
      for (let i = 2; i < 7; i++) for (let j = 3; j < 8; j++) for (let k = 4; k < 9; k++) occupied[(i * R + j) * R + k] = 1;
      for (let i = R - 4; i < R; i++) for (let j = 0; j < 4; j++) for (let k = R - 4; k < R; k++) occupied[(i * R + j) * R + k] = 1;
      const g: Grid = { res: R, bound: 1, occupied };
      const at = (i: number, j: number, k: number) =>
        i >= 0 && i < R && j >= 0 && j < R && k >= 0 && k < R ? occupied[(i * R + j) * R + k] : 0;
      for (let q = 0; q < 8; q++) {
        const table = cornerReach(g, q), sx = q & 4 ? 1 : -1, sy = q & 2 ? 1 : -1, sz = q & 1 ? 1 : -1;
        for (let i = 0; i < R; i++) for (let j = 0; j < R; j++) for (let k = 0; k < R; k++) {
          const state = at(i, j, k);
          const fits = (s: number) => {
            for (let a = 0; a < s; a++) for (let b = 0; b < s; b++) for (let c = 0; c < s; c++)
              if (at(i + a * sx, j + b * sy, k + c * sz) !== state) return false;
            return true;
          };
          let side = 1;
          for (const s of CORNER_SIDES) if (fits(s)) side = s; else break;
          expect(table[(i * R + j) * R + k], `R ${R}, octant ${q}, cell ${i} ${j} ${k}`).toBe(side | (state ? OCCUPIED_CUBE : 0));
        }
      }
      expect(cornerReach(g, 0)).toBe(cornerReach(g, 0)); // made once
    }
  });
});

describe("marching with empty-space skipping", () => {
  it("takes the samples of testing every interval on random rays, in any chunk size", () => {
    for (const seed of [1, 2, 3]) {
      const g = sparseGrid(seed), u = rng(100 + seed), s = () => u() * 2 - 1;
      const list: [number[], number[]][] = [];
      for (let i = 0; i < 600; i++) {
        // From outside towards [−1.2, 1.2]³ (some miss the box), a third from inside it.
        const target = [s() * 1.2, s() * 1.2, s() * 1.2];
        const origin = i % 3 === 0 ? [s() * 0.9, s() * 0.9, s() * 0.9] : [s() * 3, s() * 3, 3];
        const scale = 0.5 + Math.abs(s());
        list.push([origin, target.map((v, a) => (v - origin[a]) * scale)]);
      }
      const { samples } = same(g, list, 0, 6, 2048, [16, 3, 1000][seed - 1]);
      expect(samples).toBeGreaterThan(2000); // the rays see occupied cells
    }
  }, 60_000);

  it("takes the same samples on rays along cell faces, edges and corners and hugging a plane", () => {
    const g = sparseGrid(7), u = rng(5), cell = 1 / 16, below = (n: number) => Math.floor(u() * n);
    const list: [number[], number[]][] = [];
    const pattern = [[1, 0, 0], [0, -1, 0], [0, 0, 1], [1, 1, 0], [0, 1, -1], [1, -1, 1], [0.5, 1, 0], [1, 2, -1]];
    for (let i = 0; i < 300; i++) {
      // A cell corner and a lattice direction through it, started 2 units back (outside the box);
      // the same line nudged off the lattice by 1e-6.
      const corner = [0, 1, 2].map(() => -1 + below(33) * cell);
      const d = pattern[below(pattern.length)].map((v) => f(v * (0.5 + u())));
      const origin = corner.map((c, a) => f(c - 2 * d[a]));
      list.push([origin, d], [origin.map((v) => v + 1e-6), d]);
    }
    expect(same(g, list, 0, 6, 2048).samples).toBeGreaterThan(5000);
    // Along x hugging a plane y = const at a tiny slope, over stripes occupied where j + k is
    // even: rounding moves computed samples across the plane far from where the exact line does.
    const R = 32, striped = new Uint8Array(R ** 3);
    for (let c = 0; c < R ** 3; c++) striped[c] = (Math.floor(c / R) % R + (c % R)) % 2 === 0 ? 1 : 0;
    const hug: [number[], number[]][] = [];
    for (let i = 0; i < 300; i++) {
      const plane = -1 + (1 + below(31)) * cell, offset = (u() - 0.5) * 6e-7, crossing = 1.2 + 1.6 * u();
      hug.push([[-2, plane + offset, -1 + (below(32) + 0.5) * cell], [1, -offset / crossing, 0]]);
    }
    expect(same({ res: R, bound: 1, occupied: striped }, hug, 0, 6, 2048).samples).toBeGreaterThan(30000);
  }, 60_000); // thousands of rays tested step by step: seconds, more on a busy machine

  it("handles rays that miss the box, degenerate rays and a degenerate interval", () => {
    const g = sparseGrid(2);
    const list: [number[], number[]][] = [
      [[-3, 1.5, 0], [1, 0, 0]], [[-3, 1, 0], [1, 0, 0]], [[3, 3, 3], [1, 1, 1]],
      [[-3, 0.1, 0.2], [0, 0, 0]], [[-3, 0.1, 0.2], [NaN, 0, 0]], [[-3, 0.1, 0.2], [Infinity, 1, 0]],
    ];
    expect(same(g, list, 0, 6, 512).samples).toBe(0);
    // far < near (a negative interval) and near = far: every interval tested. Along x through
    // the centre of an occupied cell, with steps shorter than a cell.
    const c = g.occupied.indexOf(1), centre = (i: number) => -1 + (i + 0.5) / 16;
    const one: [number[], number[]][] = [[[-2, centre(Math.floor(c / 32) % 32), centre(c % 32)], [1, 0, 0]]];
    expect(same(g, one, 0, 6, 256).samples).toBeGreaterThan(0);
    expect(same(g, one, 6, 0, 256).samples).toBeGreaterThan(0);
    same(g, one, 2, 2, 256);
  });

  it("takes the same samples in one instance reused for other grids, octants and more rays", () => {
    // One WebAssembly instance, as renderMarch's pool reuses them: a second grid replaces the
    // first (its occupancy and cube tables), octants first met in a later frame get their
    // tables then, and a frame with more rays than the last grows the memory under it.
    const wasm = new MarchWasm(), u = rng(11), s = () => u() * 2 - 1;
    // Rays from `origin()` through random points of the box.
    const rays = (count: number, origin: () => number[]): [number[], number[]][] => Array.from({ length: count }, () => {
      const from = origin();
      return [from, [s(), s(), s()].map((v, a) => v - from[a])];
    });
    const upward = rays(60, () => [-3 + s() / 2, -3 + s() / 2, -3 + s() / 2]), anyway = rays(400, () => [s() * 3, s() * 3, s() * 3]);
    const a = sparseGrid(4), b = sparseGrid(5);
    for (const [g, list] of [[a, upward], [b, upward], [b, anyway], [a, anyway], [a, upward]] as const)
      expect(same(g, list, 0, 6, 1024, 16, wasm).samples).toBeGreaterThan(100);
  });

  it("tests far fewer steps on a mostly empty grid", () => {
    // One occupied cell of a 64³ grid, at the centre; 100 rays of 2048 steps through it.
    const R = 64, occupied = new Uint8Array(R ** 3);
    occupied[(32 * R + 32) * R + 32] = 1;
    const list: [number[], number[]][] = [];
    for (let i = 0; i < 100; i++) list.push([[-3, 0.01 + 0.00001 * i, 0.02], [1, 0, 0.00001 * i]]);
    const { samples, tested } = same({ res: R, bound: 1, occupied }, list, 0, 6, 2048);
    // ≈ 680 steps of each ray lie in the box; skipping tests the occupied cell's ≈ 11 and about
    // 2 per empty block or cell crossed.
    expect(samples).toBeGreaterThanOrEqual(100 * 10);
    expect(tested).toBeLessThan(100 * 50);
  });
});
