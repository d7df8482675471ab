// The viewer's rendering functions (TypeScript, and assembly/march.ts's WebAssembly) against
// tests/python/render_rays.py on the same inputs (fixtures from tests/fixtures/make_fixtures.py).
// Sums run in nerf-render's order, numpy's pairwise, so values agree to float32 rounding, not
// bit for bit.
import { describe, expect, it } from "vitest";
import ref from "../fixtures/reference.json";
import { cameraRays, ndcRays, outputSize, pinhole, resized } from "../../src/camera";
import { MarchWasm } from "../../src/marcher";
import { type Field, coarseT, renderDense, renderMarch, samplePdf, weightsOf } from "../../src/render";
import { toU8 } from "../../src/view";
import { graphFiles, isBounded, parseGrid } from "../../src/bundle";

const close = (got: ArrayLike<number>, want: number[], tol = 2e-6) => {
  expect(got.length).toBe(want.length);
  let worst = 0;
  for (let i = 0; i < want.length; i++) worst = Math.max(worst, Math.abs(got[i] - want[i]) / Math.max(1, Math.abs(want[i])));
  expect(worst).toBeLessThanOrEqual(tol);
};

/** The fixtures' made-up field, computed as the Python one: float64 polynomials of float32 inputs. */
const fakeField: Field = async (p, v, n) => {
  const rgb = new Float32Array(3 * n), sigma = new Float32Array(n);
  for (let i = 0; i < n; i++) {
    const x = p[3 * i], y = p[3 * i + 1], z = p[3 * i + 2];
    sigma[i] = Math.max(0, 30 * (0.8 - (x * x + y * y + z * z)));
    for (let a = 0; a < 3; a++) rgb[3 * i + a] = Math.min(Math.max(0.5 + 0.3 * p[3 * i + a] + 0.1 * v[3 * i + a], 0), 1);
  }
  return { rgb, sigma };
};

describe("camera rays", () => {
  for (const key of ["camera_full", "camera_focal"] as const) {
    it(`${key} matches camera_rays`, () => {
      const c = ref[key];
      const cam = resized(pinhole(c.camera), c.width, c.height);
      const { o, d } = cameraRays(cam, c.c2w, Int32Array.from(c.pixels));
      close(o, c.o, 0);
      close(d, c.d, 1e-6);
    });
  }
  it("keeps the aspect as nerf-render --width", () => {
    expect(outputSize(pinhole({ width: 100, height: 75, focal: 1 }), 50)).toEqual([50, 38]);
    expect(outputSize(pinhole({ width: 64, height: 64, focal: 1 }), 32, 20)).toEqual([32, 20]);
  });
  it("warps rays as ndc_rays", () => {
    const r = ref.ndc;
    const { o, d } = ndcRays(r.ndc, Float32Array.from(r.o), Float32Array.from(r.d));
    close(o, r.o2, 1e-6);
    close(d, r.d2, 1e-6);
  });
});

describe("sampling and compositing", () => {
  it("coarse t is linspace(near, far)", () => {
    close(coarseT({ near: 2, far: 6, n_coarse: 8, n_fine: 0, lindisp: false }), ref.weights.t, 1e-6);
  });
  it("weights_of", () => {
    const r = ref.weights, S = r.t.length, w = new Float32Array(S);
    for (let k = 0; k < r.dnorm.length; k++) {
      weightsOf(r.t, r.sigma.slice(k * S, (k + 1) * S), Math.fround(r.dnorm[k]), w);
      close(w, r.w.slice(k * S, (k + 1) * S), 1e-6);
    }
  });
  it("compositing's exp (WebAssembly) is Math.exp to 1e-14 over its range, and exp outside it", () => {
    const wasm = new MarchWasm(), expAlpha = (x: number) => wasm.expAlpha(x);
    // Every float32 step of 2⁻¹⁰ from −110 to 0, and the edges: α's float32 is Math.exp's but
    // for a rounding tie or so (both are off the exact exp by far less than a float32 ulp).
    let worst = 0, differ = 0, count = 0;
    for (let x = -110; x <= 0; x += 2 ** -10, count++) {
      const got = expAlpha(x), want = Math.exp(x);
      if (want > 1e-300) worst = Math.max(worst, Math.abs(got / want - 1));
      if (Math.fround(got) !== Math.fround(want)) differ++;
    }
    expect(worst).toBeLessThan(1e-14);
    expect(differ / count).toBeLessThan(1e-5);
    expect(expAlpha(0)).toBe(1);
    expect(expAlpha(-0)).toBe(1);
    expect(Math.fround(expAlpha(-104.5))).toBe(0);
    // Outside, the module's own exp (AssemblyScript's, not V8's: the same to an ulp or so).
    expect(expAlpha(NaN)).toBeNaN();
    expect(expAlpha(-Infinity)).toBe(0);
    for (const x of [0.5, 3]) expect(Math.abs(expAlpha(x) / Math.exp(x) - 1)).toBeLessThan(1e-15);
    // A hand value: e⁻¹.
    expect(Math.abs(expAlpha(-1) - 0.36787944117144233)).toBeLessThan(1e-16);
  });
  it("sample_pdf", () => {
    const r = ref.sample_pdf, nb = r.bins.length / 3, nw = r.weights.length / 3, out = new Float32Array(r.n);
    const u = Float32Array.from({ length: r.n }, (_, i) => Math.fround(i) / Math.fround(r.n - 1));
    for (let k = 0; k < 3; k++) {
      samplePdf(r.bins.slice(k * nb, (k + 1) * nb), r.weights.slice(k * nw, (k + 1) * nw), u, out);
      close(out, r.out.slice(k * r.n, (k + 1) * r.n), 1e-5);
    }
  });
});

