// The hash grid evaluated in WebAssembly (hashgrid.ts, assembly/hashgrid.ts): corner indices and weights on
// hand-computed cases, the harmonics, and the split (encoder + the graph's head) against the
// whole graph in onnxruntime-web on the fixtures.
import { describe, expect, it } from "vitest";
import { readFileSync } from "node:fs";
import { resolve } from "node:path";
import { graphInfo } from "../../src/bundle";
import { concatBytes, lengthDelimited, stringField } from "../../src/proto";
import { FEATURES_TENSOR, HashEncoder, type HashGridConfig, SH4_DIM, SH_TENSOR, levelLayout, splitHashGrid } from "../../src/hashgrid";

const REPO = resolve(import.meta.dirname, "../../..");
const bytesOf = (path: string) => new Uint8Array(readFileSync(resolve(REPO, path)));
const one = (c: Partial<HashGridConfig>): HashGridConfig => ({ levels: 1, features_per_level: 1, log2_table_size: 3, base_resolution: 16, max_resolution: 16, ...c });

/** The one feature of the unit point `p` with a table whose row i holds `row(i)`. */
function encodeOne(config: HashGridConfig, graphLayout: boolean, rows: number, row: (i: number) => number, p: number[]): number {
  const levels = levelLayout(config, graphLayout);
  const table = Float32Array.from({ length: rows }, (_, i) => row(i));
  // The box [0, 1]³: world points are unit points.
  const enc = new HashEncoder(levels, 1, table, [0, 0, 0], [1, 1, 1], false);
  const out = new Float32Array(1), sh = new Float32Array(SH4_DIM);
  enc.encode(Float32Array.from(p), Float32Array.from([0, 0, 1]), 1, out, sh);
  return out[0];
}

describe("levelLayout", () => {
  it("is LevelLayout's: instant-ngp's grid, and the graph's rows", () => {
    const c: HashGridConfig = { levels: 16, features_per_level: 2, log2_table_size: 19, base_resolution: 16, max_resolution: 2048 };
    const levels = levelLayout(c, false);
    // b = 2048/16 ^ (1/15) = 2^(7/15); level 0: 16 − 1 = 15, res 16, 4096 entries, dense.
    expect(levels[0]).toEqual({ scale: 15, resolution: 16, entries: 4096, dense: true, row: 0, rows: 4096 });
    expect(levels[15].scale).toBe(2047);
    expect(levels.filter((l) => l.dense).length).toBe(5); // res³ ≤ 2¹⁹ up to res 80
    expect(levels[5]).toMatchObject({ dense: false, entries: 1 << 19 });
    // Graph layout: hashed levels first at j·T, dense ones after, padded to res³ + res² + res + 1.
    const graph = levelLayout(c, true);
    expect(graph[5].row).toBe(0);
    expect(graph[15].row).toBe(10 * (1 << 19));
    expect(graph[0].row).toBe(11 * (1 << 19));
    expect(graph[1].row).toBe(11 * (1 << 19) + 16 ** 3 + 16 ** 2 + 16 + 1);
    expect(graph[0].rows).toBe(16 ** 3 + 16 ** 2 + 16 + 1);
    expect(graph[5].rows).toBe(1 << 19);
  });
});

