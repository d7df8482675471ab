// Reading a graph's operators and table precision, and the provider choice from them.
import { describe, expect, it } from "vitest";
import { readFileSync } from "node:fs";
import { resolve } from "node:path";
import { graphInfo } from "../../src/bundle";
import { pickProvider } from "../../src/provider";

const REPO = resolve(import.meta.dirname, "../../..");
const read = (path: string) => graphInfo(new Uint8Array(readFileSync(resolve(REPO, path))), path);
const gpu = (f16: boolean) => ({ features: new Set(f16 ? ["shader-f16"] : []), info: { vendor: "google", architecture: "swiftshader", isFallbackAdapter: true } });

describe("graphInfo", () => {
  it("reads the bitwise float16 hash grid, the portable float32 one and an MLP", () => {
    const bitwise = read("models/lego-ngp/field.onnx"), portable = read("viewer/tests/fixtures/ngp-portable/field.onnx"), mlp = read("models/lego/fine.onnx");
    expect([bitwise.ops.has("BitwiseXor"), bitwise.float16, bitwise.metadata["nerf.hash_lowering"]]).toEqual([true, true, "bitwise"]);
    expect([portable.ops.has("BitwiseXor"), portable.ops.has("Gather"), portable.float16, portable.metadata["nerf.hash_lowering"]]).toEqual([false, true, false, "portable"]);
    expect([mlp.ops.has("Gemm"), mlp.float16]).toEqual([true, false]);
  });
  it("names the file of a truncated or foreign one", () => {
    const bytes = new Uint8Array(readFileSync(resolve(REPO, "models/spheres/coarse.onnx")));
    expect(() => graphInfo(bytes.subarray(0, 1000), "coarse.onnx")).toThrow(/coarse\.onnx: not an ONNX model \(.*(past the end|truncated)/);
    expect(() => graphInfo(new TextEncoder().encode("<html>404</html>"), "x.onnx")).toThrow(/x\.onnx: not an ONNX model/);
  });
});

describe("pickProvider", () => {
  const portable = [{ name: "field.onnx", info: read("viewer/tests/fixtures/ngp-portable/field.onnx") }];
  const bitwise = [{ name: "field.onnx", info: read("models/lego-ngp/field.onnx") }];
  const f16 = [{ name: "field.onnx", info: { ...portable[0].info, float16: true } }];
  it("takes WebGPU for a portable graph on any adapter", () => {
    expect(pickProvider(gpu(false), portable)).toEqual({ provider: "webgpu", reason: "google swiftshader adapter, software" });
  });
  it("falls back to WASM and says why", () => {
    expect(pickProvider(null, portable, true)).toEqual({ provider: "wasm", reason: "no WebGPU in this browser" });
    expect(pickProvider(null, portable)).toEqual({ provider: "wasm", reason: "no GPU adapter" });
    expect(pickProvider(gpu(true), bitwise).reason).toMatch(/field\.onnx has ops WebGPU lacks: BitwiseXor/);
    expect(pickProvider(gpu(false), f16).reason).toMatch(/float16 table and the GPU adapter lacks shader-f16/);
    // With shader-f16 a float16 table runs on the GPU.
    expect(pickProvider(gpu(true), f16).provider).toBe("webgpu");
  });
});