describe("whole renders with a made-up field", () => {
  it("render (coarse + fine) matches render()", async () => {
    const r = ref.render, o = Float32Array.from(r.o), d = Float32Array.from(r.d);
    const f = (await renderDense(r.scene.sampling, true, fakeField, fakeField, o, d, d))!;
    close(f.rgb, r.rgb, 1e-5); close(f.depth, r.depth, 1e-5); close(f.acc, r.acc, 1e-5);
  });
  it("march (occupancy grid, early termination) matches march()", async () => {
    const r = ref.march, o = Float32Array.from(r.o), d = Float32Array.from(r.d);
    const grid = { res: r.res, bound: r.bound, occupied: Uint8Array.from(r.occupied) };
    const f = (await renderMarch(r.scene.sampling, r.scene.march_steps, true, grid, fakeField, o, d, d))!;
    close(f.rgb, r.rgb, 1e-5); close(f.depth, r.depth, 1e-5); close(f.acc, r.acc, 1e-5);
    // Smaller chunks per call give the same pixels (the queue only changes batching).
    const g = (await renderMarch(r.scene.sampling, r.scene.march_steps, true, grid, fakeField, o, d, d, undefined, 16, 1e-4, 3))!;
    close(g.rgb, Array.from(f.rgb), 0);
  });
  it("march: frames in flight together are the frames rendered alone", async () => {
    // Each frame marches in its own WebAssembly memory: two frames whose field calls interleave
    // (each call waits a turn of the event loop) give the pixels each gives alone.
    const r = ref.march, o = Float32Array.from(r.o), d = Float32Array.from(r.d);
    const grid = { res: r.res, bound: r.bound, occupied: Uint8Array.from(r.occupied) };
    const shifted = o.map((v, i) => (i % 3 === 0 ? v + 0.1 : v));
    const later: Field = async (p, v, n) => { await new Promise((ok) => setTimeout(ok, 0)); return fakeField(p, v, n); };
    const render = (origins: Float32Array, field: Field) => renderMarch(r.scene.sampling, r.scene.march_steps, true, grid, field, origins, d, d,
      undefined, 16, 1e-4, 3);
    const alone = [(await render(o, fakeField))!, (await render(shifted, fakeField))!];
    const together = await Promise.all([render(o, later), render(shifted, later)]);
    expect(alone[0].rgb).not.toEqual(alone[1].rgb);
    for (let k = 0; k < 2; k++) {
      expect(together[k]!.rgb).toEqual(alone[k].rgb);
      expect(together[k]!.depth).toEqual(alone[k].depth);
    }
  });
});

describe("bundle files and pixels", () => {
  it("names graphs by role in both formats", () => {
    expect(graphFiles({ graphs: { field: "field.onnx" } })).toEqual({ field: "field.onnx" });
    expect(graphFiles({ format: "nerf-rs-scene-1", networks: { coarse: "c.onnx", fine: "f.onnx" } })).toEqual({ coarse: "c.onnx", fine: "f.onnx" });
    expect(graphFiles({ format: "nerf-rs-scene-1", field: "ngp", networks: { coarse: "g.onnx" } })).toEqual({ field: "g.onnx" });
    expect(isBounded({ format: "nerf-rs-scene-1", field: "ngp" })).toBe(true);
    expect(() => graphFiles({ graphs: { field: "../x.onnx" } })).toThrow(/plain file name/);
  });
  it("reads occupancy.bin and rejects a truncated one", () => {
    const buf = new ArrayBuffer(20 + 4 * 8), v = new DataView(buf);
    "NERFOCC1".split("").forEach((c, i) => v.setUint8(i, c.charCodeAt(0)));
    v.setUint32(8, 2, true); v.setFloat32(12, 1.5, true); v.setFloat32(16, 0.5, true);
    v.setFloat32(20 + 4 * 3, 0.7, true);
    const g = parseGrid(buf);
    expect([g.res, g.bound, Array.from(g.occupied)]).toEqual([2, 1.5, [0, 0, 0, 1, 0, 0, 0, 0]]);
    expect(() => parseGrid(buf.slice(0, 40))).toThrow(/truncated/);
  });
  it("quantises as core/src/io/image.rs", () => {
    expect([0, 1, 0.5, 0.1, 0.002, 0.998, -3, 7].map(toU8)).toEqual([0, 255, 128, 26, 1, 254, 0, 255]);
  });
});