describe("HashEncoder", () => {
  it("hashes a level's corners as tiny-cuda-nn (x·1 ⊕ y·2654435761 ⊕ z·805459861 mod T)", () => {
    // T = 8, res 16 > 2: hashed. At the unit origin pos = 0.5 on each axis: every corner weighs
    // 1/8. Mod 8 the primes are 1 and 5, so corners (x, y, z) ∈ {0, 1}³ land on x ⊕ y ⊕ 5z:
    // 0, 1, 1, 0, 5, 4, 4, 5; with row i holding 2^i the mean is (1+2+2+1+32+16+16+32)/8 = 12.75.
    expect(encodeOne(one({}), false, 8, (i) => 2 ** i, [0, 0, 0])).toBe(12.75);
    // The same point at (1, 2, 3) cells (pos 1.5, 2.5, 3.5 with scale 15): corners 1..2, 2..3,
    // 3..4; e.g. (1, 2, 3) → 1 ⊕ 2 ⊕ 15 = 12 mod 8 = 4 … all eight, each 1/8 of its row i = i.
    const corners = [[1, 2, 3], [2, 2, 3], [1, 3, 3], [2, 3, 3], [1, 2, 4], [2, 2, 4], [1, 3, 4], [2, 3, 4]];
    const want = corners.reduce((s, [x, y, z]) => s + ((x ^ y ^ (5 * z)) & 7), 0) / 8;
    expect(encodeOne(one({}), false, 8, (i) => i, [1 / 15, 2 / 15, 3 / 15])).toBeCloseTo(want, 5);
  });

  it("indexes a dense level x + y·res + z·res², wrapping at the level's entries, in either layout", () => {
    // base 2: scale 1, res 2, 8 entries, dense. Unit (1, 1, 1): pos 1.5, corners 1..2 per axis,
    // indices 7, 8, 9, 10, 11, 12, 13, 14 → wrapped 7, 0, 1, …, 6: the mean of rows 0..7 = 3.5.
    const c = one({ base_resolution: 2, max_resolution: 2 });
    expect(levelLayout(c, false)[0]).toEqual({ scale: 1, resolution: 2, entries: 8, dense: true, row: 0, rows: 8 });
    expect(levelLayout(c, true)[0].rows).toBe(15);
    expect(encodeOne(c, false, 8, (i) => i, [1, 1, 1])).toBe(3.5);
    // The graph's padded rows (15, row r holding r mod 8) give the same.
    expect(encodeOne(c, true, 15, (i) => i % 8, [1, 1, 1])).toBe(3.5);
    // Trilinear: at unit (0.25, 0, 0) pos = 0.75, 0.5, 0.5: weights 0.75/0.25 along x.
    // Corners x 0/1, y 0/1, z 0/1 → rows x + 2y + 4z, table row i = i: 0.25·(0+2+4+6)/4 + 0.75·(1+3+5+7)/4.
    expect(encodeOne(c, false, 8, (i) => i, [0.25, 0, 0])).toBe(0.25 * 3 + 0.75 * 4);
  });

  it("clamps points outside the box, NaN to its lower face", () => {
    const c = one({ base_resolution: 2, max_resolution: 2 });
    const at = (p: number[]) => encodeOne(c, false, 8, (i) => i, p);
    expect(at([5, 5, 5])).toBe(at([1, 1, 1]));
    expect(at([NaN, -3, 0])).toBe(at([0, 0, 0]));
  });
});

describe("the harmonics", () => {
  it("are the degree-4 harmonics of +z and +x", () => {
    // One point (any), the direction's 16 harmonics.
    const enc = new HashEncoder(levelLayout(one({}), false), 1, new Float32Array(8), [0, 0, 0], [1, 1, 1], false);
    const out = new Float32Array(SH4_DIM), sh4 = (dir: number[]) => enc.encode(new Float32Array(3), Float32Array.from(dir), 1, new Float32Array(1), out);
    sh4([0, 0, 1]);
    const c = [0.2820948, 0.4886025, 1.0925484, 0.9461747, 0.31539157, 0.5462742, 0.5900436, 2.8906114, 0.4570458, 0.3731763, 1.4453057].map(Math.fround);
    // Signed zeros as IEEE products give them (0·(1 − 5) = −0 at 11 and 13).
    expect(Array.from(out)).toEqual([c[0], -0, c[1], -0, 0, -0, Math.fround(c[3] - c[4]), -0, 0, 0, 0, -0, Math.fround(2 * c[9]), -0, 0, 0]);
    sh4([1, 0, 0]);
    // x = 1: −c1·x at 3, c5·x² at 8, c8·x·(1 − 0) at 13, c6·x·(−x²) at 15, −c4 at 6.
    expect([out[3], out[6], out[8], out[13], out[15]]).toEqual([-c[1], -c[4], c[5], c[8], -c[6]]);
  });
});

describe("splitHashGrid", () => {
  it("cuts the head at the encodings' outputs, without the hash grid's ops", () => {
    for (const path of ["models/lego-ngp/field.onnx", "viewer/tests/fixtures/ngp-portable/field.onnx"]) {
      const split = splitHashGrid(bytesOf(path), path);
      if (!split || !("head" in split)) throw new Error(split?.reason ?? "not a hash grid");
      const head = graphInfo(split.head, "head"), whole = graphInfo(bytesOf(path), path);
      expect(whole.ops.has("Gather")).toBe(true);
      expect(head.ops.has("Gather") || head.ops.has("BitwiseXor") || head.ops.has("Floor")).toBe(false);
      expect(head.ops.has("Gemm")).toBe(true);
      expect(split.encoder.width).toBe(path.includes("lego") ? 32 : 16);
    }
  });

  it("leaves an MLP graph whole, and names a malformed file", () => {
    expect(splitHashGrid(bytesOf("models/lego/fine.onnx"), "fine.onnx")).toBeNull();
    const bytes = bytesOf("viewer/tests/fixtures/ngp-portable/field.onnx");
    expect(() => splitHashGrid(bytes.subarray(0, 5000), "field.onnx")).toThrow(/field\.onnx: not an ONNX model/);
  });

  it("names the file and the field of a hash-grid graph whose metadata is out of range", () => {
    // A model of one node whose nerf.ngp metadata is the given JSON.
    const model = (ngp: string) => concatBytes([
      lengthDelimited(14, concatBytes([stringField(1, "nerf.field"), stringField(2, "ngp")])),
      lengthDelimited(14, concatBytes([stringField(1, "nerf.ngp"), stringField(2, ngp)])),
      lengthDelimited(7, lengthDelimited(1, concatBytes([stringField(1, "x"), stringField(2, "y"), stringField(4, "Relu")]))),
    ]);
    const grid = { levels: 16, features_per_level: 2, log2_table_size: 19, base_resolution: 16, max_resolution: 2048 };
    const bound = { min: [-1, -1, -1], max: [1, 1, 1] };
    const split = (spec: object) => () => splitHashGrid(model(JSON.stringify(spec)), "field.onnx");
    expect(split({ grid: { ...grid, levels: 40 }, bound })).toThrow(/field\.onnx: nerf\.ngp: grid .*"levels":40.*\(levels 1–32/);
    expect(split({ grid: { ...grid, features_per_level: 3 }, bound })).toThrow(/field\.onnx: nerf\.ngp: grid/);
    expect(split({ bound })).toThrow(/field\.onnx: nerf\.ngp: grid undefined/);
    expect(split({ grid, bound: { min: [1, 1, 1], max: [1, 2, 2] } })).toThrow(/field\.onnx: nerf\.ngp: bound .* finite min < max/);
    expect(() => splitHashGrid(model("{"), "field.onnx")).toThrow(/field\.onnx: nerf\.ngp \/ nerf\.grid_table metadata/);
  });

  it("the encoder and the head give the whole graph's outputs in onnxruntime-web (plain and contracted)", async () => {
    const ort = await import("onnxruntime-web/wasm");
    ort.env.wasm.wasmPaths = resolve(REPO, "viewer/node_modules/onnxruntime-web/dist") + "/";
    ort.env.wasm.numThreads = 1;
    for (const [path, spread] of [["viewer/tests/fixtures/ngp-portable/field.onnx", 1.6], ["viewer/tests/fixtures/ngp-contracted/field.onnx", 20]] as const) {
      const bytes = bytesOf(path), split = splitHashGrid(bytes, path);
      if (!split || !("head" in split)) throw new Error(split?.reason ?? "not a hash grid");
      // Points over the box and past it (the contracted field's whole world), deterministic.
      const n = 4096, points = new Float32Array(3 * n), dirs = new Float32Array(3 * n);
      let s = 12345;
      const rand = () => ((s = (Math.imul(s, 1103515245) + 12345) >>> 0) / 2 ** 32) * 2 - 1;
      for (let i = 0; i < n; i++) {
        for (let a = 0; a < 3; a++) points[3 * i + a] = Math.fround(rand() * spread);
        const d = [rand(), rand(), rand()], norm = Math.hypot(...d);
        for (let a = 0; a < 3; a++) dirs[3 * i + a] = Math.fround(d[a] / norm);
      }
      const whole = await ort.InferenceSession.create(bytes);
      const want = await whole.run({ points: new ort.Tensor("float32", points, [n, 3]), viewdirs: new ort.Tensor("float32", dirs, [n, 3]) });
      const features = new Float32Array(split.encoder.width * n), sh = new Float32Array(SH4_DIM * n);
      split.encoder.encode(points, dirs, n, features, sh);
      const head = await ort.InferenceSession.create(split.head);
      const got = await head.run({ [FEATURES_TENSOR]: new ort.Tensor("float32", features, [n, split.encoder.width]), [SH_TENSOR]: new ort.Tensor("float32", sh, [n, SH4_DIM]) });
      for (const name of ["rgb", "sigma"]) {
        const a = got[name].data as Float32Array, b = want[name].data as Float32Array;
        expect(a.length).toBe(b.length);
        let worst = 0;
        for (let i = 0; i < a.length; i++) worst = Math.max(worst, Math.abs(a[i] - b[i]) / Math.max(1, Math.abs(b[i])));
        expect(worst, `${path} ${name}`).toBeLessThanOrEqual(1e-5);
      }
    }
  });
});
